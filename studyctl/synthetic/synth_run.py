"""A synthetic study: register N synthetic participants (codes, ages, fields, counterbalanced
orders, traits), run their sessions here, in local processes or on a Dask cluster, and store
each whole as it finishes (studyctl/synthetic/bundles.py). The participants themselves (motor and answer
models) are studyctl/synthetic/participant.py's."""

from __future__ import annotations

import random
import time
from pathlib import Path

from analysis.errors import InputError, Interrupted
from analysis.statistics.faults import condition_events, kinds_text
from brainsim_assets import path as asset
from sim.sweep import completed, reachable
from sim.text import counted
from studyctl.fields import field_rows, synthetic_fields
from studyctl.protocol import load_protocol
from studyctl.schedule import assign_order
from studyctl.session.lock import synth_lock
from studyctl.store import Store, init_study, now, roster
from studyctl.store.sessions import insert_traits, next_session_id
from studyctl.store.snapshot import discrimination, trial_events
from studyctl.synthetic.bundles import run_away, seed_for, store_bundle
from studyctl.synthetic.participant import MAX_SYNTHETIC, SyntheticParticipant, skill_for
from studyctl.synthetic.rig import keep_shipped


def run_synthetic_study(db, participants: int | None, seed: int = 0, jobs: int = 1, protocol_path=None, progress=None,
                        scheduler: str | None = None, alongside_people: bool = False, complete: bool = False) -> dict:
    """Register N synthetic participants, give them counterbalanced orders, run their sessions:
    in this process (jobs 1), in `jobs` local processes, or on the Dask cluster at `scheduler`.

    Codes, ages, orders, traits and session ids are assigned up front and in order, so orders,
    trials, forces and answers are the same for the same seed wherever and however the sessions
    run and however busy the machine (the observer reads no wall-clock time); measured times
    differ. Each session runs in a scratch study and is stored here as it finishes
    (studyctl/synthetic/bundles.py): a Dask worker that dies costs its participant's run, never a participant.

    Nothing the caller did not ask for: a database that does not exist is created only for a
    `protocol_path` given; a study with people registered takes synthetic sessions only
    `alongside_people` (its reports then say MIXED DATA). Participants registered by a run that
    was interrupted (Ctrl-C, a crash) are run by `complete` (True), with the seed they were
    registered with, which brings that run to its N; `participants` new ones (None: none) are
    then added. While such participants wait, new ones alone are refused (they would pool with
    them unasked). One synth at a time per study (studyctl/session/lock.py): a second one, with
    --complete or not, is refused while the first runs. Ctrl-C raises Interrupted saying what was stored and the command that completes it."""
    if participants is None and not complete:
        raise InputError("--participants: missing; give how many new synthetic participants (1..1000), "
                         "or --complete to finish an interrupted run")
    if participants is not None and not 1 <= participants <= MAX_SYNTHETIC:
        raise InputError(f"--participants: {participants} is out of range; allowed: 1..{MAX_SYNTHETIC}")
    if not 1 <= jobs <= 64:
        raise InputError(f"--jobs: {jobs} is out of range; allowed: 1..64")
    reachable(scheduler)  # an unreachable cluster is refused before anything is written
    created = None
    if not Path(db).exists():  # a new study only of the protocol the user names
        if complete:
            raise InputError(f"--complete: {db} does not exist; nothing to complete")
        if protocol_path is None:
            raise InputError(f"--db: {db} does not exist; give --protocol FILE to create a study of that protocol there "
                             f"(the paper's: {asset('protocols/brain_pull_2015.toml')}), or `studyctl study init` it first")
        init_study(db, protocol_path)
        created = str(protocol_path)
    # the lock held for the whole run: a second synth is told this one runs, not that it was interrupted
    with Store(db) as store, synth_lock(db):
        protocol = store.protocol()
        if protocol_path is not None and load_protocol(protocol_path).sha256 != protocol.sha256:
            raise InputError(f"--protocol: {protocol_path} is not the protocol {db} was created with; leave --protocol out")
        people = roster.participant_count(store, synthetic=False)
        if people and not alongside_people:
            raise InputError(f"--db: {db} is a study of people ({people} {'person' if people == 1 else 'people'} registered): synthetic "
                             "sessions would be pooled with theirs in every report; give --alongside-people to add them anyway "
                             "(reports then say MIXED DATA), or run them in a study of their own")
        pending = _unrun(store)
        _check_pending(db, pending, complete)
        codes = _register(store, protocol, participants, seed) if participants else []
        runs = pending + [(code, seed) for code in codes]
        t0, stored = time.perf_counter(), 0
        try:  # from the registration's commit on, an interruption leaves participants to complete
            first_id = next_session_id(store)
            seeds = [seed_for(store, code, s, first_id + k) for k, (code, s) in enumerate(runs)]
            for _, bundle in completed(run_away, seeds, jobs, scheduler):
                store_bundle(store, bundle)
                stored += 1  # counted once its transaction committed (Ctrl-C inside it rolls it back)
                if progress:
                    progress(stored, len(seeds))
        except (KeyboardInterrupt, Interrupted):  # Ctrl-C between sessions, or inside one (run_session's own Interrupted
            # names its scratch study, which is gone): either way the registered participants left are completed by --complete
            left = len(runs) - stored
            raise Interrupted(f"synth: interrupted after {stored} of {counted(len(runs), 'session')} (each stored whole); "
                              f"`studyctl synth --db {db} --complete` runs the {counted(left, 'registered participant')} "
                              f"left without one, completing this run's {len(runs)}") from None
        total = roster.synthetic_with_session(store)
        warnings = fault_warnings(list(protocol.conditions), trial_events(store))
        if protocol.tasks:  # the discrimination trials' intervals, counted apart (`report jnd` withholds from them)
            warnings += fault_warnings(list(protocol.conditions), discrimination(store), "discrimination trials")
    return {"participants": len(codes), "codes": codes, "seed": seed, "jobs": jobs, "scheduler": scheduler, "ran": len(runs),
            "total_synthetic": total, "warnings": warnings,
            "seconds": time.perf_counter() - t0, "protocol": protocol.name, "protocol_file": str(protocol.path), "created": created,
            "completed": [{"code": c, "seed": s} for c, s in pending]}


def fault_warnings(conditions: list[str], events, what: str = "trials") -> list[str]:
    """One line per condition whose stored trials are mostly model faults (analysis/statistics/faults.py): the
    data are kept (synth succeeds), and the reports withhold its tests; said here so that a
    broken model is not found only in a report."""
    return [f"condition {e.condition}: {e.fault_trials} of {e.trials} {what} had a model fault ({kinds_text(e)}); "
            "the reports withhold every test involving it" for e in condition_events(conditions, events) if e.withheld]


def _check_pending(db, pending: list, complete: bool) -> None:
    """Refuse new participants while an interrupted run's participants wait (they would run together,
    more sessions than asked), and --complete with nothing to complete."""
    if pending and not complete:
        n = len(pending)
        raise InputError(f"--db: {db} holds {n} synthetic participant{'s' if n != 1 else ''} an interrupted synth registered "
                         "without a session; give --complete to run them (with --participants N to add N more after)")
    if complete and not pending:
        raise InputError(f"--complete: {db} holds no synthetic participant an interrupted synth left without a session; nothing to complete")


def _unrun(store) -> list[tuple[str, int]]:
    """(code, seed) of the synthetic participants registered by a `synth` that did not finish:
    no session, not withdrawn; the seed they were registered with (their traits' rows)."""
    return [(r["code"], int(r["seed"])) for r in roster.unrun_synthetic(store) if r["seed"] is not None]


def _register(store, protocol, participants: int, seed: int) -> list[str]:
    """Register `participants` new synthetic codes (S001, S002, ... skipping codes in use) with
    ages, fields, orders and generating traits, in one transaction: all or none."""
    rng = random.Random(f"ages:{seed}")
    registered = roster.participant_codes(store)
    codes, k = [], 0
    while len(codes) < participants:
        k += 1
        if f"S{k:03d}" not in registered:
            codes.append(f"S{k:03d}")
    before = roster.participant_count(store, synthetic=True)
    values = synthetic_fields(protocol, codes, seed, start=before)  # groups in turn: balanced
    with store.transaction() as conn:
        for code in codes:
            person = {"code": code, "age": rng.randint(protocol.age_min, protocol.age_max), "synthetic": 1, "created_at": now()}
            roster.insert_participants(conn, [person], [], field_rows(code, values[code]))
            assign_order(store, protocol, code)
            # its traits (and so its seed) kept now: a run interrupted before its session is
            # completed by the next `synth`, with this seed
            drawn = SyntheticParticipant.draw(code, seed, skill_for(store, protocol, code))
            insert_traits(conn, code, drawn.trait_values(), seed)
    keep_shipped(store)  # the frame times its synthetic participants perceive, kept with the study
    return codes
