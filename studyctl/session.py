"""A session: training, then each condition in the participant's order (trials on the
simulator, then the questionnaire), every trial and answer committed when it happens.

`--resume` continues an interrupted session after its last committed trial or answer: nothing
is lost (beyond the trial in flight) and nothing is done twice.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable

from studyctl.errors import StoreError
from studyctl.store import Store, dumps, now, sha256_file

SOFTWARE_VERSION = "brainsim-study 0.1.0"


class TerminalAnswers:
    """Asks each question in the terminal: y/yes or n/no, until one is given."""

    source = "terminal"

    def __init__(self, prompt: Callable[[str], str] | None = None, echo: Callable[[str], None] = print):
        self.prompt = prompt or input
        self.echo = echo

    def begin(self, model_label: str) -> None:
        self.echo(f"\nQuestions about the tissue you just pulled ({model_label}). Answer y or n.")

    def __call__(self, question, model: str, measured: dict) -> bool:
        while True:
            reply = self.prompt(f"{question.text} [y/n] ").strip().lower()
            if reply in ("y", "yes"):
                return True
            if reply in ("n", "no"):
                return False
            self.echo("Please answer y or n.")


_SCENES: dict = {}  # (scene file, model) -> Scene: models are built once per process


def _scene(protocol, model: str, device: str):
    """The protocol's scene for `model`, with every hand on `device` (built once, reused)."""
    import dataclasses

    from sim.scene import build_scene

    key = (str(protocol.scene), model, device)
    if key in _SCENES:
        return _SCENES[key]
    scene = build_scene(protocol.scene, model)
    if any(h.device != device for h in scene.spec.hands):
        hands = tuple(dataclasses.replace(h, device=device) for h in scene.spec.hands)
        scene.spec = dataclasses.replace(scene.spec, hands=hands)
    _SCENES[key] = scene
    return scene


def reference_model(protocol):
    """The linear FEM on the protocol's scene: the force reference of the answer model."""
    return _scene(protocol, "fem", "simulated").model


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
        "events": dumps(s["events"]),
    }
    lat = []
    for measure, value in (("deformation_ms", rec["deformation_ms_mean"]), ("tick_interval_p99_us", rec["tick_interval_p99_us"]),
                           ("read_to_force_us", rec["read_to_force_us"]), ("tick_compute_us", rec["tick_compute_us"])):
        if value is not None and math.isfinite(value):
            lat.append({"session_id": session_id, "model": model, "trial": trial, "measure": measure, "value": float(value)})
    return rec, lat


def run_session(db, code: str, device: str = "simulated", synthetic: bool = False, resume: bool = False,
                time_scale: float | None = None, answers=None, seed: int = 0, progress: Callable[[str], None] | None = None,
                session_id: int | None = None) -> dict:
    from sim.run import run_scene
    from studyctl.study import assign_order

    store = Store(db)
    say = progress or (lambda msg: None)
    try:
        protocol = store.protocol()
        if not store.rows("select code from participants where code = ?", (code,)):
            raise StoreError(f"participant {code}: not registered; add with `studyctl participants add`")
        if time_scale is None:
            time_scale = 0.0 if synthetic else 1.0
        sessions = store.rows("select * from sessions where code = ? order by id", (code,))
        if any(s["status"] == "done" for s in sessions):
            raise StoreError(f"participant {code}: the session is already complete")
        running = [s for s in sessions if s["status"] == "running"]
        if running and not resume:
            raise StoreError(f"participant {code}: a session was interrupted; continue it with --resume")
        if resume and not running:
            raise StoreError(f"participant {code}: no interrupted session to resume")
        order = assign_order(store, protocol, code)
        if running:
            session_id = running[0]["id"]
            store.event(session_id, "resumed")
            say(f"resuming session {session_id} of {code}")
        else:
            store.write("sessions", {
                **({"id": session_id} if session_id is not None else {}),
                "code": code, "started_at": now(), "finished_at": None, "status": "running", "synthetic": int(synthetic),
                "device": device, "protocol_sha256": protocol.sha256, "scene_sha256": sha256_file(protocol.scene),
                "software_version": SOFTWARE_VERSION, "conditions": json.dumps(order)}, pk="id")
            session_id = store.rows("select max(id) as id from sessions where code = ?", (code,))[0]["id"]  # the row just written
            for pos, model in enumerate(order):
                store.write("conditions", {"session_id": session_id, "position": pos, "model": model, "status": "pending"}, pk=("session_id", "position"))
        participant = None
        if answers is None and synthetic:
            from studyctl.synthetic import SyntheticAnswers, SyntheticParticipant

            participant = SyntheticParticipant.draw(code, seed)
            ref_scene = _scene(protocol, "fem", "simulated")
            answers = SyntheticAnswers(participant, ref_scene.model, ref_scene.mesh)
        answerer = answers or TerminalAnswers()
        done_events = {r["kind"] for r in store.rows("select kind from events where session_id = ?", (session_id,))}
        if "training_done" not in done_events:
            seconds = protocol.training_minutes * 60.0
            if time_scale > 0 and seconds > 0:
                say(f"training: {protocol.training_minutes:g} minutes of free pulling")
                run_scene(_scene(protocol, "plate_spring", device), duration=seconds, time_scale=time_scale)
            store.event(session_id, "training_done", f"{seconds:g} s at time scale {time_scale:g}")
        for pos, model in enumerate(order):
            done_trials = {r["trial"] for r in store.rows("select trial from trials where session_id = ? and model = ?", (session_id, model))}
            scene = None
            measured, results = [], []
            for trial in range(protocol.trials_per_condition):
                if trial in done_trials:
                    continue
                scene = scene or _scene(protocol, model, device)
                say(f"{model}: trial {trial + 1} of {protocol.trials_per_condition}")
                started = now()
                scene.operators = participant.operators(scene, trial, model) if participant else None
                result = run_scene(scene, duration=protocol.trial_seconds, time_scale=time_scale)
                scene.operators = None
                rec, lat = _trial_record(session_id, model, trial, started, result)
                measured.append(rec)
                results.append(result)
                # latency rows first, the trial row last: a trial row means the trial is complete
                if lat:
                    store.write_many("latency", lat, pk=("session_id", "model", "trial", "measure"))
                store.write("trials", rec, pk=("session_id", "model", "trial"))
            answered = {r["item"] for r in store.rows("select item from answers where code = ? and model = ?", (code, model))}
            if len(answered) < len(protocol.questions):
                answerer.begin(f"condition {pos + 1} of {len(order)}")
            for q in protocol.questions:
                if q.id in answered:
                    continue
                yes = answerer(q, model, {"trials": measured, "results": results})
                store.write("answers", {"code": code, "model": model, "item": q.id, "answer": int(bool(yes)), "session_id": session_id,
                                        "source": answerer.source, "answered_at": now()}, pk=("code", "model", "item"))
            store.db.conn.execute("update conditions set status = 'done' where session_id = ? and position = ?", (session_id, pos))
        store.db.conn.execute("update sessions set status = 'done', finished_at = ? where id = ?", (now(), session_id))
        n = store.rows("select count(*) as n from answers where code = ?", (code,))[0]["n"]
        return {"session": session_id, "participant": code, "order": order, "answers": n, "synthetic": synthetic}
    finally:
        store.close()


__all__ = ["run_session", "TerminalAnswers"]
