"""The participant view in a real window (Xvfb), driven as a person would: X key and mouse
events through xdotool, screenshots looked at pixel by pixel."""

import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROOT
from tests.helpers import MODEL_WORDS, participant_protocol, studyctl
from tests.window_helpers import Recorder, brain_pixels, patch_pixels, run_xdotool, window


def _window_session(db, actor, tmp_path, protocol_kw, **session_kw):
    """A study with one participant, its session run in the window while `actor(done)` (a
    person or an experimenter at the keyboard and mouse) acts in a thread."""
    from studyctl.session.run import run_session

    studyctl("study", "init", "--protocol", participant_protocol(tmp_path, **protocol_kw), "--db", db)
    studyctl("participants", "add", "P01", "--db", db)
    studyctl("participants", "consent", "P01", "--db", db)
    done = threading.Event()
    t = threading.Thread(target=actor, args=(done,), daemon=True)
    t.start()
    try:
        return run_session(db, "P01", view="window", answer_with="window", time_scale=1.0, **session_kw)
    finally:
        done.set()
        t.join()


def test_sim_run_in_a_window_reports_the_view_and_saves_the_last_frame(display, tmp_path):
    shot = tmp_path / "last.png"
    res = studyctl("sim", "run", "--view", "window", "--duration", "2", "--screenshot", shot, "--json")
    assert res.exit_code == 0, res.output
    s = json.loads(res.output)
    v = s["view"]
    assert v["frames_shown"] >= 3
    assert v["fps"] > 0
    assert v["size"] == "1280x720"
    assert 0 < v["motion_to_photon_ms"]["p50"] <= v["motion_to_photon_ms"]["p99"] < 5000
    assert s["events"]["grasp"] == 2
    assert s["ticks"] == 2000
    import matplotlib.image as mpimg

    img = (mpimg.imread(shot)[:, :, :3] * 255).astype(np.uint8)
    assert img.shape == (720, 1280, 3)  # the brain, the grasped patches
    assert brain_pixels(img) > 50_000
    assert patch_pixels(img) > 30


def test_a_paced_session_in_the_window_shows_instructions_countdown_hands_and_deformation(xdotool, tmp_path, monkeypatch):
    """Simulated (scripted) hands pilot a session; the questionnaire is answered with Y/N keys in
    the window (real X key events). Looks at the screenshots of each screen."""
    db = tmp_path / "s.db"
    rec = Recorder(monkeypatch)

    def person(done):  # presses Y now and then: only keys pressed while a question is shown count
        while not done.is_set():
            w = window()
            if w:
                run_xdotool("key", "--window", w, "y")
            time.sleep(0.4)

    out = _window_session(db, person, tmp_path, dict(trials=2, trial_seconds=2.0, training=0.05, rest=1.0, conditions=("plate_spring", "fem")))
    assert out["answers"] == 18
    assert out["order"] in (["A", "B"], ["B", "A"])
    # nothing participant-facing names a model or a parameter
    assert rec.texts
    assert not [x for x in rec.texts if MODEL_WORDS.search(x)]
    joined = "\n".join(rec.texts)
    for expected in ("Training", "Pull the brain freely", "Grasp the brain to start", "Experimenter: SPACE starts the trial",
                     "Rest: 1 s", "Please answer the questions", "Is interaction real and natural?", "Condition A (", "trial 2 of 2",
                     "Thank you"):
        assert expected in joined, expected
    assert any(re.fullmatch(r"\d s", x) for x in rec.texts)  # the trial countdown
    waiting = [(img, hands) for k, img, hands, _, _ in rec.shots if k[0] == "Grasp the brain to start"]
    running = [(k, img, h, g, u) for k, img, h, g, u in rec.shots if re.fullmatch(r"\d s", k[0])]
    assert waiting
    assert running
    assert any(k[0].startswith("Rest: ") for k, *_ in rec.shots)
    img0 = waiting[0][0]
    assert brain_pixels(img0) > 50_000
    # while a trial runs: a grasped, highlighted patch; the hands have moved since the first screen
    late = running[-1]
    assert any(g is not None for g in late[3])
    assert patch_pixels(late[1]) > 30
    moved = max(np.linalg.norm(np.subtract(a, b)) for a, b in zip(late[2], waiting[0][1]))
    assert moved > 0.004
    # the tissue deforms where it is grasped: the surface drawn there has moved, and so have its pixels
    g = next(v for v in late[3] if v is not None)
    assert np.linalg.norm(late[4][g]) > 0.003
    assert np.mean(np.abs(late[1].astype(int) - img0.astype(int))[150:620, 300:980]) > 1.0
    # the text is on the screen: dark glyph pixels in the status line and the instruction line
    assert np.sum(img0[10:45, 10:700].min(axis=2) < 80) > 200
    assert np.sum(img0[660:700, 300:980].min(axis=2) < 80) > 100
    import sqlite3

    con = sqlite3.connect(db)
    assert con.execute("select count(*) from answers where source = 'window'").fetchone()[0] == 18
    assert all(r == ("grasp", 1) for r in con.execute("select started_by, grasped from trials"))


def _drag_in_sim_live(*args: str) -> dict:
    """`studyctl sim live ARGS --json` driven as a person with a mouse would: press on the left
    hemisphere, drag 60 px to the left over a second, Q while still holding (a screenshot then
    shows the pull); the run's JSON summary."""
    proc = subprocess.Popen([sys.executable, "-m", "studyctl.cli", "sim", "live", "--duration", "60", *args, "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        deadline = time.time() + 60
        while window() is None and time.time() < deadline:
            time.sleep(0.2)
        w = window()
        assert w, proc.stderr.read() if proc.poll() is not None else "no window"
        time.sleep(2.0)
        run_xdotool("mousemove", "--window", w, 560, 420)
        time.sleep(0.5)
        run_xdotool("mousedown", 1)
        time.sleep(1.0)
        for k in range(1, 11):
            run_xdotool("mousemove", "--window", w, 560 - 6 * k, 420)
            time.sleep(0.1)
        time.sleep(1.0)
        run_xdotool("key", "--window", w, "q")
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    run_xdotool("mouseup", 1)
    assert proc.returncode == 0, err
    return json.loads(out)


def test_the_mouse_grasps_and_pulls_the_brain_in_sim_live(xdotool, tmp_path):
    """A person with a mouse: press on the left hemisphere, drag, release, Q. The force that
    would be felt is drawn and recorded."""
    shot = tmp_path / "live.png"
    s = _drag_in_sim_live("--screenshot", str(shot))
    assert s["events"].get("grasp", 0) >= 1
    assert s["ended_early"] == "q"
    assert s["max_force_per_hand_n"]["left"] > 0.02
    assert s["max_force_per_hand_n"]["right"] == 0.0
    import matplotlib.image as mpimg

    img = (mpimg.imread(shot)[:, :, :3] * 255).astype(np.uint8)
    red = np.sum((img[:, :, 0] > 170) & (img[:, :, 1] < 90) & (img[:, :, 2] < 80))
    assert red > 40  # the force arrow and number; the grasped patch
    assert patch_pixels(img) > 30


def test_a_whole_session_piloted_with_the_mouse(xdotool, tmp_path, monkeypatch):
    db = tmp_path / "s.db"
    rec = Recorder(monkeypatch)

    def person(done):
        grasped = False
        while not done.is_set():
            w = window()
            if w and not grasped and any("Grasp the brain" in x for x in rec.texts):
                time.sleep(0.5)
                run_xdotool("mousemove", "--window", w, 560, 420)
                run_xdotool("mousedown", 1)
                time.sleep(0.6)
                for k in range(1, 6):
                    run_xdotool("mousemove", "--window", w, 560 - 8 * k, 420)
                    time.sleep(0.1)
                time.sleep(1.5)
                run_xdotool("mouseup", 1)
                grasped = True
            elif w and grasped:
                run_xdotool("key", "--window", w, "n")
            time.sleep(0.3)

    out = _window_session(db, person, tmp_path, dict(trials=1, trial_seconds=1.5, conditions=("plate_spring",)), device="mouse")
    assert out["answers"] == 9
    import sqlite3

    con = sqlite3.connect(db)
    assert con.execute("select started_by, grasped, max_force_n > 0.01 from trials").fetchall() == [("grasp", 1, 1)]
    assert con.execute("select device from sessions").fetchone()[0] == "mouse"
    assert not [x for x in rec.texts if MODEL_WORDS.search(x)]
    assert any(x.startswith("force: ") for x in rec.texts)  # the force is shown as a number



def test_the_experimenter_ends_training_early_and_starts_a_trial_in_which_nothing_is_grasped(xdotool, tmp_path, monkeypatch):
    db = tmp_path / "s.db"
    rec = Recorder(monkeypatch)

    def experimenter(done):
        pressed = set()
        while not done.is_set():
            w = window()
            text = rec.views[-1].text() if rec.views else {}
            if w and text.get("top") == "Training" and "e" not in pressed:
                time.sleep(1.0)
                run_xdotool("key", "--window", w, "e")
                pressed.add("e")
            elif w and text.get("center") == "Grasp the brain to start" and "space" not in pressed:
                run_xdotool("key", "--window", w, "space")
                pressed.add("space")
            elif w and "space" in pressed:
                run_xdotool("key", "--window", w, "n")
            time.sleep(0.3)

    out = _window_session(db, experimenter, tmp_path, dict(trials=1, trial_seconds=1.0, training=1.0, conditions=("fem",)), device="mouse")
    assert out["answers"] == 9
    import sqlite3

    con = sqlite3.connect(db)
    detail = json.loads(con.execute("select detail from events where kind = 'training_done'").fetchone()[0])
    assert detail["ended_early"]
    assert detail["by"] == "e"
    assert 0.5 < detail["ran_s"] < 30
    assert detail["planned_s"] == 60
    assert con.execute("select started_by, grasped, trace_ticks from trials").fetchall() == [("key", 0, 1000)]
    assert con.execute("select count(*) from answers where answer = 0").fetchone()[0] == 9


def test_clean_errors_for_a_window_without_a_display_and_a_mouse_without_a_window(tmp_path, monkeypatch):
    db = tmp_path / "s.db"
    studyctl("study", "init", "--protocol", participant_protocol(tmp_path, trials=1, conditions=("fem",)), "--db", db)
    studyctl("participants", "add", "P01", "--db", db)
    studyctl("participants", "consent", "P01", "--db", db)
    monkeypatch.delenv("DISPLAY", raising=False)
    res = studyctl("session", "run", "--db", db, "--participant", "P01")
    assert res.exit_code == 1
    assert "no display" in res.output
    assert len(res.output.strip().splitlines()) == 1
    res = studyctl("session", "run", "--db", db, "--participant", "P01", "--device", "mouse", "--view", "none")
    assert res.exit_code == 1
    assert "--device mouse" in res.output
    assert "--view window" in res.output
    res = studyctl("sim", "live")
    assert res.exit_code == 1
    assert "no display" in res.output
    import sqlite3

    assert sqlite3.connect(db).execute("select count(*) from sessions").fetchone()[0] == 0  # nothing half-written


_ON_SCREEN = r"""
import json, sys, time
import numpy as np
from sim.geometry.mesh import load_mesh
from sim.view.window import HandState, ParticipantView
mesh = load_mesh()
view = ParticipantView(mesh, width=640, height=360, show_force=True, fullscreen=sys.argv[1] == "fullscreen")
if sys.argv[1] == "resized":  # as a person drags the window's corner: the camera and the text follow
    import glfw
    glfw.set_window_size(view.window, 400, 560)
    for _ in range(20):
        view.idle()
        if view.width == 400:
            break
view.set_text(top="Condition A (1 of 3) - trial 2 of 3", center="4 s", bottom="Pull the brain freely")
u = np.zeros_like(mesh.vertices)
u[:, 0] = 0.003
view.draw(u, [HandState(tuple(mesh.vertices[3386]), (-0.4, 0.1, 0.0), 3386), HandState(tuple(mesh.vertices[13629]))])
for _ in range(5):
    view.idle()
    time.sleep(0.1)
np.save(sys.argv[2], view.image())
import shutil
shutil.copy(sys.argv[3], sys.argv[4])  # the screen, while the window is open
import glfw
print(json.dumps({"pos": glfw.get_window_pos(view.window), "size": [view.width, view.height], "renderer": view.stats()["renderer"]}))
view.close()
"""


def _xwd(path: Path) -> np.ndarray:
    """The screen Xvfb keeps in an XWD file (-fbdir): RGB rows (24-bit depth, 32 bits a pixel)."""
    data = path.read_bytes()
    head = np.frombuffer(data[:100], dtype=">u4")
    header_size, depth, width, height, byte_order, bpp, line, ncolors = (int(head[k]) for k in (0, 3, 4, 5, 7, 11, 12, 19))
    assert depth == 24
    assert bpp == 32
    px = np.frombuffer(data, dtype=np.uint8, count=line * height, offset=header_size + 12 * ncolors).reshape(height, line // 4, 4)
    px = px[:, :width]
    return px[:, :, 2::-1] if byte_order == 0 else px[:, :, 1:4]  # LSB first: B G R x


@pytest.mark.parametrize("mode", ["window", "fullscreen", "resized"])
def test_the_screen_shows_the_frame_the_view_reports(mode, tmp_path):
    """Read back from the X server's own framebuffer (Xvfb -fbdir): the pixels on the screen are
    the frame `image()` returns (screenshots, pictures); a fullscreen view fills the screen; a
    resized window keeps the brain filling it."""
    from bench.common import start_xvfb

    xvfb, display = start_xvfb("1024x600x24", "-fbdir", str(tmp_path))
    try:
        env = dict(os.environ, DISPLAY=display)
        out = subprocess.run([sys.executable, "-c", _ON_SCREEN, mode, str(tmp_path / "frame.npy"), str(tmp_path / "Xvfb_screen0"),
                              str(tmp_path / "screen.xwd")], capture_output=True, text=True, env=env, timeout=120,
                             cwd=Path(__file__).resolve().parents[1])
        assert out.returncode == 0, out.stderr[-2000:]
    finally:
        xvfb.terminate()
        xvfb.wait(timeout=10)
    info = json.loads(out.stdout.strip().splitlines()[-1])
    frame = np.load(tmp_path / "frame.npy")
    screen = _xwd(tmp_path / "screen.xwd")
    (x, y), (width, height) = info["pos"], info["size"]
    assert (width, height) == {"fullscreen": (1024, 600), "window": (640, 360), "resized": (400, 560)}[mode]
    assert frame.shape == (height, width, 3)
    brain = np.all(frame < 245, axis=2)
    rows, cols = np.flatnonzero(brain.any(axis=1)), np.flatnonzero(brain.any(axis=0))
    assert max((rows[-1] - rows[0]) / height, (cols[-1] - cols[0]) / width) > 0.85  # the fit: 92% of the tighter side
    shown = screen[y:y + height, x:x + width].astype(int)
    # the same pixels but for a few on triangle edges (measured: 0 in a window, 1 of 614 400 fullscreen)
    assert np.mean(np.abs(shown - frame).max(axis=2) > 1) < 1e-4, info
    assert brain_pixels(frame) > 0.2 * width * height
    assert patch_pixels(frame) > 10




_MIXED = r"""
import json
import numpy as np
from sim.geometry.mesh import load_mesh
from sim.view.window import HandState, ParticipantView
mesh = load_mesh()
pictures = ParticipantView(mesh, width=320, height=240, visible=False)
pictures.draw(None, [HandState(tuple(mesh.vertices[3386]), grasped_vertex=3386)])
first = pictures.image()
window = ParticipantView(mesh, width=320, height=240)
window.draw(None, [])
again = ParticipantView(mesh, width=320, height=240, visible=False)
again.draw(None, [])
shown = window.image()
same = pictures.image()
window.close()
pictures.close()
print(json.dumps({"same": bool(np.array_equal(first, same)), "differs": int((np.abs(first.astype(int) - shown).max(axis=2) > 30).sum()),
                  "plain": bool(np.array_equal(shown, again.image()))}))
"""


def test_window_and_offscreen_views_live_side_by_side_in_one_process(display):
    """A session's window and offscreen pictures (GLX and EGL contexts) in one process, made and
    used in turns: each view draws its own scene (once, this ended the process with BadAccess)."""
    out = subprocess.run([sys.executable, "-c", _MIXED], capture_output=True, text=True, env=dict(os.environ, DISPLAY=display), timeout=120,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.returncode == 0, out.stderr[-2000:]
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r == {"same": True, "differs": r["differs"], "plain": True}  # the grasped patch and the forceps
    assert r["differs"] > 100


def test_a_plugin_model_in_the_window_with_the_mouse(xdotool, tmp_path):
    """A lab's own model (tests/plugins, named "package.module:Class" in the scene) held with
    the mouse: its force, written as `force` only, reaches the servo process as a copy of the
    model (sim.models.api.ModelForce) and is felt and recorded like a built-in model's."""
    from tests.helpers import BAD, plugin_scene

    scene = plugin_scene(tmp_path, f"{BAD}:Spring")
    s = _drag_in_sim_live("--scene", str(scene), "--model", f"{BAD}:Spring")
    assert s["model"] == f"{BAD}:Spring"
    assert s["events"].get("grasp", 0) >= 1
    assert s["max_force_per_hand_n"]["left"] > 0.02
    assert "model_fault" not in s["events"]
    assert "nan_force" not in s["events"]
