"""Stability sweep: the quick sweep never sends a NaN or an over-limit force, cases end the
way their physics says, and a Dask cluster gives the same answers as local processes."""

import json
import math
import re

import numpy as np
import pytest
from click.testing import CliRunner

from analysis.reports.stability_report import markdown
from analysis.verification.stability import (
    CHATTER_REVERSALS,
    Case,
    _scene_for,
    make_cases,
    peak_reversals,
    run_case,
)
from sim.devices.simulated import PullScript, SimulatedOmni
from sim.models.api import Contact, TissueModel
from sim.run import run_scene
from sim.servo.loop import Hand, ServoLoop
from studyctl.cli import cli


@pytest.fixture(scope="module")
def quick_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("stab")
    res = CliRunner().invoke(cli, ["bench", "stability", "--quick", "--json", "--out", str(out)])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout), out


def test_quick_sweep_sends_no_nan_and_no_over_limit_force(quick_sweep):
    out, d = quick_sweep
    cases = out["cases"]
    assert len(cases) == len(make_cases(quick=True)) > 50
    for c in cases:
        assert {"model", "case", "outcome", "reason", "nan_sent", "over_limit_sent"} <= set(c)
        assert c["outcome"] in ("stable", "refused", "unstable")
        assert not c["nan_sent"], c
        assert not c["over_limit_sent"], c
        assert c["max_force_n"] <= 3.3 + 1e-9
        if c["outcome"] != "stable":
            assert c["reason"]
    assert sorted(p.name for p in d.iterdir()) == ["heatmap.png", "heatmap.svg", "stability.csv", "stability.json", "stability.md"]


def test_outcomes_follow_the_physics(quick_sweep):
    by = {(c["model"], c["case"]): c for c in quick_sweep[0]["cases"]}
    # out-of-bounds plate-spring parameters are refused with the bound named
    assert by[("plate_spring/continuous", "alpha=2.5")]["outcome"] == "refused"
    assert "allowed: [1, 2]" in by[("plate_spring/continuous", "alpha=2.5")]["reason"]
    # a coupling stiffer than the Omni renders is refused
    assert by[("mass_spring/implicit", "k=1e+06N/m")]["outcome"] == "refused"
    assert "700" in by[("mass_spring/implicit", "k=1e+06N/m")]["reason"]
    # E = 1 GPa: explicit integration would need tens of thousands of sub-steps: refused
    assert by[("mass_spring/explicit", "E=1e+09Pa")]["outcome"] == "refused"
    assert "sub-steps" in by[("mass_spring/explicit", "E=1e+09Pa")]["reason"]
    # a rigid FEM contact (1 GPa) is held at the device's limit: clamped, never beyond, and its
    # force reverses as the hand leaves the grasp point. Whether it reaches the chatter limit is
    # marginal (a peak of 6 or 9 reversals of 10 in 50 ms, by BLAS threads and kernels: issue 25),
    # so what is asserted is what holds on every machine; test_rigid_fem_contact_is_flagged_
    # exactly_when_its_trace_chatters checks the flag against the trace
    for model in ("fem/linear", "fem/corotational"):
        rigid = by[(model, "E=1e+09Pa")]
        assert rigid["events"].get("force_clamped", 0) > 0
        assert rigid["max_force_n"] == pytest.approx(3.3)
        assert rigid["peak_reversals"] > 0
        chattered = rigid["events"].get("force_chatter", 0) == 1
        assert rigid["outcome"] == ("unstable" if chattered else "stable")
        assert ("chatter" in rigid["reason"] and 0 < rigid["detected_at_s"] < 0.4) if chattered else rigid["reason"] == ""
    # a soft tissue is nowhere near the chatter limit
    assert by[("fem/linear", "E=1Pa")]["peak_reversals"] == 0
    # a 200 mm pull inverts corotational elements; the step's line search carries the model
    # through them (it used to give up and render nothing), with a force of the linear FEM's order
    corot = by[("fem/corotational", "pull=200mm")]
    assert corot["outcome"] == "stable"
    assert "model_unstable" not in corot["events"]
    assert 0.8 * by[("fem/linear", "pull=200mm")]["max_force_n"] < corot["max_force_n"] < 3.3
    # a one-tick 5 cm glitch drops the grasp (logged)
    assert by[("fem/linear", "glitch=5cm")]["events"].get("position_jump") == 1
    # a 200 mm pull in 250 ms: the mass-spring's force is of the linear FEM's size (1.3 N), not the
    # 3.3 N limit its stale 30 Hz patch used to reach between frames (the hand moves 26 mm per frame)
    far = by[("mass_spring/implicit", "pull=200mm")]["max_force_n"]
    assert 0.5 * by[("fem/linear", "pull=200mm")]["max_force_n"] < far < 3.3
    # the implicit integrators survive the stiffest springs and the longest steps
    for model in ("mass_spring/implicit", "mass_spring/local-global"):
        assert by[(model, "E=1e+09Pa")]["outcome"] == "stable"
        assert by[(model, "dt=50ms")]["outcome"] == "stable"


def test_a_model_that_throws_is_unstable_not_a_crash(monkeypatch):
    from sim.models import plate_spring

    def boom(self, contacts, displacements):
        raise FloatingPointError("overflow in the stack")

    monkeypatch.setattr(plate_spring.PlateSpringModel, "deformation", boom)
    out = run_case(Case("plate_spring/continuous", "E=3000Pa", "young", 3000.0))
    assert out["outcome"] == "unstable"
    assert "overflow in the stack" in out["reason"]
    assert not out["nan_sent"]
    assert not out["over_limit_sent"]


def test_dask_cluster_gives_the_local_answers():
    from distributed import LocalCluster

    import analysis.verification.stability as st

    # the FEM's rigid rows too: CHOLMOD's bits depend on the BLAS thread count, which Dask's
    # nanny sets to one; every process that factorises runs one thread (sim.linalg.one_thread_pools)
    cases = [c for c in make_cases(quick=True) if c.model == "plate_spring/continuous"
             or (c.model.startswith("fem/") and c.case == "E=1e+09Pa")]
    here = st.run_stability(quick=True, jobs=1, cases=cases)["cases"]
    pool = st.run_stability(quick=True, jobs=2, cases=cases)["cases"]
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        remote = st.run_stability(quick=True, scheduler=cluster.scheduler_address, cases=cases)["cases"]
    strip = lambda r: {k: v for k, v in r.items() if k != "wall_s"}  # noqa: E731
    assert [strip(r) for r in remote] == [strip(r) for r in here] == [strip(r) for r in pool]


def test_unreachable_scheduler_is_a_one_line_error():
    res = CliRunner().invoke(cli, ["bench", "stability", "--quick", "--scheduler", "tcp://127.0.0.1:1"])
    assert res.exit_code == 1
    assert "scheduler tcp://127.0.0.1:1: cannot connect" in res.output
    assert "Traceback" not in res.output


def test_report_carries_the_heat_map(quick_sweep, small_study, tmp_path):
    _, d = quick_sweep
    db = small_study
    res = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--format", "html", "--stability", str(d / "stability.json"),
                                   "--out", str(tmp_path / "r.html")])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "r.html").read_text()
    assert "Numerical stability" in page
    assert 'alt="stability"' in page
    # non-stable rows with their reasons (cases decisive on every machine: 11 019 sub-steps
    # against at most 2000; a coupling stiffer than the Omni's 700 N/m)
    assert "sub-steps per 0.03333 s step" in page
    assert "<td>mass_spring/implicit</td><td>k=1e+06N/m</td><td>refused</td>" in page
    md = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--stability", str(d / "stability.json")]).output
    assert "## Numerical stability" in md
    assert "| mass_spring/implicit | k=1e+06N/m | refused |" in md


def _monitor_on_the_trace(times, forces, events, window=0.05, limit=10):
    """The chatter monitor's definition, worked on a recorded trace with a plain loop (not the
    servo's code, nor `peak_reversals`): a reversal is two consecutive sent forces pointing
    apart, both above 0.05 N; `limit` of them within `window` s, ends included, is chatter. At a
    logged `force_chatter` the trace holds the zero sent instead of the force that made the last
    reversal, which the event carries. Returns (the ticks where the definition is met, the peak
    count in a window)."""
    withheld = {}
    for e in events:
        if e.kind == "force_chatter":
            m = re.search(r"withheld force \((\S+), (\S+), (\S+)\) N", e.detail)
            withheld[e.t] = tuple(float(x) for x in m.groups())
    reversals, met, peak = [], [], 0
    for i in range(1, len(times)):
        a, b = forces[i - 1], withheld.get(times[i], forces[i])
        strong = sum(x * x for x in a) > 0.0025 and sum(x * x for x in b) > 0.0025
        if strong and sum(x * y for x, y in zip(a, b)) < 0.0:
            reversals.append(times[i])
            n = sum(1 for r in reversals if r >= times[i] - window)
            peak = max(peak, n)
            if n >= limit:
                met.append(times[i])
                reversals = []  # the monitor starts counting again after it fires
    return met, peak


def _check_flag_against_trace(times, forces, events):
    flagged = [e.t for e in events if e.kind == "force_chatter"]
    met, peak = _monitor_on_the_trace([float(t) for t in times], [tuple(map(float, f)) for f in forces], events)
    assert flagged == met  # flagged exactly where the trace meets the definition, nowhere else
    return met, peak


@pytest.mark.parametrize("model", ["fem/linear", "fem/corotational"])
def test_rigid_fem_contact_is_flagged_exactly_when_its_trace_chatters(model):
    # the marginal case of issue 25: whichever way it goes on this machine, the flag and the
    # trace agree, the reported margin is the trace's, and no force is NaN or over the limit
    scene = _scene_for(Case(model, "E=1e+09Pa", "young", 1e9), "protocols/scenes/brain_pull.toml")
    result = run_scene(scene, duration=0.4, time_scale=0.0)
    forces = result.forces.reshape(len(result.forces), -1, 3)[:, 0, :]
    assert np.all(np.isfinite(forces))
    assert np.linalg.norm(forces, axis=1).max() <= 3.3 * (1 + 1e-9)
    met, peak = _check_flag_against_trace(result.times, forces, result.events)
    assert peak > 0  # the rigid contact reverses the force as the hand leaves the grasp point
    assert peak_reversals(result.times, forces) == (peak if not met else peak - 1)  # the withheld one is not in the trace


class _RigidPoint(TissueModel):
    """A rigid point contact, f = -k d with k = 1e7 N/m in every direction: no BLAS, no mesh."""

    def force(self, contact, d):
        return (-1e7 * d[0], -1e7 * d[1], -1e7 * d[2])


# (pull direction, grasp point's offset from the hand's start, m): any real grasp point lies off
# the encoder's 0.055 mm lattice. With the monitor off, these peak at 18, 18, 14 and 19 reversals
# in 50 ms within the test's 0.4 s (the limit is 10); plain float arithmetic, the same on any machine.
RIGID_GEOMETRIES = [((1.0, 0.0, 0.0), (2e-5, 2e-5, -2e-5)), ((0.0, 1.0, 0.0), (2e-5, 2e-5, -2e-5)),
                    ((0.0, 0.0, 1.0), (2e-5, 2e-5, -2e-5)), ((1.0, 0.0, 0.0), (1e-5, -2e-5, 1.3e-5))]


def _rigid_run(direction, offset, suspend_at=None):
    dev = SimulatedOmni(PullScript(start=(0.0, 0.0, 0.0), pull=tuple(1e-3 * c for c in direction), grasp_at=0.0,
                                   pull_start=0.0, pull_time=0.05, release_at=10.0))
    hand = Hand(index=0, name="h", device=dev)
    servo = ServoLoop(model=_RigidPoint(), hands=[hand], peak_force=3.3, ramp_s=0.01)
    servo.tick(0.0)
    hand.contact = Contact(hand=0, vertex=0, point=offset, normal=(0.0, 0.0, 1.0))
    for i in range(1, 400):
        if suspend_at is not None and i / 1000 == suspend_at:
            servo.suspend(i / 1000, 0.003, "deadline_streak")
        servo.tick(i / 1000)
    return servo, hand


@pytest.mark.parametrize("direction, offset", RIGID_GEOMETRIES)
def test_a_rigid_contact_held_below_the_force_limit_chatters_and_is_flagged(direction, offset):
    # The hand pulls 1 mm away (0.3 N on its 300 N/m arm, far below the Omni's 3.3 N): the
    # rigid contact holds it at the grasp point, where the clamped force flips with every
    # encoder step, a limit cycle at the quantum that a 1 kHz loop cannot render. Decisive on
    # every machine: plain float arithmetic, and well above the limit at its peaks.
    servo, hand = _rigid_run(direction, offset)
    rows = servo.rows.array()
    times, forces = rows[:, 0], rows[:, 6:9]
    assert [e.kind for e in servo.events].count("force_chatter") == 1  # the servo saw it live
    met, _ = _check_flag_against_trace(times, forces, servo.events)
    at = int(np.flatnonzero(times == met[0])[0])
    assert hand.contact is None  # grasp dropped: nothing more is rendered
    assert np.all(forces[at:] == 0.0)
    assert np.linalg.norm(forces, axis=1).max() <= 3.3 * (1 + 1e-12)
    assert math.isfinite(forces.sum())


def test_markdown_lists_the_stable_cases_near_the_chatter_limit():
    def case(name, peak):
        return {"model": "fem/linear", "case": name, "outcome": "stable", "reason": "", "detected_at_s": None, "peak_reversals": peak}

    result = {"cases": [case("E=1e+09Pa", CHATTER_REVERSALS - 1), case("E=1Pa", 2)],
              "meta": {"quick": True, "resolution_m": 0.008, "duration_s": 0.4, "counts": {"stable": 2, "refused": 0, "unstable": 0},
                       "nan_sent": 0, "over_limit_sent": 0}}
    md = markdown(result)
    assert "Stable but near the chatter limit (10 force reversals within 50 ms): fem/linear E=1e+09Pa (9)." in md
    assert "E=1Pa" not in md


def test_the_chatter_window_includes_its_ends():
    # times exact in binary: reversals at 0.25, 0.5 and 0.75 s; the first and the last lie
    # exactly one 0.5 s window apart, which counts them together
    times, forces = [0.0, 0.25, 0.5, 0.75], [(1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0)]
    assert peak_reversals(times, forces, window=0.5) == 3
    assert peak_reversals(times, forces, window=0.25) == 2
    for window, fires in ((0.5, [False, False, False, True]), (0.375, [False] * 4)):
        servo = ServoLoop(model=None, hands=[], peak_force=3.3, chatter_reversals=3, chatter_window_s=window)
        hand = Hand(index=0, name="h", device=None)
        fired = []
        for t, f in zip(times, forces):
            fired.append(servo._chatter(hand, t, f))
            hand.force = f
        assert fired == fires


def test_the_monitor_counts_only_forces_that_are_sent():
    # Review finding: the monitor ran before the suspension rule, so a reversal completed on a
    # suspended tick (a zero was sent) dropped the grasp under the event `suspended`. Suspend
    # exactly at the tick where the unsuspended run fires: the grasp is dropped only with a
    # force_chatter event, where the trace meets the definition.
    direction, offset = RIGID_GEOMETRIES[0]
    first, _ = _rigid_run(direction, offset)
    fires_at = next(e.t for e in first.events if e.kind == "force_chatter")
    servo, hand = _rigid_run(direction, offset, suspend_at=fires_at)
    rows = servo.rows.array()
    kinds = [e.kind for e in servo.events]
    assert "suspended" in kinds, kinds
    assert hand.contact is None, kinds
    assert "force_chatter" in kinds, kinds
    _check_flag_against_trace(rows[:, 0], rows[:, 6:9], servo.events)
