"""sim.targets.TargetTracker with hand-worked numbers: a 40 mm target along +x, 3 mm tolerance,
0.5 s hold, 0.29 N safe force."""

import math
from types import SimpleNamespace

import pytest

from sim.targets import HandTarget, TargetSpec, TargetTracker

SPEC = TargetSpec(distance=0.040, tolerance=0.003, hold=0.5, safe_force=0.29)


def hand(x, y=0.0, z=0.0, grasped=True, force=(0.0, 0.0, 0.0)):
    return SimpleNamespace(position=(x, y, z), force=force, contact=object() if grasped else None)


def tracker():
    # the first hand has a target along +x from a grasp point at (0.01, 0, 0); the second none
    return TargetTracker([HandTarget(SPEC, (1.0, 0.0, 0.0)), None], [(0.01, 0.0, 0.0), (0.0, 0.0, 0.0)])


def test_before_a_grasp_the_target_is_shown_from_the_scenes_grasp_point():
    tr = tracker()
    st = tr.states[0]
    assert tr.states[1] is None
    assert tr.any
    assert not tr.all_held
    assert st.point == pytest.approx((0.05, 0.0, 0.0))
    assert st.progress == 0.0
    assert math.isnan(st.error)
    tr.update(0.0, [hand(0.02, grasped=False), hand(0.0, grasped=False)])
    assert st.point == pytest.approx((0.05, 0.0, 0.0))
    assert not st.on_target


def test_progress_error_on_target_hold_and_latch():
    tr = tracker()
    st = tr.states[0]
    other = hand(0.0, grasped=False)
    tr.update(0.0, [hand(0.02), other])  # the grasp takes hold at x = 20 mm: the target is at 60 mm now
    assert st.point == pytest.approx((0.06, 0.0, 0.0))
    assert st.progress == 0.0
    assert st.error == pytest.approx(0.040)
    tr.update(0.1, [hand(0.04, 0.004), other])  # 20 mm along, 4 mm off the line
    assert st.progress == pytest.approx(0.5)
    assert st.error == pytest.approx(math.hypot(0.020, 0.004))
    assert not st.on_target
    tr.update(0.2, [hand(0.058, 0.002), other])  # 38 mm along, 2 mm off: error sqrt(8) = 2.83 mm <= 3 mm
    assert st.progress == pytest.approx(0.95)
    assert st.error == pytest.approx(math.sqrt(8) * 1e-3)
    assert st.on_target
    assert not st.held
    tr.update(0.6, [hand(0.061), other])  # on target 0.4 s: not yet held
    assert st.on_target
    assert st.progress == pytest.approx(1.025)
    assert not st.held
    tr.update(0.65, [hand(0.064), other])  # 4 mm past: off target, the hold starts again
    assert not st.on_target
    assert not st.held
    tr.update(0.7, [hand(0.060), other])
    tr.update(1.15, [hand(0.060), other])  # 0.45 s
    assert not st.held
    tr.update(1.2, [hand(0.060), other])  # 0.5 s within the tolerance: held
    assert st.held
    assert tr.all_held
    tr.update(1.3, [hand(0.030), other])  # moved away: no longer on target, but held stays
    assert st.held
    assert not st.on_target
    assert st.progress == pytest.approx(0.25)


def test_a_release_resets_the_origin_to_where_the_next_grasp_takes_hold():
    tr = tracker()
    st = tr.states[0]
    other = hand(0.0, grasped=False)
    tr.update(0.0, [hand(0.02), other])
    tr.update(0.1, [hand(0.05), other])
    assert st.progress == pytest.approx(0.75)
    tr.update(0.2, [hand(0.05, grasped=False), other])  # released: shown from the scene's grasp point again
    assert st.point == pytest.approx((0.05, 0.0, 0.0))
    assert st.progress == 0.0
    assert math.isnan(st.error)
    assert not st.on_target
    tr.update(0.3, [hand(0.03, 0.01), other])  # grasped again at (30, 10, 0) mm
    assert st.point == pytest.approx((0.07, 0.01, 0.0))
    assert st.progress == 0.0
    tr.update(0.4, [hand(0.04, 0.01), other])
    assert st.progress == pytest.approx(0.25)


def test_over_limit_is_the_force_now_above_the_safe_force_grasped_or_not():
    tr = tracker()
    st = tr.states[0]
    other = hand(0.0, grasped=False)
    tr.update(0.0, [hand(0.02, force=(0.2, 0.2, 0.0)), other])  # |f| = 0.283 N <= 0.29
    assert not st.over_limit
    tr.update(0.1, [hand(0.02, force=(0.2, 0.2, 0.05)), other])  # 0.287 N
    assert not st.over_limit
    tr.update(0.2, [hand(0.02, force=(0.2, 0.2, 0.1)), other])  # 0.3 N
    assert st.over_limit
    tr.update(0.3, [hand(0.02, grasped=False, force=(0.0, 0.3, 0.0)), other])
    assert st.over_limit
    tr.update(0.4, [hand(0.02, force=(0.0, 0.1, 0.0)), other])
    assert not st.over_limit


def test_no_target_no_tracking():
    tr = TargetTracker([None, None], [(0.0, 0.0, 0.0)] * 2)
    assert not tr.any
    assert not tr.all_held
    assert tr.states == [None, None]
