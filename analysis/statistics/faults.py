"""A condition's model faults and safety events, from its stored trials, and the rule that
withholds its tests when its trials are mostly faults.

Every trial stores how many times each servo event happened (`sim.servo.loop`). Two families
count here:

- **faults** (`FAULT_KINDS`): the model did not give the force the participant should have
  felt: a NaN or infinite force zeroed (`nan_force`), a model that raised or returned the wrong
  shape (`model_fault`), a model that said its state blew up (`model_unstable`);
- **safety events** (`SAFETY_KINDS`): limits and guards that are normal operation and leave the
  model's force in place or briefly withheld: the force clamped to the device's peak or its
  continuous budget, chatter, the servo suspended after missed deadlines, a device fault or a
  jump, force calls over their time budget. They are reported, never a reason to withhold.

A condition is withheld when more than `FAULT_SHARE_MAX` of its trials had a fault: its
participants then mostly felt zero force rather than the model, so their answers describe the
fault, not the model, and a test involving the condition would compare something else than
it claims. Its rates stay (described, flagged); every test that involves it (Cochran's Q, the
McNemar, Wilcoxon and choice pairs, Friedman, the GEEs and mixed models) is withheld with the
reason. All of a condition's stored trials count, complete participants or not.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass

import pandas as pd

from analysis.statistics.result_records import Record

FAULT_KINDS = ("nan_force", "model_fault", "model_unstable")
SAFETY_KINDS = ("force_clamped", "force_budget", "force_chatter", "suspended", "deadline_streak", "device_fault", "nan_position", "position_jump",
                "over_budget")
# more than half the trials faulty: most of what the participants felt was not the model
FAULT_SHARE_MAX = 0.5
NAN = float("nan")
# what a withheld pair does not report (its counts stay: they describe, they test nothing)
PAIR_NUMBERS = ("p_value", "p_holm", "statistic", "odds_ratio", "rank_biserial", "rb_ci_low", "rb_ci_high", "difference", "se",
                "ci_low", "ci_high", "log_odds_ratio", "share_b", "share_b_low", "share_b_high")


@dataclass(frozen=True, kw_only=True)
class ConditionEvents(Record):
    """One condition's faults and safety events over its stored trials.

    - trials: its stored trials; affected_trials: those with any fault or safety event;
    - fault_trials: those with a fault; fault_share: fault_trials / trials (NaN without trials);
    - kinds: per event kind (faults, then safety events, in `FAULT_KINDS`/`SAFETY_KINDS` order),
      the trials that had it;
    - withheld: whether its tests are withheld (`FAULT_SHARE_MAX`); reason: why (None when not)."""

    condition: str
    trials: int
    affected_trials: int
    fault_trials: int
    fault_share: float
    kinds: Mapping[str, int]
    withheld: bool
    reason: str | None = None


def _counts(text) -> dict:
    try:
        events = json.loads(text) if isinstance(text, str) else {}
    except ValueError:
        return {}
    return {k: v for k, v in events.items() if k in FAULT_KINDS + SAFETY_KINDS and isinstance(v, int) and v > 0} if isinstance(events, dict) else {}


def condition_events(conditions, trial_events: pd.DataFrame) -> tuple[ConditionEvents, ...]:
    """Per condition (in `conditions`' order), its faults and safety events from `trial_events`
    (analysis.study.study_snapshot.Study.trial_events: code, model, trial, events as JSON)."""
    out = []
    for c in conditions:
        rows = [_counts(e) for e in trial_events.loc[trial_events["model"] == c, "events"]]
        n = len(rows)
        faulty = sum(1 for r in rows if any(k in FAULT_KINDS for k in r))
        kinds = {k: sum(1 for r in rows if k in r) for k in FAULT_KINDS + SAFETY_KINDS}
        share = faulty / n if n else NAN
        out_of_tests = n > 0 and share > FAULT_SHARE_MAX
        named = ", ".join(k for k in FAULT_KINDS if kinds[k])
        reason = (f"withheld: condition {c} had a model fault in {faulty} of its {n} trials ({named}), more than "
                  f"{FAULT_SHARE_MAX:.0%}" if out_of_tests else None)
        out.append(ConditionEvents(condition=c, trials=n, affected_trials=sum(1 for r in rows if r), fault_trials=faulty,
                                   fault_share=share, kinds={k: v for k, v in kinds.items() if v}, withheld=out_of_tests, reason=reason))
    return tuple(out)


def withheld(events) -> dict[str, str]:
    """The withheld conditions and why: {condition: reason}."""
    return {e.condition: e.reason for e in events if e.withheld}


def is_withheld(reason: str | None) -> bool:
    """Whether a test's `reason` is a withheld condition's (this module's wording)."""
    return bool(reason) and reason.startswith("withheld: condition ")


def involving(conditions, held: Mapping[str, str]) -> str | None:
    """Why a test of `conditions` is withheld (the first withheld one's reason), or None."""
    return next((held[c] for c in conditions if c in held), None)


def withhold_pairs(pairs: list[dict], held: Mapping[str, str]) -> list[dict]:
    """Pair dicts (a, b, p_value, ...) with those involving a withheld condition not tested:
    p-values, statistics and effect sizes NaN (so Holm leaves them out, and no effect of a fault
    is printed as the model's), no small-sample warning, and the reason."""
    out = []
    for p in pairs:
        why = involving((p["a"], p["b"]), held)
        out.append(p if why is None else p | {k: NAN for k in PAIR_NUMBERS if k in p} | {k: None for k in ("warning",) if k in p}
                   | {"reason": why})
    return out


def withhold_fit(fit: dict, held: Mapping[str, str], conditions) -> dict:
    """A model fit over `conditions` (a GEE, a mixed model: `problems`, `pairs`) withheld when one
    of them is: not estimable, every pair withheld (even one of two sound conditions: its
    contrast comes from the same withheld fit), the reason its problem."""
    why = involving(conditions, held)
    if why is None:
        return fit
    pairs = [p | {k: NAN for k in PAIR_NUMBERS if k in p} | {k: None for k in ("warning",) if k in p} | {"reason": why}
             | ({"estimable": False, "ci_low": NAN, "ci_high": NAN} if "estimable" in p else {}) for p in fit.get("pairs") or []]
    return fit | {"converged": False, "estimable": False, "problems": [*(fit.get("problems") or []), why], "pairs": pairs}


def rates_with_events(rates: pd.DataFrame, events) -> pd.DataFrame:
    """Table 1's rates (one row per question and condition) with each condition's events
    (`events_columns`), unchanged when no trial had one."""
    cols = events_columns(events)
    if not cols:
        return rates
    extra = pd.DataFrame([{"model": c, **v} for c, v in cols.items()])
    return rates.merge(extra, on="model", how="left")


def any_events(events) -> bool:
    return any(e.affected_trials for e in events)


def kinds_text(e: ConditionEvents) -> str:
    return ", ".join(f"{k} {v}" for k, v in e.kinds.items()) or "none"



def events_columns(events) -> dict[str, dict[str, object]]:
    """Per condition the CSV columns of its events (trials, trials_with_events, event_kinds,
    withheld_reason); {} when no trial had one (the CSV then keeps its columns)."""
    if not any_events(events):
        return {}
    return {e.condition: {"trials": e.trials, "trials_with_events": e.affected_trials, "event_kinds": kinds_text(e),
                          "withheld_reason": e.reason or ""} for e in events}
