"""A study database read once: everything the analyses use, as an immutable snapshot.

`read_study(store)` reads it from an open `studyctl.store.Store` (the caller opens and closes
it: `with Store(path, mode="read") as store: study = read_study(store)`); every function of
analysis/table1.py, stats.py, kinds.py and report.py that looks at a study takes the `Study`,
so a report reads the database once and never opens it itself. The snapshot's tables are
never changed by the analyses (each works on copies).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import pandas as pd

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
    - `periods`: each participant's position (0-based) of each condition in their session:
      ``code, model, period`` (the session's order, else the assigned one);
    - `latency`: each participant's mean deformation time per condition: ``code, model, value, trials``;
    - `latency_trials`: every trial's deformation time: ``model, value``;
    - `configurations`: what each condition ran: ``condition, config, config_sha256, sessions``;
    - `discrimination`: every discrimination trial: ``code, model, task, trial, delta, comparison_interval,
      answer, correct, state (the procedure's, JSON), source``, and `traits` every synthetic participant's generating traits: ``code, trait, value``.
    """

    protocol: object
    answers: pd.DataFrame
    synthetic_participants: int
    person_participants: int
    mixed_source_participants: tuple[str, ...]
    periods: pd.DataFrame
    latency: pd.DataFrame
    latency_trials: pd.DataFrame
    configurations: pd.DataFrame
    discrimination: pd.DataFrame
    traits: pd.DataFrame


def read_study(store) -> Study:
    """The snapshot of the study in `store` (an open studyctl.store.Store), read in one go."""
    con = store.db.conn

    def query(sql: str) -> pd.DataFrame:
        return pd.read_sql_query(sql, con)

    # counted from the answers' own source, not from a participant flag that could drift
    synthetic = con.execute("select count(distinct code) from answers where source = 'synthetic'").fetchone()[0]
    persons = con.execute("select count(distinct code) from answers where source != 'synthetic'").fetchone()[0]
    mixed = tuple(r[0] for r in con.execute(
        "select code from answers group by code having sum(source = 'synthetic') > 0 and sum(source != 'synthetic') > 0 order by code"))
    orders = pd.concat([query("select code, conditions from sessions order by id"), query("select code, conditions from schedule")])
    return Study(
        protocol=store.protocol(),
        answers=query("select code, model, item, trial, answer from answers"),
        synthetic_participants=synthetic,
        person_participants=persons,
        mixed_source_participants=mixed,
        periods=_periods(orders),
        latency=query("select s.code, l.model, avg(l.value) as value, count(*) as trials from latency l join sessions s on s.id = l.session_id "
                      "where l.measure = 'deformation_ms' group by s.code, l.model"),
        latency_trials=query("select model, value from latency where measure = 'deformation_ms'"),
        configurations=query("select model as condition, config, config_sha256, count(distinct session_id) as sessions "
                             "from conditions group by model, config_sha256 order by min(session_id)"),
        discrimination=query("select code, model, task, trial, delta, comparison_interval, answer, correct, state, source from discrimination "
                             "order by code, model, task, trial"),
        traits=query("select code, trait, value from synthetic_traits order by code, trait"),
    )


def _periods(orders: pd.DataFrame) -> pd.DataFrame:
    """The period factor of the GEE from each participant's condition orders (sessions first,
    then the schedule): the first session's order wins."""
    orders = orders[orders["conditions"].notna()].drop_duplicates("code")
    rows = [{"code": r.code, "model": m, "period": k} for r in orders.itertuples() for k, m in enumerate(json.loads(r.conditions))]
    return pd.DataFrame(rows, columns=["code", "model", "period"])
