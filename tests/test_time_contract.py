"""A model that uses time (sim.models.api, `uses_time`) is told the tick's time and the hand's
velocity; a model that does not is called as before."""

import math
from dataclasses import dataclass

import numpy as np
import pytest

from sim.devices.base import DeviceState
from sim.models.api import Contact, TissueModel, option
from sim.run import run_scene
from sim.scene import Scene, load_scene
from sim.servo.loop import Hand, ServoLoop
from sim.servo.velocity import WINDOW_S
from tests.conftest import SCENE
from tests.helpers import lockstep_trace

OMNI_STEP_M = 55e-6


class KelvinVoigt(TissueModel):
    """A spring and a dashpot under the grasp: force on the hand -(k d + c v)."""

    description = "a Kelvin-Voigt contact (tests)"
    uses_time = True

    @dataclass(frozen=True)
    class Options:
        k: float = option(20.0, unit="N/m", lo=0.0)
        c: float = option(2.0, unit="N s/m", lo=0.0)

    def __init__(self, mesh=None, options=None, scene=None):
        self.mesh = mesh
        o = options or {"k": 20.0, "c": 2.0}
        self.k, self.c = o["k"], o["c"]
        self.times: list = []

    def grasp(self, point, hand=0):
        vertex = 0 if self.mesh is None else int(np.argmin(np.linalg.norm(self.mesh.vertices - np.asarray(point), axis=1)))
        return Contact(hand=hand, vertex=vertex, point=tuple(float(x) for x in point), normal=(0.0, 0.0, 1.0))

    def force(self, contact, displacement, velocity=None, t=None):
        if velocity is None or t is None:
            raise TypeError("a model that uses time is told the velocity and the time")
        self.times.append(t)
        return tuple(-(self.k * d + self.c * v) for d, v in zip(displacement, velocity))

    def deformation(self, contacts, displacements, velocities=None, t=None):
        if velocities is None or t is None:
            raise TypeError("a model that uses time is told the velocities and the time")
        return np.zeros((len(self.mesh.vertices), 3)) if self.mesh is not None else np.zeros((0, 3))


class Ramp:
    """A hand held closed from t = 0, moving at `speed` (m/s) along x, its position read in
    steps of `step` m (0: exact)."""

    def __init__(self, speed, step=0.0):
        self.speed, self.step, self.sent = speed, step, []

    def read(self, t):
        x = self.speed * t
        if self.step:
            x = math.floor(x / self.step) * self.step
        return DeviceState(position=(x, 0.0, 0.0), button=True)

    def write_force(self, f):
        self.sent.append(tuple(f))

    def close(self):
        pass


def _servo(speed, step=0.0, ticks=300):
    dev = Ramp(speed, step)
    hand = Hand(index=0, name="h", device=dev)
    model = KelvinVoigt()
    servo = ServoLoop(model=model, hands=[hand], peak_force=3.3, ramp_s=0.05)
    servo.tick(0.0)
    hand.contact_t, hand.contact = 0.0, model.grasp((0.0, 0.0, 0.0))
    for i in range(1, ticks):
        servo.tick(i * 1e-3)
    return np.array(dev.sent), model, servo


def test_a_time_model_gets_the_ticks_time_and_the_hands_velocity():
    speed = 0.01
    sent, model, servo = _servo(speed)
    assert servo.timed
    assert model.times[0] == pytest.approx(0.001) and model.times[-1] == pytest.approx(0.299)
    t = np.arange(len(sent)) * 1e-3
    after = t >= 0.05 + WINDOW_S  # past the grasp's force ramp and a full velocity window
    want = -(20.0 * speed * t + 2.0 * speed)
    assert np.allclose(sent[after, 0], want[after], rtol=1e-9)
    assert abs(2.0 * speed) / abs(want[after][0]) > 0.5  # the dashpot is most of the force there: a test of v, not of d


def test_on_an_omnis_position_steps_the_viscous_force_is_within_one_velocity_step():
    speed = 0.01
    sent, _, _ = _servo(speed, step=OMNI_STEP_M)
    t = np.arange(len(sent)) * 1e-3
    after = t >= 0.05 + WINDOW_S
    want = -(20.0 * speed * t + 2.0 * speed)
    allowed = 20.0 * OMNI_STEP_M + 2.0 * OMNI_STEP_M / WINDOW_S  # one step of position and of velocity
    assert np.max(np.abs(sent[after, 0] - want[after])) <= allowed
    # on average the floored position is half a step short (the spring's part), and the velocity right
    assert np.mean(sent[after, 0] - want[after]) == pytest.approx(20.0 * OMNI_STEP_M / 2, rel=0.1)


def _windowed_velocity(times, positions):
    """The velocity CHAI3D's window gives on a recorded trace (numpy, written apart from
    `sim.servo.velocity`): position now minus the oldest within 15 ms, over the time between."""
    out = np.zeros_like(positions)
    for k in range(len(times)):
        j = int(np.searchsorted(times, times[k] - WINDOW_S - 1e-9))
        if times[k] > times[j]:
            out[k] = (positions[k] - positions[j]) / (times[k] - times[j])
    return out


def _check_kelvin_voigt_trace(r, scene, k=20.0, c=2.0):
    """Every force the run rendered, once a grasp's force ramp and a velocity window are past,
    is -(k d + c v) of the recorded positions (d from the grasped vertex)."""
    checked = 0
    for hand in range(r.positions.shape[1]):
        grasp = next(e for e in r.events if e.kind == "grasp" and e.hand == hand)
        anchor = scene.mesh.vertices[int(grasp.detail.split()[-1])]
        held = r.buttons[:, hand] & (r.times >= grasp.t + 0.05 + WINDOW_S + 1e-9)
        released = [e.t for e in r.events if e.kind == "release" and e.hand == hand]
        if released:
            held &= r.times < released[0]
        v = _windowed_velocity(r.times, r.positions[:, hand])
        want = -(k * (r.positions[:, hand] - anchor) + c * v)
        assert np.allclose(r.forces[held, hand], want[held], rtol=1e-9, atol=1e-12)
        checked += int(held.sum())
    return checked


def test_a_time_model_runs_every_tick_in_python_and_its_frames_get_the_time(monkeypatch):
    """In a lockstep run the compiled ticks (laws of d alone) never run a model that uses time."""
    scene = Scene(load_scene(SCENE))
    model = KelvinVoigt(scene.mesh)
    scene.model = model
    r, compiled = lockstep_trace(scene, True, monkeypatch, duration=1.5)
    assert compiled == 0
    assert np.abs(r.forces).max() > 0.01  # the hands pulled and felt the contact
    assert len(model.times) > 1000
    assert _check_kelvin_voigt_trace(r, scene) > 1000


def test_a_servo_in_another_process_tells_a_time_models_law_the_velocity_and_the_time():
    """In real time the servo process evaluates the model's copy (`ModelForce`) with the
    velocities it estimates and its tick's time: the same rendered law as in lockstep."""
    scene = Scene(load_scene(SCENE))
    scene.model = KelvinVoigt(scene.mesh)
    r = run_scene(scene, duration=1.5, time_scale=1.0)
    assert r.stats()["mode"] == "realtime-process"
    assert "model_fault" not in {e.kind for e in r.events}
    assert _check_kelvin_voigt_trace(r, scene) > 1000


def test_the_bench_pulls_a_time_model_in_time_at_each_speed(monkeypatch):
    """The accuracy bench's pulls (sim/pulls.py, the quick bench's samples) at each of its speeds:
    a Kelvin-Voigt contact's force at each sample is k d + c v at the pull's speed within 1% (it
    is exact: the bench tells the model the hand's velocity), k x_end while held; the quasi-static
    pull is at QUASI_STATIC_M_S, where the dashpot is nothing next to the spring."""
    from analysis.verification import accuracy, bench_pulls
    from analysis.verification.truth_in_time import bench_speeds
    from sim.pulls import make_pulls, scene_with

    cfg = accuracy.quick_config()
    scene = scene_with(cfg.scene)
    monkeypatch.setattr(bench_pulls, "build_model", lambda scene, setting, handset, e_ratio: KelvinVoigt(scene.mesh))
    pulls = make_pulls(scene)[:2]
    xs = accuracy.sample_displacements(cfg)
    for sp in bench_speeds(("quasi-static", "typical", "fast")):
        out = bench_pulls.model_pulls(cfg.scene, None, accuracy.Setting("kelvin_voigt", "default"), pulls, xs, speed=sp.speed_m_s, holds=sp.holds_s)
        v = bench_pulls.QUASI_STATIC_M_S if sp.speed_m_s is None else sp.speed_m_s
        assert out["in_time"] and out["speed_m_s"] == v
        for p, pull in enumerate(pulls):
            e = np.asarray(pull.direction)
            want = -np.vstack([20.0 * np.outer(xs, e) + 2.0 * v * e, np.tile(20.0 * xs[-1] * e, (len(sp.holds_s), 1))])
            assert np.allclose(out["force"][p], want, rtol=0.01, atol=0)
            share = 2.0 * v / (20.0 * xs[0] + 2.0 * v)  # the dashpot's share at the first sample
            assert share < 0.01 if sp.speed_m_s is None else share > 0.35


def test_the_contract_check_drives_a_time_model_along_a_ramp():
    """`model check --contract`'s checks on a model that uses time: it is told the time and the
    velocity (it raises without them), and passes; its forces along the ramp are k d + c v."""
    from analysis.verification.model_check import CONTRACT_SPEED_M_S, CheckConfig, budgets, contract

    scene = Scene(load_scene(SCENE))
    model = KelvinVoigt(scene.mesh)
    scene.model = model
    rows, parts = contract(scene)
    failed = [r for r in rows if r["ok"] is False]
    assert not failed, failed
    assert "finite, continuous force along the pull" in [r["check"] for r in rows]
    assert max(model.times) == pytest.approx(float(np.linalg.norm(parts["pull"])) / CONTRACT_SPEED_M_S)
    # the budgets time the calls a servo makes of it: with the velocity and the time, none raises
    timed = budgets(parts, CheckConfig(scene=SCENE, force_calls=200, frames=6))
    assert [r["budget"] for r in timed] == ["force_us_p99", "deformation_ms_p99", "grasp_ms_p99"]
    assert not any("raised" in r for r in timed)


def test_a_paced_start_gives_the_velocity_of_the_new_clock():
    """A paced run waits (the tick time counts from the run's begin), then its clock starts again
    at the first grasp (`ServoLoop.restart`): the velocity is the hand's from there, never the
    difference of positions read on the two clocks."""
    speed = 0.01
    dev = Ramp(speed)
    hand = Hand(index=0, name="h", device=dev)
    model = KelvinVoigt()
    servo = ServoLoop(model=model, hands=[hand], peak_force=3.3, ramp_s=0.05)
    for k in range(1300):  # 1.3 s waiting
        servo.tick(k * 1e-3)
    servo.restart(keep_last=True)
    hand.contact_t, hand.contact = 0.0, model.grasp(hand.position)
    seen = []
    for k in range(1, 200):  # the devices keep their own clock
        servo.tick(k * 1e-3, device_t=1.299 + k * 1e-3)
        seen.append(hand.velocity[0])
    assert max(seen) <= speed * (1 + 1e-9)  # never the 50 m/s of two clocks' positions
    assert seen[-1] == pytest.approx(speed, rel=1e-9)
    sent = np.array(dev.sent)[-1]
    assert np.linalg.norm(sent) < 0.5  # the dashpot renders 0.02 N, not the device's peak


def test_a_time_model_with_laws_of_d_alone_is_asked_as_one_and_has_no_pair_table():
    """A model that uses time may still give plain `sim.laws` laws (no velocity): they are asked
    `force(d)`; and a pair table (a law of the two displacements) is not sent for it."""
    from sim.laws import Linearised
    from sim.models.api import servo_state

    model = KelvinVoigt()
    law = Linearised(tuple(float(x) for x in np.eye(3).ravel() * 10.0))
    c = Contact(hand=0, vertex=0, point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), law=law)
    assert TissueModel.force(model, c, (0.001, 0.0, 0.0), velocity=(0.5, 0.0, 0.0), t=1.0) == law.force((0.001, 0.0, 0.0))
    model.pair_law = lambda contacts: "a table"
    assert servo_state(model, [c, c])[0] is None


def test_model_check_quick_runs_a_time_model_end_to_end():
    """`studyctl model check --quick` of a model that uses time, named by its class: every contract
    check passes (it raises where it is not told the time and the velocity), the quick sweep runs it
    stable, and the accuracy bench scores it at each speed, raw and calibrated: against the
    timeless truth quasi-static, against the viscoelastic truth at the hands' speeds."""
    import json

    from tests.helpers import studyctl

    res = studyctl("model", "check", "tests.test_time_contract:KelvinVoigt", "--quick", "--json")
    assert res.exit_code in (0, 1), res.output  # 1: a budget or a rate the card reports as missed, not a crash
    card = json.loads(res.stdout if hasattr(res, "stdout") else res.output)
    assert card["contract"] and all(r["ok"] is not False for r in card["contract"]), card["contract"]
    assert card["stability"]["counts"] == {"stable": 4, "unstable": 0, "refused": 0} and card["stability"]["safety_held"]
    rows = {(r["speed"], r["calibration"]): r for r in card["accuracy"]["rows"]}
    assert set(rows) == {(v, c) for v in ("quasi-static", "typical", "fast") for c in ("raw", "calibrated")}
    for (speed, _), r in rows.items():
        if speed == "quasi-static":  # against the timeless truth, where it is decided
            assert math.isfinite(r["force_error"]) and r["n_test"] > 0
        else:  # against the viscoelastic truth at the pull's speed, which rests beyond the data's rates: scored, not judged
            assert r["speed_m_s"] > 0.01 and r["n_test"] == 0 and r["force_error"] is None
            assert math.isfinite(r["force_error_extrapolated"]) and r["extrapolated"] > 0
