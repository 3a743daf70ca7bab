"""A condition's discrimination task in a session (studyctl/tasks.py): trials of two intervals,
the answer, the adaptive procedure's next increment.

Each trial pulls the tissue twice, the reference and the comparison (the condition's model
with its stiffness scaled, `sim.scene.Scene.with_stiffness`) in a random order, then asks which
was stiffer (keys 1 / 2 in the window or the terminal; what was typed before the question
appears answers nothing). The trial's row holds the increment, the order, the answer, whether
it was right, the procedure's state after it, both intervals' servo events (counts summed: the
trial had a fault if either interval did) and both intervals' traces (written durably first). A resumed session replays the stored trials through a new procedure, which then asks
for what the uninterrupted one would have: at most the trial in flight is lost.
"""

from __future__ import annotations

import math
import random
import time
from collections import Counter

from analysis.study.questions import Question
from analysis.study.trace_files import write_trace
from sim.run import Pacing, run_scene
from studyctl.session.procedures import replay
from studyctl.store import dumps, now
from studyctl.store.trials import discrimination_done

INTERVALS = ("1", "2")
_STIMULI: dict = {}  # (the condition's scene, scale) -> its scaled scene: the few a procedure keeps trying
# FEM scenes share their factors (`LinearFem.scaled`); a mass-spring's is rebuilt. Keeping all 35
# of QUEST+'s stimuli instead saved no time and held much more memory (docs/synthetic.md).
STIMULI_KEPT = 6


def stimulus_scene(scene, scale: float):
    """The condition's scene with its stiffness times `scale` (the scene itself at 1)."""
    if scale == 1.0:
        return scene
    key = (scene, float(scale))  # the scene itself (hashed by identity), never its id(): a freed scene's id is reused
    out = _STIMULI.pop(key, None)
    if out is None:
        out = scene.with_stiffness(scale)
        while len(_STIMULI) >= STIMULI_KEPT:
            _STIMULI.pop(next(iter(_STIMULI)))  # the least recently used
    _STIMULI[key] = out
    return out


def answer_question(task) -> Question:
    """The forced choice as a question of kind "choice" between the two intervals."""
    return Question(id=f"task_{task.index + 1}", text=task.question, kind="choice", when="condition")


def run_task(run, scene, pos: int, model: str, task, status: str) -> None:
    """Every trial of `task` in this condition that is not stored yet, each committed whole."""
    store = run.store
    done = discrimination_done(store, run.session_id, model, task.index)
    procedure = replay(task.procedure_spec(), [(r["delta"], bool(r["correct"])) for r in done])
    for trial in range(len(done), task.trials):
        delta = float(procedure.next_stimulus())
        rng = random.Random(f"order:{run.seed}:{run.code}:{model}:{task.index}:{trial}") if run.participant else random.SystemRandom()
        comparison_interval = rng.choice((1, 2))
        reference, comparison = task.scales(delta)
        started = now()
        results = []
        for interval in (1, 2):
            scale = comparison if interval == comparison_interval else reference
            results.append(_run_interval(run, stimulus_scene(scene, scale), model, task, trial, interval, status))
        answer = _answer(run, task, model, trial, results, status)
        correct = answer == comparison_interval
        procedure.update(delta, correct)
        if task.feedback:
            _feedback(run, correct)
        _store_trial(run, pos, model, task, trial, delta, comparison_interval, answer, procedure.state(), started, results)


def _run_interval(run, scene, model: str, task, trial: int, interval: int, status: str):
    """One interval's pull: the person starts it with a grasp (or SPACE), it lasts the task's
    interval time; a synthetic participant pulls as in its free trials, its motion drawn anew."""
    shown = run.shown
    head = f"{status} - comparison {trial + 1} of {task.trials}"

    def caption(phase, left):
        if phase == "waiting":
            return {"top": head, "center": f"Tissue {interval} of 2: grasp the brain to start", "bottom": "Experimenter: SPACE starts it",
                    "question": ""}
        return {"top": head, "center": f"Tissue {interval} of 2: {math.ceil(left)} s", "bottom": "Pull the tissue", "question": ""}

    pacing = Pacing(view=shown, wait_for_grasp=run.paced, caption=caption, keys=run.keys, notify=run.say) if (run.paced or shown) else None
    scene.operators = run.participant.operators(scene, f"task{task.index}:{trial}:{interval}", model) if run.participant else None
    try:
        # a synthetic interval in lockstep ends when both hands have let go: its judgement reads
        # each hand's first hold only, so the rest of the interval would change no answer
        return run_scene(scene, duration=task.interval_seconds, time_scale=run.time_scale, pacing=pacing, servo=run.servo,
                         end_on_release=bool(run.participant) and run.time_scale == 0)
    finally:
        scene.operators = None
        if shown is not None:
            shown.at_rest()


def _answer(run, task, model: str, trial: int, results: list, status: str) -> int:
    """1 or 2: the interval the participant felt stiffer."""
    context = {"labels": {i: i for i in INTERVALS}, "trial": trial, "task": task, "intervals": results}
    if hasattr(run.answerer, "discriminate"):  # a synthetic participant: from the two traces
        return int(run.answerer.discriminate(task, model, context))
    run.answerer.begin(f"{status} - comparison {trial + 1} of {task.trials}")
    return int(run.answerer(answer_question(task), model, context))


def _feedback(run, correct: bool) -> None:
    text = "Correct" if correct else "Not correct"
    run.say(f"feedback: {text}")
    if run.shown is not None:
        run.shown.set_text(center=text, bottom="", question="")
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            run.shown.idle()


def _store_trial(run, pos: int, model: str, task, trial: int, delta: float, comparison_interval: int, answer: int, state: dict,
                 started: str, results: list) -> None:
    """Both traces durably, then the trial's row (the row last: a row means the trial is whole)."""
    row = {"session_id": run.session_id, "code": run.code, "model": model, "task": task.index, "trial": trial,
           "reference": task.reference, "delta": delta, "comparison": task.reference * (1.0 + delta),
           "comparison_interval": comparison_interval, "answer": answer, "correct": int(answer == comparison_interval),
           "state": dumps(state), "source": run.answerer.source, "started_at": started, "answered_at": now(),
           "events": dumps(dict(Counter(e.kind for r in results for e in r.events)))}
    for interval, result in zip((1, 2), results):
        name = f"condition-{pos + 1}-task-{task.index + 1}-trial-{trial + 1}-interval-{interval}.npz"
        t = write_trace(run.db, run.session_id, pos, trial, result, name=name)
        row |= {f"trace_path_{interval}": t["trace_path"], f"trace_sha256_{interval}": t["trace_sha256"]}
    run.store.write("discrimination", row, pk=("session_id", "model", "task", "trial"))
