"""Performance metrics (analysis/validity/metrics.py) against closed forms on constructed traces, then with
tremor and the Omni's encoder quantisation added; `studyctl metrics` on a synthetic study."""

import json
import math
import re
from io import StringIO
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

from analysis.validity import kinematics as kin
from analysis.validity.metrics import COLUMNS, METRICS, SAFE_FORCE_N, Goal, hand_metrics, trial_metrics
from tests.conftest import ROOT
from tests.helpers import fast_protocol, studyctl

FS = 1000.0
Q = 0.055e-3  # the Omni's tip quantisation, m
D, T = 0.05, 1.2  # reach distance m, duration s
U = np.array([1.0, 2.0, 2.0]) / 3.0  # a diagonal: every axis's encoder steps


def reach(tremor_m=0.0, quantised=False, rest_s=0.3):
    """A straight minimum-jerk reach (Flash and Hogan 1985) from rest to rest, grasped exactly
    while it moves, with a 10 Hz tremor across it and the encoders' rounding if asked."""
    t = np.arange(0, T + 2 * rest_s + 1e-9, 1 / FS)
    s = np.clip((t - rest_s) / T, 0, 1)
    x = (D * (10 * s**3 - 15 * s**4 + 6 * s**5))[:, None] * U + np.array([0.01, -0.02, 0.03])
    across = np.cross(U, [0.0, 0.0, 1.0])
    x = x + tremor_m * np.sin(2 * np.pi * 10 * t)[:, None] * across / np.linalg.norm(across)
    if quantised:
        x = np.round(x / Q) * Q
    held = (t >= rest_s - 1e-9) & (t <= rest_s + T + 1e-9)
    return t, x, held


def sparc_continuous(fc=10.0, amp_th=0.05):
    """SPARC of the minimum-jerk speed profile by another route: its continuous Fourier
    transform by quadrature (the speed is 30 s^2 (1 - s)^2 D/T on s in [0, 1], so the profile's
    spectrum is T-scaled: evaluate it for T = 1.2 s), the adaptive cut-off found on a fine grid."""
    def mag(f):
        w = 2 * np.pi * f * T
        re_ = quad(lambda s: 30 * s**2 * (1 - s) ** 2 * math.cos(w * s), 0, 1)[0]
        im_ = quad(lambda s: 30 * s**2 * (1 - s) ** 2 * math.sin(w * s), 0, 1)[0]
        return math.hypot(re_, im_)  # |V(0)| = 1: already normalised

    f = np.linspace(0, fc, 20001)
    m = np.array([mag(x) for x in f])
    last = np.flatnonzero(m >= amp_th)[-1]
    f, m = f[:last + 1], m[:last + 1]
    return -float(np.sum(np.hypot(np.diff(f) / f[-1], np.diff(m))))


def test_minimum_jerk_reach_equals_its_closed_forms():
    t, x, held = reach()
    m = hand_metrics(t, x, np.zeros_like(x), held)
    assert m["duration"] == pytest.approx(T, abs=1e-9)
    assert m["path_length"] == pytest.approx(D, rel=1e-4)
    assert m["path_ratio"] == pytest.approx(1.0, rel=1e-4)
    assert m["mean_speed"] == pytest.approx(D / T, rel=1e-4)
    assert m["peak_speed"] == pytest.approx(1.875 * D / T, rel=1e-4)
    # the published 4 levels of zero-padding resolve the spectrum to 0.03 Hz, which costs 0.006
    # here; 8 levels converge on the continuous transform's -1.4081 (to 0.0005)
    assert m["sparc"] == pytest.approx(sparc_continuous(), abs=0.02)
    assert kin.sparc(kin.speed(t[held], x[held]), FS, pad=8) == pytest.approx(sparc_continuous(), abs=0.002)


def test_a_pulls_ramp_and_hold_equal_the_minimum_jerk_closed_form():
    """Pulled D in T (minimum jerk) then held H before the release: the 10-90% rise of
    s(u) = 10u^3 - 15u^4 + 6u^5 found by root-finding here, the speed 0.8 D over it, the hold H plus
    the ramp's last tenth."""
    H = 0.9
    t = np.arange(0, 0.3 + T + H + 1e-9, 1 / FS)
    u = np.clip((t - 0.3) / T, 0, 1)
    x = (D * (10 * u**3 - 15 * u**4 + 6 * u**5))[:, None] * U
    held = t >= 0.3 - 1e-9
    m = hand_metrics(t, x, np.zeros_like(x), held)
    s = lambda v, level: 10 * v**3 - 15 * v**4 + 6 * v**5 - level  # noqa: E731
    u10, u90 = brentq(s, 0, 1, args=(0.1,)), brentq(s, 0, 1, args=(0.9,))
    assert m["pull_distance"] == pytest.approx(D, rel=1e-4)  # the 20 Hz low-pass rings by 5e-6
    assert m["ramp_time"] == pytest.approx((u90 - u10) * T, abs=2e-3)  # the ticks are 1 ms
    assert m["ramp_speed"] == pytest.approx(0.8 * D / ((u90 - u10) * T), rel=4e-3)
    assert m["ramp_speed"] == pytest.approx(1.579 * D / T, rel=4e-3)
    assert m["hold_time"] == pytest.approx((1 - u90) * T + H, abs=2e-3)


def test_sparc_does_not_depend_on_distance_or_duration_and_falls_with_a_second_submovement():
    t = np.arange(0, 1.0 + 1e-9, 1 / FS)
    s = t / t[-1]
    v = 30 * s**2 * (1 - s) ** 2
    assert kin.sparc(3.7 * v, FS) == pytest.approx(kin.sparc(v, FS), abs=1e-9)
    t2 = np.arange(0, 2.0 + 1e-9, 1 / FS)
    s2 = t2 / t2[-1]
    assert kin.sparc(30 * s2**2 * (1 - s2) ** 2, FS) == pytest.approx(kin.sparc(v, FS), abs=0.01)
    two = np.concatenate([v, v])  # stop and go again: less smooth
    assert kin.sparc(two, FS) < kin.sparc(v, FS) - 0.3


def test_a_force_held_above_the_limit_gives_its_time_and_impulse():
    t = np.arange(0, 2.0, 1 / FS)
    f = np.zeros((len(t), 3))
    above = (t >= 0.5 - 1e-9) & (t < 0.85 - 1e-9)  # 350 ticks: 0.35 s
    f[above] = np.array([0.6, 0.0, 0.8]) * 0.5  # |F| = 0.5 N
    f[~above] = [0.1, 0.0, 0.0]
    goal = Goal(target_m=0.01, safe_force_n=0.3)
    m = hand_metrics(t, np.zeros((len(t), 3)), f, np.ones(len(t), bool), goal)
    assert m["peak_force"] == pytest.approx(0.5)
    assert m["time_above_limit"] == pytest.approx(0.35, abs=1e-9)
    assert m["impulse_above_limit"] == pytest.approx(0.35 * 0.2, abs=1e-9)
    assert m["mean_force"] == pytest.approx((0.35 * 0.5 + 1.65 * 0.1) / 2.0, rel=1e-3)
    assert m["force_integral"] == pytest.approx(0.35 * 0.5 + 1.65 * 0.1, rel=2e-3)
    assert (m["force_p50"], m["force_p90"], m["force_p99"]) == pytest.approx((0.1, 0.5, 0.5))
    assert SAFE_FORCE_N == pytest.approx(0.294, abs=1e-3)  # 30 g (Yokoh et al. 1983)


def test_outcome_of_a_reach_to_its_target():
    t, x, held = reach()
    hold = 0.2
    held = held | ((t > 0.3 + T) & (t <= 0.3 + T + hold + 1e-9))  # grasp on at rest, at the target
    goal = Goal(target_m=tuple(D * U), tolerance_m=0.001, hold_s=hold)
    m = hand_metrics(t, x, np.zeros_like(x), held, goal)
    # the reach enters 1 mm of its end where 10s^3-15s^4+6s^5 = 1 - 0.001/D
    s_in = brentq(lambda s: 10 * s**3 - 15 * s**4 + 6 * s**5 - (1 - 0.001 / D), 0.5, 1)
    assert m["target_reached"] == 1.0
    assert m["final_error"] == pytest.approx(0, abs=1e-6)
    assert m["overshoot"] == pytest.approx(0, abs=1e-6)
    assert m["time_to_target"] == pytest.approx(s_in * T, abs=2e-3)
    far = hand_metrics(t, x, np.zeros_like(x), held, Goal(target_m=0.8 * D, tolerance_m=0.001, hold_s=hold))
    assert far["target_reached"] == 0.0
    assert math.isnan(far["time_to_target"])
    assert far["overshoot"] == pytest.approx(0.2 * D, rel=1e-4)
    assert far["final_error"] == pytest.approx(0.2 * D, rel=1e-4)


# Tolerances with 0.2 mm of 10 Hz tremor and 0.055 mm quantisation, each several times what
# was measured (in brackets): the tremor lengthens the real path by 4.7%, quantisation after the
# 20 Hz low-pass adds under 0.1% to it; unfiltered, the staircase would add about 20%.
def test_tremor_and_quantisation_stay_within_the_stated_tolerances():
    t, x, held = reach(tremor_m=0.2e-3, quantised=True)
    noisy = hand_metrics(t, x, np.zeros_like(x), held)
    t, xt, _ = reach(tremor_m=0.2e-3)
    tremor = hand_metrics(t, xt, np.zeros_like(x), held)
    assert noisy["duration"] == pytest.approx(T, abs=1e-9)
    assert noisy["path_length"] == pytest.approx(D, rel=0.10)  # [4.7%]
    assert noisy["path_length"] == pytest.approx(tremor["path_length"], rel=0.01)  # quantisation only [<0.1%]
    assert noisy["mean_speed"] == pytest.approx(D / T, rel=0.10)  # [4.7%]
    assert noisy["peak_speed"] == pytest.approx(1.875 * D / T, rel=0.05)  # [about 1%]
    assert noisy["sparc"] == pytest.approx(sparc_continuous(), abs=0.05)  # [about 0.01]


def test_trial_metrics_rows_and_bimanual():
    t, x, held = reach()
    n = len(t)
    f = np.zeros((n, 2, 3))
    f[:, 0, 0], f[:, 1, 0] = 0.2, 0.1
    held2 = np.zeros(n, bool)
    held2[: n // 2] = True
    trace = SimpleNamespace(hand_names=["left", "right"], times=t, positions=np.stack([x, x], axis=1), forces=f,
                            buttons=np.stack([held, held2], axis=1))
    rows = pd.DataFrame(trial_metrics(trace))
    both = rows[rows["hand"] == "both"].set_index("metric")["value"]
    assert both["force_ratio"] == pytest.approx(0.5)
    overlap = np.sum(held & held2) / np.sum(held | held2)
    assert both["movement_overlap"] == pytest.approx(overlap, rel=1e-9)
    assert not ({"target_reached", "time_above_limit"} & set(rows["metric"]))  # no goal: no outcome, no limit
    assert "peak_force" in set(rows["metric"])
    with_goal = pd.DataFrame(trial_metrics(trace, {"left": Goal(target_m=D)}))
    assert set(with_goal.loc[with_goal["metric"] == "target_reached", "hand"]) == {"left"}


def test_docs_list_every_metric_with_its_unit():
    doc = (ROOT / "docs/metrics.md").read_text()
    for m in METRICS:
        assert re.search(rf"\| `{m.name}` \| {re.escape(m.unit)} \|", doc), m.name


def test_cli_metrics_on_a_synthetic_study(tmp_path):
    db = tmp_path / "s.db"
    res = studyctl("synth", "--db", db, "--participants", "2", "--seed", "1",
                   "--protocol", fast_protocol(tmp_path, conditions=("plate_spring", "mass_spring"), trials=2))
    assert res.exit_code == 0, res.output
    res = studyctl("metrics", "--db", db, "--format", "csv")
    assert res.exit_code == 0, res.output
    csv = res.stdout if hasattr(res, "stdout") else res.output
    table = pd.read_csv(StringIO(csv))
    assert list(table.columns) == COLUMNS
    assert table["synthetic"].all()
    assert table["code"].nunique() == 2
    assert set(table["condition"]) == {"plate_spring", "mass_spring"}
    assert set(table["trial"]) == {0, 1}
    assert set(table["hand"]) == {"left", "right", "both"}
    per_trial = table.groupby(["code", "condition", "trial", "hand"]).size()
    assert len(per_trial) == 2 * 2 * 2 * 3
    assert not table.duplicated(["code", "condition", "trial", "hand", "metric"]).any()
    assert "SYNTHETIC" in res.output
    res = studyctl("metrics", "--db", db, "--format", "json")
    out = json.loads(res.output)
    assert out["synthetic"] is True
    assert "SYNTHETIC" in out["note"]
    assert len(out["rows"]) == len(table)
    assert {m["name"] for m in out["metrics"]} == {m.name for m in METRICS}
    # --speeds: the pulls' percentiles, against the rows' own numbers (numpy's percentiles of them here)
    res = studyctl("metrics", "--db", db, "--speeds")
    assert res.exit_code == 0, res.output
    speeds = json.loads(res.output)
    pulls = table[(table["hand"] != "both") & table["metric"].isin(["ramp_speed", "pull_distance"])].pivot_table(
        index=["code", "condition", "trial", "hand"], columns="metric", values="value")
    pulls = pulls[pulls["pull_distance"] >= 1e-3]
    assert speeds["pulls"] == len(pulls) > 0 and speeds["participants"] == 2 and speeds["synthetic"] is True
    assert speeds["speeds"]["typical"]["speed_m_s"] == pytest.approx(np.median(pulls["ramp_speed"]), rel=1e-12)
    assert speeds["percentiles"]["ramp_speed"]["p90"] == pytest.approx(np.percentile(pulls["ramp_speed"], 90), rel=1e-12)
    assert "SYNTHETIC" in speeds["note"]
    wrong = studyctl("metrics", "--db", db, "--speeds", "--format", "csv")
    assert wrong.exit_code == 2 and "--speeds writes JSON" in wrong.output
    missing = studyctl("metrics", "--db", tmp_path / "nope.db")
    assert missing.exit_code == 1
    assert len(missing.output.strip().splitlines()) == 1
    assert "no such study database" in missing.output
