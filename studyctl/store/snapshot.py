"""What the reports read of a study, and `read_study`, which reads it into analysis.study.study_snapshot.Study: the answers and the
counts of whose they are, the condition orders, the deformation latencies, the configurations
each condition ran, the discrimination trials, the synthetic traits, the synthetic codes and the
traced trials behind the performance metrics. Each is a function of
an open `Store`; tables come back as pandas DataFrames exactly as pandas reads the query (its
column names, dtypes and row order), since the reports built from them must not change."""

from __future__ import annotations

import json

import pandas as pd

from analysis.study.completeness import Completeness
from analysis.study.completeness import completeness as count_complete
from analysis.study.study_snapshot import Study
from studyctl.store.database import Store
from studyctl.store.participant_fields import read_fields


def _frame(store: Store, sql: str) -> pd.DataFrame:
    return pd.read_sql_query(sql, store.db.conn)


# counted from the answers' own source, not from a participant flag that could drift
def synthetic_count(store: Store) -> int:
    """How many participants have synthetic answers."""
    return store.db.conn.execute("select count(distinct code) from answers where source = 'synthetic'").fetchone()[0]


def person_count(store: Store) -> int:
    """How many participants have answers not synthetic (a person's)."""
    return store.db.conn.execute("select count(distinct code) from answers where source != 'synthetic'").fetchone()[0]


def mixed_source_codes(store: Store) -> tuple[str, ...]:
    """The codes with both synthetic answers and a person's, in code order."""
    return tuple(r[0] for r in store.db.conn.execute(
        "select code from answers group by code having sum(source = 'synthetic') > 0 and sum(source != 'synthetic') > 0 order by code"))


def condition_orders(store: Store) -> pd.DataFrame:
    """code, conditions (JSON) of every session in id order, then of every schedule row."""
    return pd.concat([_frame(store, "select code, conditions from sessions order by id"),
                      _frame(store, "select code, conditions from schedule")])


def answers(store: Store) -> pd.DataFrame:
    """Every stored answer: code, model, item, trial, answer."""
    return _frame(store, "select code, model, item, trial, answer from answers")


def answer_sources(store: Store) -> pd.DataFrame:
    """Each participant's answer sources: code, source (one row per distinct pair)."""
    return _frame(store, "select distinct code, source from answers order by code")


def completeness(store: Store, protocol, only: set[str] | None = None, stored: pd.DataFrame | None = None) -> Completeness:
    """Who is complete, who is not and of which kind (analysis.study.completeness: the one rule every
    count uses); `only`: count these codes alone; `stored`: `answers(store)` where the caller
    has read it already."""
    return count_complete(protocol, answers(store) if stored is None else stored, answer_sources(store), only)


def latency(store: Store) -> pd.DataFrame:
    """Each participant's mean deformation time per condition: code, model, value, trials."""
    return _frame(store, "select s.code, l.model, avg(l.value) as value, count(*) as trials from latency l join sessions s on s.id = l.session_id "
                         "where l.measure = 'deformation_ms' group by s.code, l.model")


def latency_trials(store: Store) -> pd.DataFrame:
    """Every trial's deformation time: model, value."""
    return _frame(store, "select model, value from latency where measure = 'deformation_ms'")


def configurations(store: Store) -> pd.DataFrame:
    """What each condition ran: condition, config, config_sha256, sessions, software_versions (the
    distinct software versions of those sessions, comma-separated); in order of first session."""
    return _frame(store, "select c.model as condition, c.config, c.config_sha256, count(distinct c.session_id) as sessions, "
                         "group_concat(distinct s.software_version) as software_versions "
                         "from conditions c left join sessions s on s.id = c.session_id "
                         "group by c.model, c.config_sha256 order by min(c.session_id)")


def discrimination(store: Store) -> pd.DataFrame:
    """Every discrimination trial: code, model, task, trial, delta, comparison_interval, answer, correct, state, source, events
    (its two intervals' servo events, JSON; NULL before schema 10)."""
    return _frame(store, "select code, model, task, trial, delta, comparison_interval, answer, correct, state, source, events from discrimination "
                         "order by code, model, task, trial")


def traits(store: Store) -> pd.DataFrame:
    """Every synthetic participant's generating traits: code, trait, value."""
    return _frame(store, "select code, trait, value from synthetic_traits order by code, trait")


def synthetic_codes(store: Store) -> tuple[str, ...]:
    """The codes registered as synthetic or with a synthetic answer, in code order."""
    return tuple(r[0] for r in store.db.conn.execute(
        "select code from participants where synthetic union select code from answers where source = 'synthetic' order by code"))


def traced_trials(store: Store) -> pd.DataFrame:
    """Every traced trial with its participant: code, synthetic, model, trial, session_id,
    trace_path, trace_sha256, by code, condition, trial, then session."""
    return _frame(store, "select s.code, p.synthetic, t.model, t.trial, t.session_id, t.trace_path, t.trace_sha256 from trials t "
                         "join sessions s on s.id = t.session_id join participants p on p.code = s.code "
                         "where t.trace_path is not null order by s.code, t.model, t.trial, t.session_id")


def session_setups(store: Store) -> pd.DataFrame:
    """How the finished sessions ran: device, software_version, synthetic, sessions (a count)."""
    return _frame(store, "select device, software_version, synthetic, count(*) as sessions from sessions where status = 'done' "
                         "group by device, software_version, synthetic order by min(id)")


def latency_summary(store: Store) -> pd.DataFrame:
    """Every latency measure per condition over the trials: measure, model, trials, mean, lowest, highest."""
    return _frame(store, "select measure, model, count(*) as trials, avg(value) as mean, min(value) as lowest, max(value) as highest "
                         "from latency group by measure, model order by measure, model")


def trial_events(store: Store) -> pd.DataFrame:
    """Every stored trial's servo events: code, model, trial, events (JSON), by code, condition, trial."""
    return _frame(store, "select s.code, t.model, t.trial, t.events from trials t join sessions s on s.id = t.session_id "
                         "order by s.code, t.model, t.trial, t.session_id")


def read_study(store) -> Study:
    """The snapshot of the study in `store` (an open studyctl.store.Store), read in one go."""
    # counted from the answers' own source, not from a participant flag that could drift
    synthetic = synthetic_count(store)
    persons = person_count(store)
    mixed = mixed_source_codes(store)
    orders = condition_orders(store)
    protocol = store.protocol()
    stored = answers(store)  # read once: the answers and who is complete among them
    fields = [{"code": code, "field": k, "value": v} for code, values in read_fields(store, protocol).items() for k, v in values.items()]
    return Study(
        protocol=protocol,
        answers=stored,
        synthetic_participants=synthetic,
        person_participants=persons,
        mixed_source_participants=mixed,
        completeness=completeness(store, protocol, stored=stored),
        periods=_periods(orders),
        latency=latency(store),
        latency_trials=latency_trials(store),
        configurations=configurations(store),
        discrimination=discrimination(store),
        traits=traits(store),
        path=store.path,
        synthetic_codes=synthetic_codes(store),
        fields=pd.DataFrame(fields, columns=["code", "field", "value"], dtype=object),
        traced_trials=traced_trials(store),
        setups=session_setups(store),
        latencies=latency_summary(store),
        trial_events=trial_events(store),
    )


def _periods(orders: pd.DataFrame) -> pd.DataFrame:
    """The period factor of the GEE from each participant's condition orders (sessions first,
    then the schedule): the first session's order wins."""
    orders = orders[orders["conditions"].notna()].drop_duplicates("code")
    rows = [{"code": r.code, "model": m, "period": k} for r in orders.itertuples() for k, m in enumerate(json.loads(r.conditions))]
    return pd.DataFrame(rows, columns=["code", "model", "period"])
