"""Each condition's model faults and safety events (analysis.statistics.faults) as the reports show them:
a table and a sentence."""

from __future__ import annotations

from analysis.reports.table import Table
from analysis.statistics.faults import (
    FAULT_KINDS,
    FAULT_SHARE_MAX,
    SAFETY_KINDS,
    ConditionEvents,
    any_events,
    kinds_text,
)


def events_cell(e: ConditionEvents) -> str:
    """A condition's trials affected of its trials, with the kinds: "12 of 12 trials (nan_force 12)"."""
    return f"{e.affected_trials} of {e.trials} trials ({kinds_text(e)})" if e.affected_trials else f"0 of {e.trials} trials"


def events_table(events) -> Table | None:
    """The faults and safety events per condition, with the conditions withheld and why; None
    when no trial of any condition had one (the reports then show nothing)."""
    if not any_events(events):
        return None
    rows = [[e.condition, events_cell(e), f"{e.fault_trials} of {e.trials}" + (f" ({e.fault_share:.0%})" if e.trials else ""),
             e.reason.replace("withheld:", "WITHHELD:", 1) if e.withheld else "tested"] for e in events]
    return Table(columns=["Condition", "Trials with a fault or safety event (kinds: trials)", "Trials with a model fault", "Tests"],
                 rows=rows, title="Faults and safety events",
                 notes=f"Faults: {', '.join(FAULT_KINDS)} (the participant felt zero force, not the model's); safety events: "
                       f"{', '.join(SAFETY_KINDS)} (limits of normal operation). A condition with model faults in more than "
                       f"{FAULT_SHARE_MAX:.0%} of its trials is withheld from every test that involves it.")


def events_text(events) -> str:
    """The faults and safety events as a sentence for the results ("" when there were none)."""
    if not any_events(events):
        return ""
    parts = [f"{e.condition}: {e.affected_trials} of {e.trials} trials ({kinds_text(e)})" for e in events if e.affected_trials]
    out = "Faults and safety events per condition: " + "; ".join(parts) + "."
    for e in events:
        if e.withheld:
            out += (f" WITHHELD: {e.condition}'s trials were mostly model faults ({e.fault_trials} of {e.trials}): every test "
                    f"involving {e.condition} is withheld; its answers describe the fault, not the model.")
    return out
