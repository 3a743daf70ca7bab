"""A session: training, then each condition in the participant's order (trials on the
simulator, then the questionnaire), every trial and answer committed when it happens.

Blind: each session labels its conditions A, B, C in a random order (stored with the
conditions; exports and reports show it). Nothing a participant sees or the terminal prints
names a model or a parameter: only "condition 2 of 3" and the label.

A person's session (real time) is paced by the participant: training with a visible countdown
that the experimenter may end early (E in the window, Enter in the terminal); a trial starts at
the first grasp (or the experimenter's SPACE / Enter), lasts the protocol's trial time, and a
rest screen follows. Synthetic sessions run in lockstep at full speed.

Every trial's per-tick trace is written durably before its row (studyctl/session/traces.py). Answers
computed from a condition's trials (the synthetic answer model) read every stored trace of that
condition, so a resumed session answers as an uninterrupted one would.

`--resume` continues an interrupted session after its last committed trial or answer: nothing
is lost (beyond the trial in flight) and nothing is done twice.
"""

from __future__ import annotations

import contextlib
import json
import math
import random
import signal
import string
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from analysis.errors import InputError, Interrupted, StoreError
from analysis.study.questions import NOT_PER_TRIAL, SESSION, Kind
from analysis.study.trace_files import trace_dir, write_trace
from analysis.verification.truth import load_truth
from sim.run import Pacing, run_scene
from sim.servo.process import ServoProcess
from sim.text import counted
from studyctl.conditions import (
    SOFTWARE_VERSION,
    condition_configs,
    condition_scene,
    config_json,
    config_sha256,
    scene_itself,
)
from studyctl.participants import has_consent
from studyctl.schedule import assign_order
from studyctl.session.asking import TerminalAnswers, flush_input, terminal_keys
from studyctl.session.discrimination import run_task
from studyctl.session.lock import session_lock
from studyctl.session.traces import trial_traces
from studyctl.session.window_answers import WindowAnswers
from studyctl.store import Store, dumps, now, roster, sha256_file
from studyctl.store import sessions as session_rows
from studyctl.store.trials import discrimination_done
from studyctl.synthetic.participant import SyntheticAnswers, SyntheticParticipant, skill_for
from studyctl.synthetic.rig import frame_times

OPEN = ("running", "interrupted")  # a session to resume: killed while running, or stopped with Ctrl-C
TRAINING_MODEL = "plate_spring"  # free exploration before the first condition (never named on screen)


def _unasked(store: Store, questions, code: str, model: str, trial: int) -> list:
    """Those of `questions` not yet answered for this condition (and trial)."""
    done = session_rows.answered_items(store, code, model, trial)
    return [q for q in questions if q.id not in done]


def _ask(store: Store, answerer, questions, code: str, model: str, trial: int, session_id: int, context: dict, about: str) -> None:
    """Ask what is still unanswered of `questions`, each answer committed as it is given, in its
    kind's type (a yes/no as 0/1)."""
    todo = _unasked(store, questions, code, model, trial)
    if not todo:
        return
    answerer.begin(about)
    for q in todo:
        value = answerer(q, model, context)
        session_rows.record_answer(store, code, model, q.id, trial, int(bool(value)) if q.kind == Kind.YES_NO else value, session_id,
                                   answerer.source)


def condition_labels(models, rng) -> dict[str, str]:
    """A blind label per condition: A, B, C... in a random order."""
    letters = list(string.ascii_uppercase[: len(models)])
    rng.shuffle(letters)
    return dict(zip(models, letters))


def _trial_record(session_id: int, model: str, trial: int, started: str, result) -> tuple[dict, list[dict]]:
    s = result.stats()
    d = result.deformation_s * 1e3
    rec = {
        "session_id": session_id, "model": model, "trial": trial, "started_at": started, "ended_at": now(),
        "max_force_n": s["max_force_n"],
        "deformation_ms_mean": float(d.mean()) if len(d) else None,
        "deformation_ms_p99": s["deformation_ms"]["p99"],
        "tick_interval_p99_us": s["tick_interval_us"]["p99"],
        "read_to_force_us": s["read_to_force_us"]["p50"],
        "tick_compute_us": s["tick_compute_us"]["p50"],
        "events": dumps(s["events"] | ({"ended_early": result.ended_early} if result.ended_early else {})),
        "grasped": int(any(e.kind == "grasp" for e in result.events)),
        "started_by": result.started_by,
        "waited_s": result.waited_s,
    }
    lat = []
    for measure, value in (("deformation_ms", rec["deformation_ms_mean"]), ("tick_interval_p99_us", rec["tick_interval_p99_us"]),
                           ("read_to_force_us", rec["read_to_force_us"]), ("tick_compute_us", rec["tick_compute_us"])):
        if value is not None and math.isfinite(value):
            lat.append({"session_id": session_id, "model": model, "trial": trial, "measure": measure, "value": float(value)})
    return rec, lat


def _rest_screen(view, seconds: float, status: str, message: str, keys=None) -> None:
    """A rest screen with a countdown (text in the view, if any); SPACE / Enter skips it."""
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        if view is not None:
            view.set_text(top=status, center=f"{message}: {math.ceil(left)} s", bottom="", question="", corner="")
            view.idle()
            pressed = view.take_keys()
        else:
            time.sleep(min(left, 0.1))
            pressed = []
        pressed += keys() if keys is not None else []
        if any(k in ("space", "enter") for k in pressed):
            return


def _check_options(device: str, synthetic: bool, time_scale: float | None, view: str, answer_with: str) -> float:
    """Refuse impossible combinations before anything is opened or written; the time scale."""
    if time_scale is not None and not (math.isfinite(time_scale) and 0 <= time_scale <= 1000):
        raise InputError(f"--time-scale: {time_scale!r} is out of range; allowed: 0..1000")
    if time_scale is None:
        time_scale = 0.0 if synthetic else 1.0
    if view not in ("none", "window"):
        raise InputError(f"--view: {view!r} is not none or window")
    if view == "window" and time_scale <= 0:
        raise InputError("--view window: the participant view needs real time (--time-scale > 0)")
    if device in ("openhaptics", "mouse") and time_scale <= 0:
        raise InputError(f"--device {device}: a person's device runs in real time only; leave out --time-scale 0")
    if device == "mouse" and view != "window":
        raise InputError("--device mouse: the mouse drives the hands in the participant view; add --view window")
    if answer_with == "window" and view != "window":
        raise InputError("--answers window: answering with keys in the window needs --view window")
    return time_scale


def _check_participant(store: Store, protocol, code: str, synthetic: bool) -> None:
    """Registered, not withdrawn, not done; a person or synthetic, never both; answers from one
    source; a person has signed the protocol's consent form."""
    person = roster.person(store, code)
    if person is None:
        raise StoreError(f"participant {code}: not registered; add with `studyctl participants add`")
    if person["withdrawn_at"]:
        raise StoreError(f"participant {code}: withdrew on {person['withdrawn_at'][:10]}; no further sessions")
    if session_rows.has_done_session(store, code):
        raise StoreError(f"participant {code}: the session is already complete")
    registered_synthetic = bool(person["synthetic"])
    if synthetic and not registered_synthetic:
        raise StoreError(f"participant {code}: registered as a person; --synthetic runs only participants registered "
                         "as synthetic (`studyctl synth`, or `participants add --synthetic`)")
    if not synthetic and registered_synthetic:
        raise StoreError(f"participant {code}: registered as synthetic; a person's session needs a person's code (or add --synthetic)")
    imported = session_rows.imported_answers(store, code)
    if imported:
        raise StoreError(f"participant {code}: already has {imported} answers imported from another source; "
                         "a simulator session would mix sources")
    if not synthetic and not has_consent(store, code, protocol.consent_version):
        raise StoreError(f"participant {code}: no consent recorded for consent form {protocol.consent_version!r}; "
                         f"record it with `studyctl participants consent {code}`")


def run_session(db, code: str, device: str = "simulated", synthetic: bool = False, resume: bool = False,
                time_scale: float | None = None, *args, view: str = "none", answer_with: str = "terminal", **kwargs) -> dict:
    """Run (or with `resume`, continue) participant `code`'s session; see `_run_session`. One
    process at a time drives a participant's session (studyctl/session/lock.py)."""
    time_scale = _check_options(device, synthetic, time_scale, view, answer_with)
    with Store(db) as store:  # a missing, foreign, read-only or older database, or the wrong participant: no lock file made
        _check_participant(store, store.protocol(), code, synthetic)
        open_ = session_rows.open_sessions(store, code, OPEN)
        if resume and not open_:
            raise StoreError(f"participant {code}: no interrupted session to resume")
        if resume and open_[0]["device"] != device:  # said before any device or window is opened
            raise StoreError(f"participant {code}: session {open_[0]['id']} was started with --device {open_[0]['device']}, "
                             f"not {device}; resume it with --device {open_[0]['device']}")
    with _ctrl_c_shield() as shield, session_lock(db, code):
        return _run_session(db, code, device, synthetic, resume, time_scale, *args, view=view, answer_with=answer_with,
                            shield=shield, **kwargs)


@contextlib.contextmanager
def _ctrl_c_shield():
    """A function that, called at the first Ctrl-C, ignores further ones until the block ends:
    the session is marked interrupted, its servo and view closed, its store and lock released
    whole, and the line saying how to resume reaches the user (a second Ctrl-C used to cut that
    short and leave no line). The previous handler is restored at the end."""
    old = []

    def shield() -> None:
        if not old and threading.current_thread() is threading.main_thread():  # signals are set in the main thread only
            old.append(signal.signal(signal.SIGINT, signal.SIG_IGN))

    try:
        yield shield
    finally:
        if old:
            signal.signal(signal.SIGINT, old[0])


@dataclass
class _Run:
    """What every step of one session's run uses: the study, the participant, the session's
    row, how it is run and shown, and who answers."""

    db: object
    store: Store
    protocol: object
    code: str
    device: str
    time_scale: float
    say: Callable[[str], None]
    shown: object = None  # the participant view, if any
    servo: object = None  # the session's servo process (real time)
    session_id: int | None = None
    labels: dict = field(default_factory=dict)  # model -> blind label
    answerer: object = None
    participant: object = None  # a synthetic participant's generating traits
    seed: int | None = None  # the session's seed (synthetic)
    paced: bool = False  # a person sets the pace
    keys: Callable | None = None  # the experimenter's terminal keys


def _run_session(db, code: str, device: str = "simulated", synthetic: bool = False, resume: bool = False,
                time_scale: float | None = None, answers=None, seed: int | None = None, progress: Callable[[str], None] | None = None,
                session_id: int | None = None, view: str = "none", answer_with: str = "terminal", device_names: list[str] | None = None,
                fullscreen: bool = False, shield: Callable[[], None] = lambda: None) -> dict:
    with Store(db) as store:  # closed last, after the servo and the view
        run = _Run(db=db, store=store, protocol=None, code=code, device=device, time_scale=time_scale, say=progress or (lambda msg: None))
        try:
            protocol = run.protocol = store.protocol()
            first = condition_scene(protocol, protocol.conditions[0], device)
            if device_names is not None:
                first.device_names = device_names
            # before anything is written: no display or no device is a clean error, not a half-made session
            if view == "window":
                from sim.view.window import open_view  # lazy: OpenGL, matplotlib, numba: not in a synthetic worker

                run.shown = open_view("window", first, show_force=device == "mouse", fullscreen=fullscreen)
            if time_scale > 0:  # one servo process for the session: devices opened once, kept across trials
                run.servo = ServoProcess(first, time_scale)
            _check_participant(store, protocol, code, synthetic)  # again, now that this process holds the lock
            order, seed = _open_session(run, synthetic, resume, seed, session_id)
            run.seed = seed
            run.labels = {r["model"]: r["label"] or chr(ord("A") + r["position"])
                          for r in session_rows.condition_labels(store, run.session_id)}
            if answers is None and synthetic:
                answers = _synthetic_answers(run, seed)
            run.paced = time_scale > 0 and not synthetic  # a person sets the pace
            run.answerer = answers or (WindowAnswers(run.shown) if answer_with == "window" else TerminalAnswers(view=run.shown))
            run.keys = terminal_keys if run.paced else None
            _training(run)
            for pos, model in enumerate(order):
                _run_condition(run, pos, model, len(order))
            _ask_at_the_end(run)
            session_rows.session_done(store, run.session_id)
            if run.shown is not None:
                run.shown.set_text(top="", center="Thank you: the session is complete", bottom="", question="", corner="")
                run.shown.idle()
            n = session_rows.answer_count(store, code)
            return {"session": run.session_id, "participant": code, "order": [run.labels[m] for m in order], "answers": n, "synthetic": synthetic}
        except KeyboardInterrupt:
            shield()
            raise Interrupted(_interrupted(run, synthetic)) from None
        finally:
            if run.servo is not None:
                run.servo.close()
            if run.shown is not None:
                run.shown.close()


def _interrupted(run: _Run, synthetic: bool) -> str:
    """Ctrl-C: the session marked `interrupted` at once (the trial in flight is not kept: a trial
    row is written only whole); what to type to go on."""
    if run.session_id is None:
        return f"session of {run.code}: interrupted before it started; nothing was written"
    store = run.store
    session_rows.mark_interrupted(store, run.session_id)
    store.event(run.session_id, "interrupted")
    trials = session_rows.trial_count(store, run.session_id)
    again = f"studyctl session run --db {run.db} --participant {run.code}" + (" --synthetic" if synthetic else "") + \
        (f" --device {run.device}" if run.device != "simulated" else "") + " --resume"
    return (f"session {run.session_id} of {run.code} interrupted ({trials} trial{'s' if trials != 1 else ''} kept; the one in "
            f"flight, if any, is not); resume it with: {again}")


def _open_session(run: _Run, synthetic: bool, resume: bool, seed: int | None, session_id: int | None) -> tuple[list[str], int]:
    """The participant's running session, resumed (checked: same options, seed and condition
    configurations), or a new one written with its conditions. Sets `run.session_id`; returns
    the participant's condition order and the session's seed."""
    store, protocol, code, device, say = run.store, run.protocol, run.code, run.device, run.say
    sessions = session_rows.participant_sessions(store, code)
    running = [s for s in sessions if s["status"] in OPEN]
    if running and not resume and not session_rows.has_trials_or_answers(store, running[0]["id"]):
        # interrupted before its first trial (e.g. in training): nothing of it is kept, start afresh
        session_rows.discard_session(store, running[0]["id"])
        say(f"discarded session {running[0]['id']} of {code}: it stopped before its first trial")
        running = []
    if running and not resume:
        raise StoreError(f"participant {code}: a session was interrupted; continue it with --resume")
    if resume and not running:
        raise StoreError(f"participant {code}: no interrupted session to resume")
    order = assign_order(store, protocol, code)
    if running and (bool(running[0]["synthetic"]), running[0]["device"]) != (synthetic, device):
        was = running[0]
        raise StoreError(f"participant {code}: session {was['id']} was started with --device {was['device']}"
                         f"{' --synthetic' if was['synthetic'] else ''}; resume it with the same options")
    stored = running[0].get("seed") if running and synthetic else None
    if stored is not None and seed is not None and seed != stored:
        raise StoreError(f"participant {code}: session {running[0]['id']} was started with --seed {stored}; "
                         f"resume it with the same seed (or leave --seed out)")
    # the session's own seed on a resume; else the one given; else 0 (also a session from
    # before seeds were stored)
    seed = stored if stored is not None else (0 if seed is None else seed)
    configs = condition_configs(protocol, order)  # before anything is written: a condition that fails is a clean error
    if running:
        run.session_id = running[0]["id"]
        for r in session_rows.condition_shas(store, run.session_id):
            now_sha = config_sha256(configs[r["model"]]) if r["model"] in configs else None
            if r["config_sha256"] and now_sha != r["config_sha256"]:
                raise StoreError(f"participant {code}: condition {r['model']!r} of session {run.session_id} ran configuration "
                                 f"{r['config_sha256'][:12]}; the protocol's scene now gives another (its scene or parameter "
                                 f"files changed): resuming would mix the two")
        store.event(run.session_id, "resumed")
        say(f"resuming session {run.session_id} of {code}")
        return order, seed

    folder = trace_dir(run.db)
    try:  # where the traces go, checked before the session is recorded
        folder.mkdir(exist_ok=True)
    except OSError as exc:
        raise StoreError(f"{folder}: cannot hold the trial traces: {exc.strerror}") from None
    rng = random.Random(f"labels:{seed}:{code}") if synthetic else random.SystemRandom()
    labels = condition_labels(order, rng)
    run.session_id = session_rows.open_session(store, code, synthetic, device, protocol.sha256, sha256_file(protocol.scene),
                                               SOFTWARE_VERSION, json.dumps(order), seed if synthetic else None, session_id)
    for pos, model in enumerate(order):
        session_rows.add_condition(store, run.session_id, pos, model, labels[model], config_json(configs[model]),
                                   config_sha256(configs[model]))
    return order, seed


def _synthetic_answers(run: _Run, seed: int):
    """A synthetic participant drawn from the code and seed, answering from what it perceives on
    the study's rig; sets `run.participant` (its motor traits drive the simulated hands)."""

    # its group's skill profile ([synthetic.groups.NAME]), if the protocol gives one
    run.participant = SyntheticParticipant.draw(run.code, seed, skill_for(run.store, run.protocol, run.code))
    # what it was drawn with, kept: estimates can be checked against it
    session_rows.keep_synthetic_traits(run.store, run.code, run.participant.trait_values(), seed)
    base = scene_itself(run.protocol)  # the scene's own configuration, whatever the conditions change
    rig = {c: v["frame_ms"] for c, v in frame_times(run.protocol, run.store).items()}  # the rig this study runs on
    return SyntheticAnswers(run.participant, load_truth(base), base.mesh, rig=rig)


def _training(run: _Run) -> None:
    """Free pulling before the first condition (once per session; the experimenter may end it)."""
    store, protocol, shown = run.store, run.protocol, run.shown
    if "training_done" in session_rows.event_kinds(store, run.session_id):
        return
    seconds = protocol.training_minutes * 60.0
    ran, early = 0.0, None
    if run.time_scale > 0 and seconds > 0:
        run.say(f"training: {counted(float(protocol.training_minutes), 'minute')} of free pulling; the experimenter ends it early with "
                + ("E in the window or " if shown is not None else "") + "Enter in the terminal")

        def training_caption(phase, left):
            return {"top": "Training", "center": f"Pull the brain freely: {int(left) // 60}:{int(left) % 60:02d} left",
                    "bottom": "Experimenter: E ends the training", "question": ""}

        pacing = Pacing(view=shown, caption=training_caption, stop_keys=("e", "enter"), keys=run.keys, notify=run.say) if run.paced or shown else None
        flush_input()
        result = run_scene(condition_scene(protocol, TRAINING_MODEL, run.device), duration=seconds, time_scale=run.time_scale, pacing=pacing,
                           servo=run.servo)
        if shown is not None:
            shown.at_rest()
        ran, early = (result.times[-1] if len(result.times) else 0.0), result.ended_early
    store.event(run.session_id, "training_done", dumps({"planned_s": seconds, "ran_s": round(float(ran), 3), "time_scale": run.time_scale,
                                                        "ended_early": early is not None, "by": early}))


def _run_condition(run: _Run, pos: int, model: str, n_cond: int) -> None:
    """One condition: its trials not yet stored (each followed by the per-trial questions),
    what the synthetic observer perceived, then the condition's questions."""
    store, protocol, code, session_id = run.store, run.protocol, run.code, run.session_id
    label = run.labels[model]
    status = f"Condition {label} ({pos + 1} of {n_cond})"
    done_trials = session_rows.done_trials(store, session_id, model)
    scene = None
    for trial in range(protocol.trials_per_condition):
        if trial not in done_trials:
            scene = scene or _loaded(run, protocol, model, status)
            _run_trial(run, scene, pos, model, trial, status)
        # the questions asked after every trial (a resume asks what an interruption left unasked)
        if _unasked(store, protocol.asked("trial"), code, model, trial):
            _ask(store, run.answerer, protocol.asked("trial"), code, model, trial, session_id,
                 {"labels": run.labels, "trial": trial, "results": trial_traces(store, session_id, model, trial)},
                 f"{status}, after trial {trial + 1}")
    for task in protocol.tasks:  # after the free trials: the condition's model is familiar by then
        if len(discrimination_done(store, session_id, model, task.index)) < task.trials:
            scene = scene or _loaded(run, protocol, model, status)
            run_task(run, scene, pos, model, task, status)
    results = None  # every stored trial of the condition, resumed or not: read once, when needed
    if protocol.trials_per_condition and hasattr(run.answerer, "features_of") and not session_rows.has_observer_features(
            store, code, model):
        # what the observer perceived, from every stored trace of the condition (after a
        # resume too), kept before the answers drawn from it
        results = trial_traces(store, session_id, model)
        feats = run.answerer.features_of(model, results)
        at = now()
        session_rows.keep_observer_features(store, code, model, feats, session_id, at)
    if _unasked(store, protocol.asked("condition"), code, model, NOT_PER_TRIAL):
        results = results if results is not None else trial_traces(store, session_id, model)
        _ask(store, run.answerer, protocol.asked("condition"), code, model, NOT_PER_TRIAL, session_id,
             {"labels": run.labels, "trial": None, "results": results}, f"condition {label} ({pos + 1} of {n_cond})")
    session_rows.condition_done(store, session_id, pos)


def _loaded(run: _Run, protocol, model: str, status: str):
    """The condition's scene, said first (building a fine model takes up to half a minute, and a
    silent terminal looks hung); the model is never named (the labels are blind)."""
    run.say(f"{status[:1].lower()}{status[1:]}: loading")
    return condition_scene(protocol, model, run.device)


def _run_trial(run: _Run, scene, pos: int, model: str, trial: int, status: str) -> None:
    """One trial: the rest screen before it, the run, then its trace and row (the row last: a
    trial row means the trial is complete)."""
    protocol, shown = run.protocol, run.shown
    n_trials = protocol.trials_per_condition
    run.say(f"{status[0].lower()}{status[1:]}: trial {trial + 1} of {n_trials}")
    if run.paced and (trial > 0 or pos > 0):
        _rest_screen(shown, protocol.rest_seconds, status, "Rest" if trial > 0 else "Next condition in", run.keys)

    def caption(phase, left):
        head = f"{status} - trial {trial + 1} of {n_trials}"
        if phase == "waiting":
            return {"top": head, "center": "Grasp the brain to start", "bottom": "Experimenter: SPACE starts the trial", "question": ""}
        return {"top": head, "center": f"{math.ceil(left)} s", "bottom": task, "question": ""}

    task = "Pull the tissue"
    if any(h.target is not None for h in scene.spec.hands):
        task = "Pull to the target and hold it there" + (" to end the trial" if protocol.trial_end == "targets" else "")

    pacing = Pacing(view=shown, wait_for_grasp=run.paced, caption=caption, keys=run.keys, notify=run.say) if (run.paced or shown) else None
    started = now()
    scene.operators = run.participant.operators(scene, trial, model) if run.participant else None
    try:
        result = run_scene(scene, duration=protocol.trial_seconds, time_scale=run.time_scale, pacing=pacing, servo=run.servo,
                           end_on_targets=protocol.trial_end == "targets")
    finally:
        scene.operators = None
        if shown is not None:
            shown.at_rest()
    rec, lat = _trial_record(run.session_id, model, trial, started, result)
    rec |= write_trace(run.db, run.session_id, pos, trial, result)  # durable before the trial's row
    if not rec["grasped"]:
        run.say(f"condition {run.labels[model]}: trial {trial + 1}: nothing was grasped (recorded)")
    if run.time_scale > 0:  # a person's trial: a model slower than its budget (also an event in the trace)
        for line in result.over_budget:
            run.say(f"condition {run.labels[model]}: trial {trial + 1}: {line}")
    session_rows.record_trial(run.store, rec, lat)  # latency rows first, the trial row last


def _ask_at_the_end(run: _Run) -> None:
    """The questions about the whole session, once, with every condition's perceived features."""
    store, protocol, code = run.store, run.protocol, run.code
    if not _unasked(store, protocol.asked("end"), code, SESSION, NOT_PER_TRIAL):
        return
    feats = {}
    for r in session_rows.observer_features(store, code):
        feats.setdefault(r["model"], {})[r["feature"]] = math.nan if r["value"] is None else r["value"]  # NaN is stored as NULL
    _ask(store, run.answerer, protocol.asked("end"), code, SESSION, NOT_PER_TRIAL, run.session_id,
         {"labels": run.labels, "trial": None, "results": None, "features": feats}, "all the conditions you tried")


__all__ = ["run_session", "TerminalAnswers", "WindowAnswers"]
