"""`studyctl model ...`: nonsense input is refused with one line naming the option and the
allowed range (no traceback, non-zero exit); a solve that did not converge fails; sensible
input still works."""

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from sim.models.api import MAX_PULL_M
from studyctl.cli import cli

BRAIN_PARAMS = Path(__file__).resolve().parents[1] / "protocols" / "models" / "plate_spring_handset.toml"  # as tests/conftest.py

LEFT = "-0.0313,-0.0186,0.0723"  # the scene's left hand start, on the surface
FEM = ["model", "fem", "--resolution", "8"]  # the coarsest mesh the command allows
MASS_SPRING = ["model", "mass-spring", "--resolution", "8", "--steps", "3", "--integrator", "implicit", "--dt", "0.02"]
PLATE_SPRING = ["model", "plate-spring", "--params", str(BRAIN_PARAMS)]


def _refused(args, needles, exit_code=2):
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == exit_code, res.output
    assert "Traceback" not in res.output, res.output
    errors = [line for line in res.output.splitlines() if line.startswith("Error")]
    assert len(errors) == 1, res.output
    for needle in needles:
        assert needle in errors[0], res.output
    return errors[0]


@pytest.mark.parametrize("args, needles", [
    # FEM: NaN forces with "converged": true, a 10 m pull of 103 N, a grasp 8.6 m off the brain
    ([*FEM, "--grasp", LEFT, "--displacement=nan,0,0"], ["'--displacement'", "DX is not a finite number"]),
    ([*FEM, "--grasp", LEFT, "--displacement=0,inf,-inf"], ["'--displacement'", "DY, DZ are not finite numbers"]),
    ([*FEM, "--grasp", LEFT, "--displacement", "10,0,0"], ["'--displacement'", "is 10 m long; allowed: at most 0.05 m (50 mm"]),
    ([*FEM, "--grasp=5,5,5", "--displacement=-0.005,0,0"],
     ["'--grasp'", "5,5,5 is 8595 mm from the brain surface; allowed: within 10 mm of it (the simulator's grasp reach)"]),
    ([*FEM, "--grasp=0,nan,0", "--displacement=-0.005,0,0"], ["'--grasp'", "Y is not a finite number"]),
    # mass-spring: --dt was unbounded once; the same vector checks as the FEM
    (["model", "mass-spring", "--integrator", "implicit", "--dt", "1e9"], ["'--dt'", "0.0<x<=0.1"]),
    (["model", "mass-spring", "--integrator", "implicit", "--dt", "nan"], ["'--dt'", "'nan' is not a finite number"]),
    ([*MASS_SPRING, "--displacement", "1,0,0"], ["'--displacement'", "is 1 m long; allowed: at most 0.05 m"]),
    ([*MASS_SPRING, "--displacement", "0,0,nan"], ["'--displacement'", "DZ is not a finite number"]),
    ([*MASS_SPRING, "--grasp", "0.2,0,0"], ["'--grasp'", "mm from the brain surface; allowed: within 10 mm"]),
    # plate-spring: a 1e308 m stretch gave 1.6e308 N
    ([*PLATE_SPRING, "--displacement", "1e308"], ["'--displacement'", "0.0<=x<=0.05"]),
    ([*PLATE_SPRING, "--displacement", "nan"], ["'--displacement'", "'nan' is not a finite number"]),
    ([*PLATE_SPRING, "--displacement", "-0.001"], ["'--displacement'", "0.0<=x<=0.05"]),
    ([*PLATE_SPRING, "--force", "inf"], ["'--force'", "'inf' is not a finite number"]),
])
def test_nonsense_is_one_clean_line_naming_the_option(args, needles):
    _refused(args, needles)


def test_a_pull_just_within_the_bound_is_accepted_and_just_beyond_refused():
    assert CliRunner().invoke(cli, [*PLATE_SPRING, "--displacement", str(MAX_PULL_M), "--json"]).exit_code == 0
    _refused([*PLATE_SPRING, "--displacement", str(MAX_PULL_M * 1.001)], ["'--displacement'"])
    # the length counts, not the components: 30 and 40.1 mm make a 50.08 mm pull
    _refused([*FEM, "--grasp", LEFT, "--displacement", "0.03,0.0401,0"], ["'--displacement'", "is 0.05008 m long"])


def test_a_corotational_solve_that_does_not_converge_fails():
    """One line on stderr, exit 1, and the --json report still printed, saying so (one solve: it
    iterates to its limit, about a minute)."""
    args = [*FEM, "--grasp", LEFT, "--displacement=-0.05,0,0", "--formulation", "corotational", "--steps", "1", "--json"]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("Error")]
    assert errors == ["Error: the corotational solve stopped after 0 of 1 load steps (elements inverted): the force is not the "
                      "requested pull's; try more --steps or a shorter --displacement"]
    assert json.loads(res.stdout)["converged"] is False


def test_a_finite_strain_solve_that_does_not_converge_fails():
    # a 5 cm push into the brain inverts elements on the way (P1, the quick build): the solve stops where it got to
    line = _refused([*FEM, "--order", "1", "--grasp", LEFT, "--displacement=0,0,-0.05", "--formulation", "finite-strain", "--steps", "1"],
                    ["finite-strain solve stopped at", "% of the pull after"], exit_code=1)
    assert line.endswith("the force is not the requested pull's; try more --steps or a shorter --displacement")


def test_reasonable_input_still_works():
    res = CliRunner().invoke(cli, [*FEM, "--grasp", LEFT, "--displacement=-0.012,0,0", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert out["converged"]
    assert 0.0 < out["force_magnitude_n"] < 1.0
    res = CliRunner().invoke(cli, [*FEM, "--grasp", LEFT, "--displacement=-0.005,0,0", "--formulation", "corotational", "--steps", "2"])
    assert res.exit_code == 0, res.output
    assert "converged: yes" in res.output, res.output
    res = CliRunner().invoke(cli, [*MASS_SPRING, "--grasp", LEFT, "--displacement", "-0.012,0,0", "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["stable"]
    res = CliRunner().invoke(cli, [*PLATE_SPRING, "--displacement", "0.012", "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["force"] > 0


def test_the_library_pull_refuses_a_grasp_out_of_reach_as_the_command_does():
    """The grasp reach is the library's rule (`sim.geometry.patch.grasp_problem`): `static_pull`
    called directly refuses a grasp 8.6 m off the brain with the command's words, before meshing."""
    from sim.errors import ParameterError
    from sim.models.fem import static_pull
    from sim.scene import DEFAULT_SCENE, build_scene

    with pytest.raises(ParameterError, match=r"^grasp: 5,5,5 is 8595 mm from the brain surface; allowed: within 10 mm of it "
                                             r"\(the simulator's grasp reach\)$"):
        static_pull(build_scene(DEFAULT_SCENE), (5.0, 5.0, 5.0), (-0.005, 0.0, 0.0), 0.008)
