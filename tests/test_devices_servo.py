"""The simulated Omni and the servo tick's safety rules."""

import math

import numpy as np
import pytest

from sim.devices.base import OmniSpec
from sim.devices.simulated import HandImpedance, PullScript, SimulatedOmni, min_jerk
from sim.models.api import Contact, TissueModel
from sim.servo.loop import Hand, ServoLoop, limit_force


def _still(start=(0.0, 0.0, 0.0), pull=(0.0, 0.0, 0.0)):
    return PullScript(start=start, pull=pull, grasp_at=0.0, pull_start=0.0, pull_time=1.0, release_at=10.0)


def test_min_jerk_profile():
    assert min_jerk(0) == 0
    assert min_jerk(1) == 1
    assert min_jerk(0.5) == pytest.approx(0.5)
    # zero velocity at both ends: the profile is flat there
    assert min_jerk(1e-3) < 1e-8
    assert 1 - min_jerk(1 - 1e-3) < 1e-8


def test_positions_are_quantised_to_the_encoder_resolution():
    dev = SimulatedOmni(_still(pull=(0.0123456, 0.0, 0.0)), origin=(0.0, 0.0, 0.0))
    for t in np.linspace(0.01, 1.5, 30):
        x = dev.read(float(t)).position[0]
        k = x / 0.055e-3
        assert abs(k - round(k)) < 1e-6


def test_workspace_limits_the_hand():
    # a target 0.2 m away along x: the stylus stops at the 160 mm workspace's edge (80 mm)
    dev = SimulatedOmni(_still(pull=(0.2, 0.0, 0.0)), origin=(0.0, 0.0, 0.0))
    x = dev.read(3.0).position[0]
    assert x == pytest.approx(0.08, abs=0.06e-3)
    dev = SimulatedOmni(_still(pull=(0.0, 0.0, -0.2)), origin=(0.0, 0.0, 0.0))
    assert dev.read(3.0).position[2] == pytest.approx(-0.035, abs=0.06e-3)


def test_rendered_force_moves_the_hand_through_its_impedance():
    imp = HandImpedance()
    dev = SimulatedOmni(_still(), origin=(0.0, 0.0, 0.0), impedance=imp)
    dev.write_force((0.6, 0.0, 0.0))
    x = dev.read(3.0).position[0]
    assert x == pytest.approx(0.6 / imp.stiffness_n_per_m, rel=0.02)  # static offset F / k


def test_device_motors_saturate_at_peak_and_ignore_nan():
    dev = SimulatedOmni(_still(), origin=(0.0, 0.0, 0.0))
    dev.write_force((10.0, 0.0, 0.0))
    assert dev.max_force_applied == pytest.approx(OmniSpec().peak_force_n)
    dev.write_force((math.nan, 0.0, 0.0))  # treated as no force: no NaN reaches the hand
    assert all(math.isfinite(c) for c in dev.read(0.6).position)


def test_limit_force_rules():
    assert limit_force((math.nan, 0, 0), 3.3) == ((0.0, 0.0, 0.0), "nan_force")
    assert limit_force((math.inf, 0, 0), 3.3) == ((0.0, 0.0, 0.0), "nan_force")
    f, kind = limit_force((6.0, 8.0, 0.0), 3.3)
    assert kind == "force_clamped"
    assert math.hypot(*f) == pytest.approx(3.3)
    assert f[0] / f[1] == pytest.approx(0.75)
    assert limit_force((0.1, 0.2, 0.3), 3.3) == ((0.1, 0.2, 0.3), None)


class _Stiff(TissueModel):
    """A model returning k * displacement, or NaN when asked."""

    def __init__(self, k):
        self.k = k

    def force(self, contact, d):
        return (-self.k * d[0], -self.k * d[1], -self.k * d[2])


def _servo(model, pull):
    dev = SimulatedOmni(_still(pull=pull), origin=(0.0, 0.0, 0.0))
    hand = Hand(index=0, name="h", device=dev)
    servo = ServoLoop(model=model, hands=[hand], peak_force=3.3, ramp_s=0.05)
    return servo, hand


def test_servo_ramps_clamps_and_logs():
    servo, hand = _servo(_Stiff(400.0), pull=(0.05, 0.0, 0.0))
    servo.tick(0.0)
    assert hand.grasp_request is not None  # button pressed: a grasp is requested, not done here
    hand.contact_t = 0.0
    hand.contact = Contact(hand=0, vertex=0, point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0))
    forces = []
    for k in range(1, 3000):
        servo.tick(k / 1000)
        forces.append(math.hypot(*hand.force))
    forces = np.array(forces)
    assert forces.max() <= 3.3 + 1e-12
    assert forces[:49].max() <= 400 * 0.05 * 0.05  # ramped during the first 50 ms
    kinds = [e.kind for e in servo.events]
    assert kinds.count("force_clamped") >= 1
    assert "grasp_request" in kinds


def test_servo_zeroes_nan_from_a_model():
    servo, hand = _servo(_Stiff(math.nan), pull=(0.01, 0.0, 0.0))
    servo.tick(0.0)
    hand.contact = Contact(hand=0, vertex=0, point=(0.0, 0.0, -0.001), normal=(0.0, 0.0, 1.0))
    for k in range(1, 100):
        servo.tick(k / 1000)
        assert hand.force == (0.0, 0.0, 0.0)
    assert [e.kind for e in servo.events].count("nan_force") == 1  # logged once, when it starts


def test_servo_zeroes_force_while_the_model_is_unstable():
    model = _Stiff(100.0)
    servo, hand = _servo(model, pull=(0.01, 0.0, 0.0))
    servo.tick(0.0)
    hand.contact = Contact(hand=0, vertex=0, point=(0.0, 0.0, -0.001), normal=(0.0, 0.0, 1.0))
    servo.tick(0.1)
    assert hand.force != (0.0, 0.0, 0.0)
    model.unstable = True
    for k in range(2, 50):
        servo.tick(k / 10)
        assert hand.force == (0.0, 0.0, 0.0)
    assert [e.kind for e in servo.events].count("model_unstable") == 1
