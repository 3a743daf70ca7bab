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
from sim.servo import Hand, ServoLoop

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
    with pytest.raises(DeviceError, match="OpenHaptics toolkit .* BRAINSIM_LIBHD"):
        load_library(str(tmp_path / "nope.so"))


def test_unknown_device_name_raises_with_the_error_name(libhd):
    with pytest.raises(HDError, match="opening 'Middle Device': HD_COMM_CONFIG_ERROR") as exc:
        OpenHapticsRig(["Left Device", "Middle Device"], library=libhd)
    assert exc.value.code == 0x0303


def test_calibration_is_checked(libhd):
    fake = ctypes.CDLL(libhd)
    fake.fakehd_set_calibration(1, 0x5002)  # the right device needs the inkwell
    with pytest.raises(DeviceError, match="'Right Device' needs calibration"):
        OpenHapticsRig(["Right Device"], library=libhd)
    fake.fakehd_set_calibration(1, 0x5001)  # needs an automatic update: done, then fine
    rig = OpenHapticsRig(["Right Device"], library=libhd)
    rig.close()


def test_one_callback_serves_both_devices_with_frames_and_clamped_forces(libhd):
    fake = ctypes.CDLL(libhd)
    fake.fakehd_max_force.restype = ctypes.c_double
    fake.fakehd_frames.restype = ctypes.c_long
    rig = OpenHapticsRig(["Left Device", "Right Device"], library=libhd)
    assert all(fake.fakehd_force_enabled(i) and fake.fakehd_ramping(i) for i in range(2))
    devices = rig.devices()

    class Stiff:  # a very stiff spring: forces far above the peak are asked for
        def force(self, contact, d):
            return (-1e4 * d[0], -1e4 * d[1], -1e4 * d[2])

    hands = [Hand(index=i, name=d.name, device=d) for i, d in enumerate(devices)]
    servo = ServoLoop(model=Stiff(), hands=hands, peak_force=3.3, ramp_s=0.01)
    from sim.models.base import Contact

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
    assert min(frames) > 100 and abs(frames[0] - frames[1]) <= 1  # both devices every tick
    assert not any(fake.fakehd_in_frame(i) for i in range(2))  # every begin had its end
    assert all(0.5 < fake.fakehd_max_force(i) <= 3.3 + 1e-12 for i in range(2))  # clamped, never above the peak
    assert rig.errors == []
    # positions arrive in metres: the fake's stylus circles at x = -20 mm +- 10 mm
    assert -0.031 < hands[0].position[0] < -0.009 and 0.009 < hands[1].position[0] < 0.031
    rig.close()


def test_device_fault_in_a_frame_becomes_zero_force_and_an_event(libhd):
    fake = ctypes.CDLL(libhd)
    rig = OpenHapticsRig(["Left Device", "Right Device"], library=libhd)
    devices = rig.devices()
    hands = [Hand(index=i, name=d.name, device=d) for i, d in enumerate(devices)]

    class Push:
        def force(self, contact, d):
            return (1.0, 0.0, 0.0)

    servo = ServoLoop(model=Push(), hands=hands, peak_force=3.3, ramp_s=0.001)
    from sim.models.base import Contact

    for h in hands:
        h.contact = Contact(hand=h.index, vertex=0, point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0))
    rig.start(servo.tick)
    time.sleep(0.1)
    fake.fakehd_set_fault(0, 1)
    time.sleep(0.1)
    rig.stop()
    assert any(isinstance(e, HDError) and e.name == "HD_DEVICE_FAULT" for e in rig.errors)
    assert "device_fault" in [e.kind for e in servo.events if e.hand == 0]
    assert rig.slots[0].fault == "HD_DEVICE_FAULT" and hands[0].force == (0.0, 0.0, 0.0)
    assert hands[1].force == (1.0, 0.0, 0.0)  # the other hand carries on
    rig.close()


def _openhaptics_scene(tmp_path):
    from tests.conftest import SCENE
    from tests.test_scene import _localise

    text = _localise(SCENE.read_text()).replace('device = "simulated"', 'device = "openhaptics"').replace('kind = "offscreen"', 'kind = "none"')
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
    assert s["mode"] == "scheduled" and s["ticks"] == 1200
    assert s["rate_hz"] > 0  # paced by the fake scheduler (about 1 kHz; no timing assertion here)
    kinds = [e.kind for e in r.events]
    assert "grasp" in kinds and "release" in kinds  # the fake's button toggles every 0.5 s
    f = np.linalg.norm(r.forces, axis=2)
    assert np.all(np.isfinite(f)) and f.max() <= 3.3 and f.max() > 0.0


def test_cli_without_the_library_is_one_clean_line(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from studyctl.cli import cli

    monkeypatch.setenv("BRAINSIM_LIBHD", str(tmp_path / "missing" / "libHD.so"))
    res = CliRunner().invoke(cli, ["sim", "run", "--scene", str(_openhaptics_scene(tmp_path)), "--duration", "0.1"])
    assert res.exit_code == 1 and len(res.output.strip().splitlines()) == 1
    assert "OpenHaptics HD library (libHD.so) was not found" in res.output
