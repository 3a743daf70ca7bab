"""The OpenHaptics binding against a fake libHD.so compiled here (two devices, a scheduler)."""

import ctypes
import math
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from sim.devices.openhaptics import HDError, OpenHapticsRig, load_library
from sim.errors import DeviceError
from sim.models.api import Contact, TissueModel
from sim.servo.loop import Hand, ServoLoop

SOURCE = Path(__file__).parent / "fake_libhd" / "fake_libhd.c"


@pytest.fixture
def libhd(tmp_path):
    """A fresh copy of the fake library per test (its state is global to the loaded object)."""
    if shutil.which("gcc") is None:
        pytest.skip("gcc is needed to build the fake libHD.so")
    out = tmp_path / "libHD.so"
    subprocess.run(["gcc", "-shared", "-fPIC", "-O2", "-o", str(out), str(SOURCE), "-lpthread", "-lm"], check=True)
    return str(out)


def test_missing_library_says_what_to_install(tmp_path):
    """(A missing dependency of an existing libHD is named instead: see below.)"""
    with pytest.raises(DeviceError, match="OpenHaptics toolkit .* BRAINSIM_LIBHD"):
        load_library(str(tmp_path / "nope.so"))


def test_unknown_device_name_raises_with_the_error_name(libhd):
    with pytest.raises(HDError, match=r"opening 'Middle Device' \(the names are set .*--devices.*\): HD_COMM_CONFIG_ERROR") as exc:
        OpenHapticsRig(["Left Device", "Middle Device"], library=libhd)
    assert exc.value.code == 0x0303


def _run_rig(rig, seconds):
    rig.start(lambda t: None)
    time.sleep(seconds)
    rig.stop()


def test_calibration_is_done_inside_frames_after_the_scheduler_starts_with_one_style(libhd):
    fake = ctypes.CDLL(libhd)
    fake.fakehd_set_calibration(0, 0x5001)  # needs an automatic update
    fake.fakehd_set_calibration(1, 0x5002)  # the right device needs the inkwell
    rig = OpenHapticsRig(["Left Device", "Right Device"], library=libhd)  # opening does not touch calibration
    assert rig.slots[0].style == 1 << 1  # auto, of auto | inkwell
    _run_rig(rig, 0.1)
    assert rig.errors == []  # the strict fake saw nothing out of order
    assert fake.fakehd_pending_errors() == 0
    assert rig.slots[0].calibrated
    assert not rig.slots[1].calibrated
    assert rig.slots[1].fault == "needs calibration"
    notices = rig.take_notices()
    assert "Left Device: calibrated" in notices
    assert "Right Device needs calibration: put the stylus in its inkwell" in notices
    fake.fakehd_set_calibration(1, 0x5000)  # the experimenter puts the stylus in the inkwell
    _run_rig(rig, 0.05)
    assert rig.slots[1].calibrated
    assert rig.slots[1].fault is None
    assert rig.take_notices() == ["Right Device: calibrated"]
    rig.close()


def test_the_strict_fake_refuses_what_the_vendor_forbids(libhd):
    lib = load_library(libhd)
    handle = lib.hdInitDevice(b"Default Device")  # the first configured device
    assert handle == 0
    assert lib.hdCheckCalibration() == 0  # not before the scheduler, not outside a frame
    assert lib.hdGetError().errorCode == 0x0102
    lib.hdUpdateCalibration(0b110)
    assert lib.hdGetError().errorCode == 0x0102  # not before the scheduler
    assert lib.hdInitDevice(b"Left Device") == 0xFFFFFFFF  # already open
    assert lib.hdGetError().errorCode == 0x0301
    lib.hdDisableDevice(handle)


def test_a_rig_flushes_old_errors_before_opening(libhd):
    lib = load_library(libhd)
    lib.hdInitDevice(b"Nobody")  # leaves HD_COMM_CONFIG_ERROR on the stack
    rig = OpenHapticsRig(["Left Device"], library=libhd)  # not mistaken for an error of this rig
    assert rig.slots[0].name == "Left Device"
    fake = ctypes.CDLL(libhd)
    assert fake.fakehd_soft_limit(0)
    assert fake.fakehd_ramping(0)
    assert fake.fakehd_force_enabled(0)
    rig.close()


def test_a_missing_dependency_of_libhd_is_named(tmp_path):
    if shutil.which("gcc") is None:
        pytest.skip("gcc is needed")
    dep = tmp_path / "dep"
    dep.mkdir()
    (dep / "x.c").write_text("int dep_fn(void) { return 1; }\n")
    subprocess.run(["gcc", "-shared", "-fPIC", "-Wl,-soname,libncursesfake.so.5", "-o", str(dep / "libncursesfake.so.5"), str(dep / "x.c")],
                   check=True)
    (dep / "libncursesfake.so").symlink_to(dep / "libncursesfake.so.5")
    lib = tmp_path / "libHD.so"
    subprocess.run(["gcc", "-shared", "-fPIC", "-O2", "-o", str(lib), str(SOURCE), f"-L{dep}", "-Wl,--no-as-needed", "-lncursesfake",
                    "-lpthread", "-lm"], check=True)
    shutil.rmtree(dep)  # libHD is there; what it needs is not
    with pytest.raises(DeviceError, match=r"libHD.so was found but needs libncursesfake.so.5, which is missing") as exc:
        load_library(str(lib))
    assert "\n" not in str(exc.value)


def test_warm_motors_bring_the_force_down_to_the_continuous_force():
    from sim.devices.openhaptics import _WarmMotors

    guard = _WarmMotors(0.88)
    f = (2.0, 0.0, 0.0)
    assert guard(f, 0.5) == f  # cool: untouched
    out = [guard(f, 0.8)[0] for _ in range(3000)]  # warm: the clamp shrinks 0.1% a tick
    assert out[0] <= 2.0
    assert out[500] < 1.3
    assert abs(out[-1] - 0.88) < 1e-9
    back = [guard((0.5, 0.0, 0.0), 0.4)[0] for _ in range(10)]  # cooled and under the clamp: lifted
    assert back[-1] == 0.5
    assert guard.clamp == math.inf


def test_one_callback_serves_both_devices_with_frames_and_clamped_forces(libhd):
    fake = ctypes.CDLL(libhd)
    fake.fakehd_max_force.restype = ctypes.c_double
    fake.fakehd_frames.restype = ctypes.c_long
    rig = OpenHapticsRig(["Left Device", "Right Device"], library=libhd)
    assert all(fake.fakehd_force_enabled(i) and fake.fakehd_ramping(i) for i in range(2))
    devices = rig.devices()

    class Stiff(TissueModel):  # a very stiff spring: forces far above the peak are asked for
        def force(self, contact, d):
            return (-1e4 * d[0], -1e4 * d[1], -1e4 * d[2])

    hands = [Hand(index=i, name=d.name, device=d) for i, d in enumerate(devices)]
    servo = ServoLoop(model=Stiff(), hands=hands, peak_force=3.3, ramp_s=0.01)

    def tick(t):
        for h in hands:  # grasp wherever the stylus is on the first tick
            if h.contact is None and h.ticks > 0 and not math.isnan(h.position[0]):
                h.contact_t = t
                h.contact = Contact(hand=h.index, vertex=0, point=h.position, normal=(0.0, 0.0, 1.0))
        servo.tick(t)

    rig.start(tick)
    time.sleep(0.4)
    rig.stop()
    frames = [fake.fakehd_frames(i) for i in range(2)]
    assert min(frames) > 100  # both devices every tick
    assert abs(frames[0] - frames[1]) <= 1
    assert not any(fake.fakehd_in_frame(i) for i in range(2))  # every begin had its end
    assert all(0.5 < fake.fakehd_max_force(i) <= 3.3 + 1e-12 for i in range(2))  # clamped, never above the peak
    assert rig.errors == []
    # positions arrive in metres: the fake's stylus circles 3 mm about its origin
    assert all(abs(h.position[0]) <= 0.0031 and -0.0041 <= h.position[1] <= 1e-9 for h in hands)
    rig.close()


def test_device_fault_in_a_frame_becomes_zero_force_and_an_event(libhd):
    fake = ctypes.CDLL(libhd)
    rig = OpenHapticsRig(["Left Device", "Right Device"], library=libhd)
    devices = rig.devices()
    hands = [Hand(index=i, name=d.name, device=d) for i, d in enumerate(devices)]

    class Push(TissueModel):
        def force(self, contact, d):
            return (1.0, 0.0, 0.0)

    servo = ServoLoop(model=Push(), hands=hands, peak_force=3.3, ramp_s=0.001)

    for h in hands:
        h.contact = Contact(hand=h.index, vertex=0, point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0))
    rig.start(servo.tick)
    time.sleep(0.1)
    fake.fakehd_set_fault(0, 1)
    time.sleep(0.1)
    rig.stop()
    assert any(isinstance(e, HDError) and e.name == "HD_DEVICE_FAULT" for e in rig.errors)
    assert "device_fault" in [e.kind for e in servo.events if e.hand == 0]
    assert rig.slots[0].fault == "HD_DEVICE_FAULT"
    assert hands[0].force == (0.0, 0.0, 0.0)
    assert hands[1].force == (1.0, 0.0, 0.0)  # the other hand carries on
    rig.close()


def _openhaptics_scene(tmp_path):
    from tests.conftest import SCENE
    from tests.helpers import localise

    text = localise(SCENE.read_text()).replace('device = "simulated"', 'device = "openhaptics"').replace('kind = "offscreen"', 'kind = "none"')
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def test_sim_run_on_the_rig_is_paced_by_the_hd_scheduler(libhd, tmp_path, monkeypatch):
    import numpy as np

    from sim.run import run_scene
    from sim.scene import build_scene

    monkeypatch.setenv("BRAINSIM_LIBHD", libhd)
    r = run_scene(build_scene(_openhaptics_scene(tmp_path)), duration=1.2)
    s = r.stats()
    assert s["mode"] == "realtime-process"  # the rig lives in the servo process
    assert s["pacer"] == "hd-scheduler"
    assert s["ticks"] == 1200
    assert s["rate_hz"] > 0  # paced by the fake scheduler (about 1 kHz; no timing assertion here)
    kinds = [e.kind for e in r.events]
    assert "grasp" in kinds  # the fake's button toggles every 0.5 s
    assert "release" in kinds
    f = np.linalg.norm(r.forces, axis=2)
    assert np.all(np.isfinite(f))
    assert f.max() <= 3.3
    assert f.max() > 0.0


def test_cli_without_the_library_is_one_clean_line(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from studyctl.cli import cli

    monkeypatch.setenv("BRAINSIM_LIBHD", str(tmp_path / "missing" / "libHD.so"))
    res = CliRunner().invoke(cli, ["sim", "run", "--scene", str(_openhaptics_scene(tmp_path)), "--duration", "0.1"])
    assert res.exit_code == 1
    assert len(res.output.strip().splitlines()) == 1
    assert "OpenHaptics HD library (libHD.so) was not found" in res.output


def test_device_frame_follows_the_view_and_forces_go_back_along_the_pull(tmp_path):
    """A stylus moved right / up / toward the user moves the drawn instrument right / up / larger
    on the screen (as a person sees it: the rendered picture, not the camera's algebra), and the
    tissue's force on a grasped pull points back along the pull in device coordinates."""
    import numpy as np

    from sim.scene import build_scene
    from sim.view.window import HandState, ParticipantView

    scene = build_scene(_openhaptics_scene(tmp_path), "plate_spring")
    frame = scene.device_frame(0)
    view = ParticipantView(scene.mesh, visible=False, width=640, height=480, camera=scene.spec.view)

    def tips(device_point):
        """Where the left forceps' tips are drawn for a device point 6 cm above the brain (nothing
        hides them): the end of its steel pixels farthest up and right (it comes from the lower
        left), and how many steel pixels there are."""
        view.draw(None, [HandState(frame.to_scene(np.add(device_point, (0.0, 0.0, 0.06))))])
        f = view.image().astype(float)
        ys, xs = np.nonzero((f[:, :, 2] > f[:, :, 0] + 4) & (f.max(axis=2) < 250) & (f.max(axis=2) > 40))
        k = np.argmax(xs - ys)
        return xs[k], ys[k], len(xs)

    try:
        u0, v0, n0 = tips((0.0, 0.0, 0.0))
        u, v, _ = tips((0.01, 0.0, 0.0))
        assert u > u0 + 5  # right on the screen
        assert abs(v - v0) < 0.3 * (u - u0)
        u, v, _ = tips((0.0, 0.01, 0.0))
        assert v < v0 - 5  # up on the screen
        assert abs(u - u0) < 0.3 * (v0 - v)
        u, v, _ = tips((0.0, 0.0, 0.02))  # toward the viewer: farther from the view's centre (perspective)
        assert np.hypot(u - 320, v - 240) > 1.05 * np.hypot(u0 - 320, v0 - 240)
    finally:
        view.close()
    p0 = frame.to_scene((0.0, 0.0, 0.0))
    # a pull to the user's right, 8 mm in device coordinates, on the grasped tissue
    model = scene.model
    contact = model.grasp(p0, 0)
    d_scene = np.asarray(frame.to_scene((0.008, 0.0, 0.0))) - np.asarray(p0)
    f_device = np.asarray(frame.force_to_device(model.force(contact, tuple(d_scene))))
    assert f_device[0] < -0.01
    assert abs(f_device[0]) > 2 * np.hypot(f_device[1], f_device[2])


def test_a_continuous_force_above_the_budget_is_reduced_and_logged():
    from sim.devices.base import OmniSpec

    class Steady(TissueModel):
        def force(self, contact, d):
            return (1.5, 0.0, 0.0)

    class Still:
        spec = OmniSpec()

        def read(self, t):
            from sim.devices.base import DeviceState

            return DeviceState(position=(0.0, 0.0, 0.0), button=True)

        def write_force(self, f):
            pass

    h = Hand(index=0, name="h", device=Still())
    servo = ServoLoop(model=Steady(), hands=[h], peak_force=3.3, continuous_force=0.88, budget_tau_s=1.0, ramp_s=0.001)
    servo.tick(0.0)
    h.contact = Contact(hand=0, vertex=0, point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0))
    forces = []
    for k in range(1, 5000):
        servo.tick(k * 1e-3)
        forces.append(math.sqrt(sum(c * c for c in h.force)))
    assert forces[100] == pytest.approx(1.5)  # within the budget at first
    assert max(forces[-1000:]) <= 0.88 + 1e-12  # then held at the continuous force
    assert [e.kind for e in servo.events].count("force_budget") >= 1


def test_devices_check_on_the_fake_rig(libhd, tmp_path, monkeypatch):
    import json

    from click.testing import CliRunner

    from studyctl.cli import cli

    monkeypatch.setenv("BRAINSIM_LIBHD", libhd)
    res = CliRunner().invoke(cli, ["devices", "check", "--yes", "--seconds", "3", "--json"])
    assert res.exit_code == 0, res.output
    report = json.loads(res.output[res.output.index("{"):])
    assert report["problems"] == []
    assert report["pacer"] == "hd-scheduler"
    assert all(d["calibrated"] and d["moved_mm"] > 5 and d["button_seen"] and 0.45 < d["pulse_n"] <= 0.5 + 1e-9 for d in report["devices"])
    # the right device needs the inkwell: exit 1, and the fix is said
    monkeypatch.setenv("FAKEHD_CALIBRATION", "0x5000,0x5002")
    res = CliRunner().invoke(cli, ["devices", "check", "--seconds", "1"])
    assert res.exit_code == 1
    assert "Right Device: not calibrated: put the stylus in its inkwell" in res.output
    res = CliRunner().invoke(cli, ["devices", "check", "--devices", "PHANToM 1,PHANToM 2", "--seconds", "1"])
    assert res.exit_code == 1
    assert "PHANToM 1: not found (HD_COMM_CONFIG_ERROR)" in res.output
    assert "--devices" in res.output
    monkeypatch.setenv("FAKEHD_NAMES", "PHANToM 1,PHANToM 2")  # the names the configuration tool saved
    monkeypatch.delenv("FAKEHD_CALIBRATION")
    fresh = tmp_path / "fresh" / "libHD.so"  # a new copy: the loaded one has read its names already
    fresh.parent.mkdir()
    shutil.copy(libhd, fresh)
    monkeypatch.setenv("BRAINSIM_LIBHD", str(fresh))
    res = CliRunner().invoke(cli, ["devices", "check", "--devices", "PHANToM 1,PHANToM 2", "--seconds", "3", "--yes", "--json"])
    assert res.exit_code == 0, res.output


def test_a_persons_session_on_two_fake_omnis_in_the_window(libhd, display, tmp_path, monkeypatch):
    """The whole path with real-device code: the strict fake libHD in the servo process, the
    participant view in a real window, answers typed on a pseudo-terminal."""
    import sqlite3

    from tests.helpers import participant_protocol, pty_session, studyctl

    db = tmp_path / "s.db"
    studyctl("study", "init", "--protocol", participant_protocol(tmp_path, trials=1, trial_seconds=1.0, training=0.05), "--db", db)
    studyctl("participants", "add", "P01", "--db", db)
    studyctl("participants", "consent", "P01", "--db", db)
    log = tmp_path / "hd.log"
    monkeypatch.setenv("BRAINSIM_LIBHD", libhd)
    monkeypatch.setenv("FAKEHD_LOG", str(log))
    text = pty_session(["session", "run", "--db", db, "--participant", "P01", "--device", "openhaptics", "--view", "window"],
                       lambda: "y", timeout=180)
    assert "complete" in text, text
    con = sqlite3.connect(db)
    assert con.execute("select count(*) from answers").fetchone()[0] == 27
    trials = con.execute("select started_by, grasped, tick_interval_p99_us from trials").fetchall()
    assert len(trials) == 3  # the fake's button grasps
    assert all(t[0] == "grasp" and t[1] == 1 and t[2] is not None for t in trials)
    lines = log.read_text().splitlines()
    assert sorted(ln for ln in lines if ln.startswith("init")) == ["init Left Device", "init Right Device"]  # once per session
    assert not [ln for ln in lines if ln.startswith("error")]  # the strict fake saw nothing out of order
