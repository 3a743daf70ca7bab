"""The servo's velocity estimate (sim/servo/velocity.py) against what the positions say."""

import numpy as np
import pytest

from sim.servo.velocity import WINDOW_S, VelocityEstimate

DT = 1e-3
OMNI_STEP_M = 55e-6  # the Omni's position resolution at the tip (about 0.055 mm)


def _run(positions, est=None):
    est = est or VelocityEstimate()
    return np.array([est.update(k * DT, tuple(p)) for k, p in enumerate(positions)])


def test_a_constant_velocity_is_read_exactly_once_the_window_holds_two_positions():
    v = np.array([0.01, -0.004, 0.002])  # m/s
    t = np.arange(200) * DT
    out = _run(t[:, None] * v)
    assert np.all(out[0] == 0.0)  # one position: no velocity yet
    assert np.allclose(out[1:], v, rtol=1e-9, atol=1e-12)


def test_quantised_positions_give_the_speed_within_one_step_over_the_window():
    """A 10 mm/s pull read in the Omni's 55 um steps: every estimate after the window fills is
    within one step over the window (3.7 mm/s), and their mean is the speed."""
    speed = 0.010
    t = np.arange(2000) * DT
    x = np.floor(speed * t / OMNI_STEP_M) * OMNI_STEP_M
    out = _run(np.stack([x, np.zeros_like(x), np.zeros_like(x)], axis=1))[int(WINDOW_S / DT) + 1:, 0]
    resolution = OMNI_STEP_M / WINDOW_S
    assert resolution == pytest.approx(3.67e-3, rel=1e-2)
    assert np.all(np.abs(out - speed) <= resolution + 1e-12)
    assert np.mean(out) == pytest.approx(speed, rel=0.02)
    # one tick's difference would be 0 or 55 mm/s: the window is why the estimate is usable
    assert np.max(np.abs(np.diff(x))) / DT == pytest.approx(0.055)


def test_a_start_from_rest_is_followed_within_the_window_and_a_reset_forgets():
    speed = 0.02
    t = np.arange(100) * DT
    x = np.where(t >= 0.05, (t - 0.05) * speed, 0.0)
    est = VelocityEstimate()
    out = _run(np.stack([x, 0 * x, 0 * x], axis=1), est)[:, 0]
    assert np.all(out[:51] == 0.0)
    k = 50 + int(round(WINDOW_S / DT))  # a full window after the start
    assert out[k] == pytest.approx(speed, rel=1e-9)
    assert 0 < out[50 + 7] < speed  # half way through the window: half the speed
    est.reset()
    assert est.update(1.0, (0.3, 0.0, 0.0)) == (0.0, 0.0, 0.0)


def test_a_window_that_is_not_positive_is_refused():
    with pytest.raises(ValueError, match="window: 0 is out of range; allowed: > 0 s"):
        VelocityEstimate(0)


def test_a_clock_that_starts_again_starts_the_window_again():
    """A paced run's clock goes back to 0 at its first grasp, and between runs it stands still:
    the window starts again from the new clock's first position, never mixing the two."""
    est = VelocityEstimate()
    for k in range(500):  # waiting: the hand moves at 10 mm/s on the old clock
        est.update(k * DT, (0.01 * k * DT, 0.0, 0.0))
    assert est.update(0.0, (0.005, 0.0, 0.0)) == (0.0, 0.0, 0.0)  # the new clock's t = 0
    v = est.update(DT, (0.005 + 0.01 * DT, 0.0, 0.0))
    assert v[0] == pytest.approx(0.01, rel=1e-9)
    for _ in range(1000):  # a clock standing still keeps one position, not a growing list
        est.update(5.0, (0.0, 0.0, 0.0))
    assert len(est._times) == 1
