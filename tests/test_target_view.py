"""A hand's target in the participant view (issue 32): a person's session in a real window (Xvfb)
with the mouse, on a retraction scene whose hands have targets and a protocol whose trials end
once every hand has held its target. The person aims by what is drawn: the ring where the target
is; xdotool moves the pointer, presses the buttons (left: left hand, right: right hand, one at a
time: a hand's target stays held once held) and turns the wheel (depth). Screenshots are looked
at pixel by pixel."""

import copy
import json
import sqlite3
import threading
import time

import numpy as np

from sim.view import hud
from tests.conftest import ROOT
from tests.helpers import studyctl as _studyctl
from tests.window_helpers import run_xdotool, window

QUESTION = '''[[questions]]
id = "target_clear"
text = "Was the target clear?"
'''


def _protocol(tmp_path, trial_seconds=30.0):
    """protocols/construct_validity.toml on protocols/scenes/retraction.toml: one trial, no
    training, a yes/no question (answered with a key) instead of the ratings and the SUS."""
    scene = (ROOT / "protocols/scenes/retraction.toml").read_text()
    scene = scene.replace('"../../data/', f'"{ROOT}/data/').replace('"../models/', f'"{ROOT}/protocols/models/').replace('"../materials/', f'"{ROOT}/protocols/materials/')
    (tmp_path / "retraction.toml").write_text(scene.replace('kind = "offscreen"', 'kind = "none"'))
    text = (ROOT / "protocols/construct_validity.toml").read_text()
    text = text.replace('scene = "scenes/retraction.toml"', f'scene = "{tmp_path / "retraction.toml"}"')
    text = text.replace("trials_per_condition = 10", "trials_per_condition = 1").replace("trial_seconds = 10.0", f"trial_seconds = {trial_seconds}")
    text = text.replace("training_minutes = 2.0", "training_minutes = 0.0").replace("rest_seconds = 5.0", "rest_seconds = 0.5")
    text = text[: text.index("# Face validity")] + QUESTION
    assert 'trial_end = "targets"' in text
    path = tmp_path / "protocol.toml"
    path.write_text(text)
    return path


def _colour(img, rgb, tol=60.0):
    """Pixels within `tol` of a target colour drawn lit (the ring: 0.6 to 1.05 of it) or flat (the bar)."""
    c = np.asarray(rgb) * 255
    d = img.astype(float)
    # the ring is lit: compare chroma and require it bright enough
    s = d.sum(axis=2, keepdims=True) + 1e-9
    chroma = np.abs(d / s - c / c.sum()).max(axis=2)
    return (chroma < tol / 1000.0) & (d.max(axis=2) > 0.45 * c.max())


class Person:
    """Drives the window with xdotool the way a person would aim at the ring; asks the view's
    draw (the main thread) for screenshots at moments of its choosing."""

    def __init__(self, monkeypatch, limit_s=150.0):
        from sim.view.window import ParticipantView

        self.view, self.want, self.shots, self.texts = None, None, {}, []
        self.got = threading.Event()
        draw, set_text = ParticipantView.draw, ParticipantView.set_text
        person = self

        def draw_spy(view, displacement, hands, read_t=None, heat01=None, latch=None):
            draw(view, displacement, hands, read_t, heat01, latch)
            person.view = view
            if person.want is not None and not person.got.is_set():
                person.shots[person.want] = (view.image(), [copy.copy(h.target) for h in view._last_hands])
                person.got.set()

        def set_text_spy(view, **slots):
            set_text(view, **slots)
            person.texts.extend(t for t in slots.values() if t)

        def watchdog():
            time.sleep(limit_s)
            if person.view is not None:
                person.view.closed = True

        monkeypatch.setattr(ParticipantView, "draw", draw_spy)
        monkeypatch.setattr(ParticipantView, "set_text", set_text_spy)
        threading.Thread(target=watchdog, daemon=True).start()

    def shoot(self, name, path=None):
        self.got.clear()
        self.want = name
        assert self.got.wait(20), f"no frame drawn for {name}"
        self.want = None
        if path is not None:
            from PIL import Image

            Image.fromarray(self.shots[name][0]).save(path)
        return self.shots[name]

    def pull_to_target(self, w, k, shots=(), tmp_path=None):
        """Hand k: press where its line starts (the scene's grasp point), wait for the grasp, drag
        to the ring (the wheel for depth), hold, release."""
        v = self.view
        spec = v.targets[k]
        origin = np.asarray(v._last_hands[k].target.point) - spec.spec.distance * np.asarray(spec.direction)
        u0, v0, _ = v.camera.project(origin)[0]
        run_xdotool("mousemove", "--window", w, int(round(u0)), int(round(v0)))
        time.sleep(0.4)
        button = (1, 3)[k]
        run_xdotool("mousedown", button)
        deadline = time.time() + 20
        while v._last_hands[k].grasped_vertex is None and time.time() < deadline:
            time.sleep(0.05)
        assert v._last_hands[k].grasped_vertex is not None, "the grasp did not take hold"
        time.sleep(0.3)
        point = np.asarray(v._last_hands[k].target.point)  # the target as drawn now: from where the grasp took hold
        u1, v1, depth = v.camera.project(point)[0]
        steps = int(round((v.inputs[k][2] - depth) / 0.002))  # the wheel: 2 mm of depth a notch, up towards the viewer
        for j in range(1, 13):
            run_xdotool("mousemove", "--window", w, int(round(u0 + (u1 - u0) * j / 12)), int(round(v0 + (v1 - v0) * j / 12)))
            time.sleep(0.08)
            if j == 6 and "pull" in shots:
                self.shoot("pull", tmp_path / "pull.png")
        for _ in range(abs(steps)):
            run_xdotool("click", 4 if steps > 0 else 5)
            time.sleep(0.03)
        deadline = time.time() + 10

        def now(what):  # the target's state as drawn now (no target: the trial is over, its targets held)
            st = v._last_hands[k].target
            return st is None or getattr(st, what)

        while not now("on_target") and time.time() < deadline:
            time.sleep(0.05)
        if "on" in shots:
            self.shoot("on", tmp_path / "on.png")
        while not now("held") and time.time() < deadline:
            time.sleep(0.05)
        if "held" in shots:
            self.shoot("held", tmp_path / "held.png")
        run_xdotool("mouseup", button)
        time.sleep(0.3)


def test_a_person_pulls_each_hand_to_its_target_with_the_mouse_and_the_trial_ends_when_both_are_held(xdotool, tmp_path, monkeypatch):
    from studyctl.session.run import run_session

    db = tmp_path / "s.db"
    res = _studyctl("study", "init", "--protocol", _protocol(tmp_path), "--db", db)
    assert res.exit_code == 0, res.output
    for args in (("participants", "add", "P01", "--field", "experience=student"), ("participants", "consent", "P01")):
        res = _studyctl(*args, "--db", db)
        assert res.exit_code == 0, res.output
    person = Person(monkeypatch)
    failures = []

    def act(done):
        try:
            deadline = time.time() + 90
            while not (person.view and window() and "Grasp the brain to start" in person.texts) and time.time() < deadline:
                time.sleep(0.1)
            w = window()
            time.sleep(0.5)
            person.shoot("before", tmp_path / "before.png")
            person.pull_to_target(w, 0, shots=("pull", "on", "held"), tmp_path=tmp_path)
            person.pull_to_target(w, 1)
            while not done.is_set():  # the question after the trial: no
                run_xdotool("key", "--window", w, "n")
                time.sleep(0.3)
        except Exception as exc:  # the session's own thread reports it
            failures.append(exc)
            if person.view is not None:
                person.view.closed = True

    done = threading.Event()
    t = threading.Thread(target=act, args=(done,), daemon=True)
    started = time.time()
    t.start()
    try:
        try:
            out = run_session(db, "P01", view="window", answer_with="window", time_scale=1.0, device="mouse")
        except Exception:
            assert not failures, failures  # what the person met, first
            raise
    finally:
        done.set()
        t.join()
    assert not failures, failures
    assert out["answers"] == 1
    con = sqlite3.connect(db)
    rows = con.execute("select events, trace_ticks, grasped from trials").fetchall()
    assert len(rows) == 1
    events, ticks, grasped = rows[0]
    assert json.loads(events)["ended_early"] == "targets held"
    assert grasped == 1
    assert ticks < 30_000  # ended before its 30 s limit (1 kHz)
    assert time.time() - started < 150

    # before the grasp: both rings in magenta where the targets are drawn, the bars empty
    img, states = person.shots["before"]
    v = person.view
    for st in states:
        u, vv, _ = v.camera.project(st.point)[0]
        near = img[int(vv) - 20:int(vv) + 21, int(u) - 20:int(u) + 21]
        assert _colour(near, hud.TARGET_AWAY).sum() > 40, (u, vv)
    assert _colour(img, hud.TARGET_AWAY).sum() < 2000  # only the rings and their lines: no bar filled yet
    left, right = hud.bar_rect(-1, v.width, v.ui), hud.bar_rect(1, v.width, v.ui)

    def in_bar(img, rect, rgb):
        x0, y0, x1, y1 = (int(round(c)) for c in rect)
        return int(_colour(img[y0:y1, x0:x1], rgb).sum())

    # mid-pull: the left bar part filled in magenta, from its inner end; the right bar empty
    img, states = person.shots["pull"]
    assert 0.2 < states[0].progress < 0.95
    assert not states[0].on_target
    filled = in_bar(img, left, hud.TARGET_AWAY)
    area = (left[2] - left[0]) * (left[3] - left[1])
    assert 0.1 * area < filled < 0.8 * area
    assert in_bar(img, right, hud.TARGET_AWAY) == 0
    x0, y0, x1, y1 = (int(round(c)) for c in left)
    row = _colour(img[(y0 + y1) // 2:(y0 + y1) // 2 + 1, x0:x1], hud.TARGET_AWAY)[0]
    assert row[-5:].all()  # the left hand's bar fills outwards (to the left)
    assert not row[:5].any()
    # on target: the left ring and the bar's fill green
    img, states = person.shots["on"]
    assert states[0].on_target
    assert in_bar(img, left, hud.TARGET_ON) > 0.4 * area
    u, vv, _ = v.camera.project(states[0].point)[0]
    assert _colour(img[int(vv) - 20:int(vv) + 21, int(u) - 20:int(u) + 21], hud.TARGET_ON).sum() > 40
    # held: the ring gold, "held" written (green glyphs) beside the left bar
    img, states = person.shots["held"]
    assert states[0].held
    u, vv, _ = v.camera.project(states[0].point)[0]
    assert _colour(img[int(vv) - 20:int(vv) + 21, int(u) - 20:int(u) + 21], hud.TARGET_HELD).sum() > 40
    ly = int(hud.BAR["label"] * v.ui)
    assert np.sum(np.abs(img[ly - 14:ly + 2, int(left[2]) - 40:int(left[2])].astype(float) - np.asarray(hud.TARGET_ON) * 0.7 * 255).max(axis=2) < 60) > 15
