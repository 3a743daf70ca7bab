"""Answering every question kind as a person does: in the participant view's real window
(Xvfb, real X key and mouse events through xdotool, screenshots looked at pixel by pixel) and in
the terminal through a real pseudo-terminal, with the stored answers' SQLite types checked."""

import os
import re
import sqlite3
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from analysis.study.questions import Question
from tests.helpers import MODEL_WORDS, fast_protocol, pty_session, studyctl
from tests.window_helpers import run_xdotool, window

SELECTED = np.array([0.12, 0.40, 0.85]) * 255  # sim/view/window.py: the chosen point, the slider's mark
LABELS = {"plate_spring": "A", "fem": "B", "mass_spring": "C"}


class Person:
    """Acts in the window from a thread while the main thread asks (and draws): waits for a
    question to be ready for keys, presses and clicks, and asks the main thread for screenshots
    (OpenGL stays on the thread that owns the window). A watchdog closes the view after
    `limit_s`, so a lost X event fails the test, never hangs it."""

    def __init__(self, view, shots: Path, limit_s: float = 60.0):
        self.view, self.shots = view, shots
        self.polls = 0
        self.wanted: list[str] = []
        self.taken: dict[str, np.ndarray] = {}
        self.answers: list = []
        self.texts: list[str] = []
        self.error: BaseException | None = None
        idle = view.idle

        def idle_spy():
            idle()
            self.polls += 1
            self.texts.extend(view.text().values())
            while self.wanted:
                name = self.wanted.pop(0)
                path = shots / f"{name}.png"
                view.screenshot(path)
                import matplotlib.image as mpimg

                self.taken[name] = (mpimg.imread(path)[:, :, :3] * 255).astype(np.uint8)

        view.idle = idle_spy

        def watchdog():
            deadline = time.time() + limit_s
            while time.time() < deadline and not getattr(self, "done", False):
                time.sleep(0.2)
            view.closed = True

        threading.Thread(target=watchdog, daemon=True).start()

    def wait(self, check, what: str, timeout: float = 20.0) -> None:
        deadline = time.time() + timeout
        while not check():
            if time.time() > deadline:
                raise AssertionError(f"timed out waiting for {what}")
            time.sleep(0.02)

    def ready(self, q: Question) -> None:
        """The question is shown and keys pressed from now on count (past the discarding poll)."""
        self.wait(lambda: self.view.text().get("question", "").replace("\n", " ") == q.text, q.id)
        seen = self.polls
        self.wait(lambda: self.polls >= seen + 2, f"{q.id} ready")

    def settle(self, polls: int = 2) -> None:
        """Let the window take in what was sent: `polls` more event polls."""
        seen = self.polls
        self.wait(lambda: self.polls >= seen + polls, "the window's event polls")

    def key(self, *names: str) -> None:
        for name in names:
            run_xdotool("key", "--window", self.w, name)

    def click(self, x: float, y: float, times: int = 1) -> None:
        run_xdotool("mousemove", "--window", self.w, round(x), round(y))
        time.sleep(0.05)
        for _ in range(times):
            run_xdotool("click", 1)

    def shoot(self, name: str) -> np.ndarray:
        self.wanted.append(name)
        self.wait(lambda: name in self.taken, f"screenshot {name}")
        return self.taken[name]


def _centre(box):
    u0, v0, u1, v1 = box
    return (u0 + u1) / 2, (v0 + v1) / 2


def _blue(img, box) -> float:
    """The share of a box's pixels in the chosen point's colour."""
    u0, v0, u1, v1 = (int(round(c)) for c in box)
    region = img[v0:v1, u0:u1].astype(float)
    return float(np.mean(np.linalg.norm(region - SELECTED, axis=2) < 30))


def test_every_kind_answered_in_the_window_with_keys_and_the_mouse(xdotool, tmp_path):
    """A 7-point rating by a number key (after a click on the brain that must grasp nothing, an
    out-of-range key and a click that only chooses), an 11-point one by the arrows and Enter,
    a VAS by a click, the arrows and a drag (its values checked against the line's geometry to
    the pixel), a 5-point one by clicking a point twice, a 3-point one on the keypad, and a
    choice by its letter. Types and values, and the screenshots' pixels."""
    from analysis.study.instruments import questions as instrument
    from sim.geometry.mesh import load_mesh
    from sim.view.window import HandState, ParticipantView
    from studyctl.session.window_answers import WindowAnswers

    shots = Path(os.environ.get("BRAINSIM_SHOTS") or tmp_path)
    shots.mkdir(parents=True, exist_ok=True)
    mesh = load_mesh()
    view = ParticipantView(mesh)
    hands = [HandState(tuple(mesh.vertices[3386])), HandState(tuple(mesh.vertices[13629]))]
    view.draw(None, hands)
    brain_point = (560, 540)  # on the brain, below the questionnaire's panel
    assert view.pick(*brain_point) is not None
    sus2 = instrument("sus")[1]
    qs = [Question("real7", "How real did the tissue feel?", kind="likert", points=7, anchors=("Not at all real", "Completely real")),
          Question("soft11", "How soft was the tissue?", kind="likert", points=11, anchors=("Very hard", "Very soft")),
          Question("effort", "How hard did you have to work to pull the tissue?", kind="vas", anchors=("Very low", "Very high")),
          sus2,
          Question("again", "Would you use it again?", kind="likert", points=3, anchors=("No", "Yes")),
          Question("best", "Which condition felt most like real brain tissue?", kind="choice", when="end")]
    person = Person(view, shots)
    answerer = WindowAnswers(view)

    def act():
        try:
            deadline = time.time() + 30
            while window() is None and time.time() < deadline:
                time.sleep(0.1)
            person.w = window()
            assert person.w, "no window"
            # 7 points: a click on the brain grasps nothing; 8 is no point; a click chooses 2;
            # 5 answers at once
            person.ready(qs[0])
            w = view.answers.widget
            person.click(*brain_point)
            person.key("8")
            person.settle()
            assert view.inputs == {}
            assert w.selected is None
            assert not person.answers
            person.click(*_centre(w.boxes[1]))
            person.wait(lambda: w.selected == 1, "a click chooses point 2")
            person.settle()
            img = person.shoot("view_likert")
            assert _blue(img, w.boxes[1]) > 0.5
            assert _blue(img, w.boxes[4]) < 0.05
            assert not person.answers  # a click only chooses
            person.key("5")
            person.wait(lambda: len(person.answers) == 1, "the 7-point answer")
            # 11 points: Right 8 times from nothing chosen (1, 2, .. 8), Left once; a number key
            # answers nothing (10 and 11 have none); Enter
            person.ready(qs[1])
            w = view.answers.widget
            person.key(*["Right"] * 8)
            person.wait(lambda: w.selected == 7, "Right x8 chooses 8")
            person.key("Left", "3")
            person.wait(lambda: w.selected == 6, "Left chooses 7")
            person.settle()
            assert len(person.answers) == 1
            assert w.selected == 6
            img = person.shoot("view_likert11")
            assert _blue(img, w.boxes[6]) > 0.5
            assert max(_blue(img, b) for b in w.boxes[:6] + w.boxes[7:]) < 0.05
            person.key("Return")
            person.wait(lambda: len(person.answers) == 2, "the 11-point answer")
            # VAS: Enter without a mark does nothing; a click at 30% of the line; Right twice; a
            # drag from 20% to 70%; Left; Enter on the keypad
            person.ready(qs[2])
            w = view.answers.widget
            u0, u1, v = w.line
            person.key("Return")
            person.settle(3)
            assert w.value is None
            assert len(person.answers) == 2
            x = u0 + round(0.3 * (u1 - u0))
            person.click(x, v + 6)  # a little below the line still sets it
            person.wait(lambda: w.value is not None, "a mark")
            expected = 100.0 * (x - u0) / (u1 - u0)
            person.marks = [(w.value, expected)]
            person.key("Right", "Right")
            person.wait(lambda: w.value is not None and abs(w.value - (person.marks[0][0] + 2)) < 1e-9, "Right x2 moves the mark by 2")
            run_xdotool("mousemove", "--window", person.w, u0 + round(0.2 * (u1 - u0)), v)
            run_xdotool("mousedown", 1)
            for k in range(1, 11):
                run_xdotool("mousemove", "--window", person.w, u0 + round((0.2 + 0.05 * k) * (u1 - u0)), v - 2)
                time.sleep(0.03)
            run_xdotool("mouseup", 1)
            end = u0 + round(0.7 * (u1 - u0))
            person.wait(lambda: w.value is not None and abs(w.value - 100.0 * (end - u0) / (u1 - u0)) < 0.08, "the drag's mark at 70%")
            person.settle()
            person.marks.append((w.value, 100.0 * (end - u0) / (u1 - u0)))
            img = person.shoot("view_vas")
            column = img[v - 20:v + 20, end - 2:end + 3].astype(float)
            assert np.mean(np.linalg.norm(column - SELECTED, axis=2) < 30) > 0.8  # the mark, where it was dragged to
            assert np.mean(np.linalg.norm(img[v - 20:v + 20, x - 2:x + 3].astype(float) - SELECTED, axis=2) < 30) < 0.1  # not where it was
            person.key("Left", "KP_Enter")
            person.wait(lambda: len(person.answers) == 3, "the VAS answer")
            # SUS item 2 (5 points): a click chooses 2, a second click on it confirms
            person.ready(qs[3])
            person.click(*_centre(view.answers.widget.boxes[1]), times=2)
            person.wait(lambda: len(person.answers) == 4, "the SUS answer")
            # 3 points: the keypad's digits are digits
            person.ready(qs[4])
            person.key("KP_3")
            person.wait(lambda: len(person.answers) == 5, "the keypad answer")
            # choice: a click chooses C; the letter B answers at once
            person.ready(qs[5])
            w = view.answers.widget
            assert w.labels == ("A", "B", "C")
            person.click(*_centre(w.boxes[2]))
            person.wait(lambda: w.selected == 2, "a click chooses C")
            person.settle()
            img = person.shoot("view_choice")
            assert _blue(img, w.boxes[2]) > 0.5
            assert _blue(img, w.boxes[0]) < 0.05
            person.key("b")
            person.wait(lambda: len(person.answers) == 6, "the choice")
        except BaseException as exc:  # noqa: BLE001 - reported by the main thread
            person.error = exc
            view.closed = True

    t = threading.Thread(target=act, daemon=True)
    t.start()
    context = {"labels": LABELS, "trial": None, "results": None}
    try:
        for about, asked in (("condition B (1 of 3)", qs[:5]), ("all the conditions you tried", qs[5:])):
            answerer.begin(about)
            for q in asked:
                person.answers.append(answerer(q, "" if q.when == "end" else "fem", context))
        t.join(timeout=10)
        assert person.error is None, person.error
        # on a still screen (a rest, questions in the terminal) a click grasps nothing; while a
        # run's frames are drawn it does
        run_xdotool("mousemove", "--window", person.w, *brain_point)
        run_xdotool("click", 1)
        for _ in range(3):
            view.idle()
        assert view.inputs == {}
        view.draw(None, hands)
        run_xdotool("mousedown", 1)
        for _ in range(3):
            view.draw(None, hands)
        run_xdotool("mouseup", 1)
        assert view.inputs  # grasped, held
        assert next(iter(view.inputs.values()))[1]
    except Exception:
        t.join(timeout=5)
        if person.error is not None:
            raise person.error from None
        raise
    finally:
        person.done = True
        t.join(timeout=10)
        view.close()
    assert person.error is None, person.error
    got = person.answers
    assert got[0] == 5
    assert type(got[0]) is int
    assert got[1] == 7
    assert type(got[1]) is int
    (click, at_click), (drag, at_drag) = person.marks
    # to the pixel: one pixel is 0.14 of 100 here, the value is kept to 0.1
    assert abs(click - at_click) <= 0.08
    assert abs(drag - at_drag) <= 0.08
    assert type(got[2]) is float
    assert got[2] == pytest.approx(drag - 1, abs=1e-9)
    assert abs(got[2] - 69.0) < 0.3
    assert got[3] == 2
    assert type(got[3]) is int
    assert got[4] == 3
    assert type(got[4]) is int
    assert got[5] == "fem"  # B's condition, never shown
    assert not view.questionnaire  # after a question the mouse may grasp again
    assert view.answers.widget is None
    # the window stayed blind: labels, numbers and anchors only
    assert not [x for x in person.texts if MODEL_WORDS.search(x)]
    assert any("A  B  C" == x for x in person.texts)
    assert any("Not at all real" in x for x in person.texts)
    for name in ("view_likert", "view_likert11", "view_vas", "view_choice"):
        assert (shots / f"{name}.png").stat().st_size > 10_000


KINDS_QUESTIONS = '''
[[questions]]
id = "real"
text = "How real did the tissue feel?"
kind = "likert"
points = 7
anchors = ["Not at all real", "Completely real"]

[[questions]]
id = "effort"
text = "How hard did you have to work to pull the tissue?"
kind = "vas"
anchors = ["Very low", "Very high"]

[[questions]]
id = "best"
text = "Which condition felt most like real brain tissue?"
kind = "choice"
when = "end"

[[questions]]
id = "comments"
text = "Anything else you noticed?"
kind = "text"
when = "end"
'''


def kinds_protocol(tmp_path: Path, conditions=("plate_spring", "mass_spring")) -> Path:
    """fast_protocol (tests/helpers.py) with one question of each kind but yes/no instead of
    the paper's nine: a rating and a VAS after each condition, a choice and free text at the end."""
    path = fast_protocol(tmp_path, conditions=conditions, trials=1)
    text = path.read_text()
    assert "[[questions]]" in text
    path.write_text(text[:text.index("[[questions]]")] + KINDS_QUESTIONS)
    return path


def test_every_kind_answered_in_the_terminal_through_a_pty_keeps_its_type(tmp_path):
    """A person's session (`session run`, two conditions, one trial each) answered in a real
    pseudo-terminal: a 7-point rating and a VAS after each condition, a choice among the blind
    labels and free text at the end; one value out of range first for each kind that has a range
    (the prompt says what is allowed and asks again). The stored answers keep their types."""
    db = tmp_path / "s.db"
    assert studyctl("study", "init", "--protocol", kinds_protocol(tmp_path), "--db", db).exit_code == 0
    studyctl("participants", "add", "P01", "--db", db)
    studyctl("participants", "consent", "P01", "--db", db)
    replies = {"[1-7]": ["9", "6", "3"], "[0-100]": ["150", "37.5", "80"], "[A/B]": ["D", "b"], "(free text; Enter when done)": ["42"]}
    text = pty_session(["session", "run", "--db", db, "--participant", "P01", "--time-scale", "0"], replies=replies, timeout=120)
    assert "complete" in text, text[-2000:]
    for refused, asked_again in (
            ("Please answer an integer 1..7 (1 = Not at all real, 7 = Completely real).", "How real did the tissue feel?\n"
             "  1 = Not at all real ... 7 = Completely real  [1-7]"),
            ("Please answer a number 0..100 (0 = Very low, 100 = Very high).", "How hard did you have to work to pull the tissue?\n"
             "  a number from 0 to 100: 0 = Very low, 100 = Very high  [0-100]"),
            ("Please answer one of A, B.", "Which condition felt most like real brain tissue? [A/B]")):
        assert re.search(re.escape(refused) + r"\s*" + re.escape(asked_again).replace(r"\n", r"\s*"), text.replace("\r", "")), refused
    assert text.count("Please answer") == 3
    assert not MODEL_WORDS.search(text)
    con = sqlite3.connect(db)
    (first,), (second,) = con.execute("select model from conditions order by position").fetchall()
    b = con.execute("select model from conditions where label = 'B'").fetchone()[0]
    rows = con.execute("select model, item, trial, answer, typeof(answer), source from answers order by rowid").fetchall()
    assert rows == [(first, "real", -1, 6, "integer", "terminal"), (first, "effort", -1, 37.5, "real", "terminal"),
                    (second, "real", -1, 3, "integer", "terminal"), (second, "effort", -1, 80.0, "real", "terminal"),
                    ("", "best", -1, b, "text", "terminal"), ("", "comments", -1, "42", "text", "terminal")], rows
