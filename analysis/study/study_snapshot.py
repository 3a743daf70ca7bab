"""A study database read once: everything the analyses use, as an immutable snapshot.

`studyctl.store.snapshot.read_study(store)` reads it from an open store (the caller opens and
closes it: `with Store(path, mode="read") as store: study = read_study(store)`); every report takes
the `Study` (Table 1, the statistics, the JND, construct validity, the performance metrics),
so a report reads the database once and never opens it itself; only the trace files of the
traced trials are read later, from beside `path`. The snapshot's tables are
never changed by the analyses (each works on copies).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from analysis.study.completeness import Completeness
from analysis.study.protocol_view import StudyProtocol

SYNTHETIC_FLAG = "SYNTHETIC DATA (simulated participants): not evidence about people."


def data_flag(persons: int, synthetic: int) -> str:
    """What a report says first about whose data it holds: nothing for people only, the
    synthetic flag for simulated participants only, and, pooled, how many of each."""
    if synthetic and persons:
        return (f"MIXED DATA: {persons} {'person' if persons == 1 else 'people'} and {synthetic} SYNTHETIC (simulated) "
                f"participant{'s' if synthetic != 1 else ''} pooled; not evidence about people as it stands.")
    return SYNTHETIC_FLAG if synthetic else ""


@dataclass(frozen=True, eq=False)
class Study:
    """What the analyses read of one study database.

    - `protocol`: the study's protocol (studyctl.protocol.Protocol), as stored with it;
    - `answers`: every stored answer: ``code, model, item, trial, answer`` (each in its kind's type);
    - `synthetic_participants`, `person_participants`: how many participants answered
      synthetically, and as people (from the answers' own source, not a participant flag);
      `mixed_source_participants`: the codes that answered both ways;
    - `completeness`: who is complete, who is not, and each one's kind (analysis.study.completeness:
      the one rule behind N, the banners, the lists of the incomplete and `studyctl status`);
    - `periods`: each participant's position (0-based) of each condition in their session:
      ``code, model, period`` (the session's order, else the assigned one);
    - `latency`: each participant's mean deformation time per condition: ``code, model, value, trials``;
    - `latency_trials`: every trial's deformation time: ``model, value``;
    - `configurations`: what each condition ran: ``condition, config, config_sha256, sessions, software_versions``;
    - `discrimination`: every discrimination trial: ``code, model, task, trial, delta, comparison_interval,
      answer, correct, state (the procedure's, JSON), source, events`` (both intervals' servo events, JSON, as
      `trial_events`' are: a task's faults are counted from them), and `traits` every synthetic participant's generating traits: ``code, trait, value``;
    - `path`: the database file (trace paths are relative to its folder);
    - `synthetic_codes`: the codes registered as synthetic or with a synthetic answer;
    - `fields`: every participant's protocol fields, typed by their kind: ``code, field, value``;
    - `traced_trials`: every trial with a stored trace: ``code, synthetic, model, trial, session_id,
      trace_path, trace_sha256``;
    - `setups`: how the finished sessions ran: ``device, software_version, synthetic, sessions``;
    - `latencies`: every latency measure per condition: ``measure, model, trials, mean, lowest, highest``;
    - `trial_events`: every stored trial's servo events: ``code, model, trial, events`` (JSON: kind to count),
      what a condition's faults are counted from (analysis/statistics/faults.py).
    """

    protocol: StudyProtocol
    answers: pd.DataFrame
    synthetic_participants: int
    person_participants: int
    mixed_source_participants: tuple[str, ...]
    completeness: Completeness
    periods: pd.DataFrame
    latency: pd.DataFrame
    latency_trials: pd.DataFrame
    configurations: pd.DataFrame
    discrimination: pd.DataFrame
    traits: pd.DataFrame
    path: Path
    synthetic_codes: tuple[str, ...]
    fields: pd.DataFrame
    traced_trials: pd.DataFrame
    setups: pd.DataFrame
    latencies: pd.DataFrame
    trial_events: pd.DataFrame
