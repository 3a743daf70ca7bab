"""Stability sweep: the quick sweep never sends a NaN or an over-limit force, cases end the
way their physics says, and a Dask cluster gives the same answers as local processes."""

import json

import pytest
from click.testing import CliRunner

from analysis.stability import Case, make_cases, run_case
from studyctl.cli import cli


@pytest.fixture(scope="module")
def quick_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("stab")
    res = CliRunner().invoke(cli, ["bench", "stability", "--quick", "--json", "--out", str(out)])
    assert res.exit_code == 0, res.output
    return json.loads(res.output), out


def test_quick_sweep_sends_no_nan_and_no_over_limit_force(quick_sweep):
    out, d = quick_sweep
    cases = out["cases"]
    assert len(cases) == len(make_cases(quick=True)) > 50
    for c in cases:
        assert {"model", "case", "outcome", "reason", "nan_sent", "over_limit_sent"} <= set(c)
        assert c["outcome"] in ("stable", "refused", "unstable")
        assert not c["nan_sent"] and not c["over_limit_sent"], c
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
    # a rigid FEM contact rendered directly chatters at the force limit: flagged with a time
    rigid = by[("fem/corotational", "E=1e+09Pa")]
    assert rigid["outcome"] == "unstable" and "chatter" in rigid["reason"] and 0 < rigid["detected_at_s"] < 0.4
    assert rigid["events"].get("force_chatter") == 1  # the servo saw it live and dropped the grasp
    # the linear one (since the area-mean grasp, a different 3 x 3 stiffness) is held at the
    # device's limit by the simulated hand without a limit cycle: clamped, never beyond
    lin = by[("fem/linear", "E=1e+09Pa")]
    assert lin["events"].get("force_clamped", 0) > 0 and lin["max_force_n"] == pytest.approx(3.3)
    # a 200 mm pull inverts corotational elements: the model gives up and the servo renders nothing
    assert by[("fem/corotational", "pull=200mm")]["events"].get("model_unstable") == 1
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
    assert out["outcome"] == "unstable" and "overflow in the stack" in out["reason"]
    assert not out["nan_sent"] and not out["over_limit_sent"]


def test_dask_cluster_gives_the_local_answers():
    from distributed import LocalCluster

    cases = [c for c in make_cases(quick=True) if c.model == "plate_spring/continuous"]
    local = [run_case(c) for c in cases]
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        import analysis.stability as st

        remote = st.run_stability(quick=True, scheduler=cluster.scheduler_address, cases=cases)["cases"]
    strip = lambda r: {k: v for k, v in r.items() if k != "wall_s"}  # noqa: E731
    assert [strip(r) for r in remote] == [strip(r) for r in local]


def test_unreachable_scheduler_is_a_one_line_error():
    res = CliRunner().invoke(cli, ["bench", "stability", "--quick", "--scheduler", "tcp://127.0.0.1:1"])
    assert res.exit_code == 1 and "scheduler tcp://127.0.0.1:1: cannot connect" in res.output
    assert "Traceback" not in res.output


def test_report_carries_the_heat_map(quick_sweep, small_study, tmp_path):
    _, d = quick_sweep
    db = small_study
    res = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--format", "html", "--stability", str(d / "stability.json"),
                                   "--out", str(tmp_path / "r.html")])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "r.html").read_text()
    assert "Numerical stability" in page and 'alt="stability"' in page and "force_chatter" in page
    md = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--stability", str(d / "stability.json")]).output
    assert "## Numerical stability" in md and "| mass_spring/implicit | k=1e+06N/m | refused |" in md
