"""Calibration of the plate-spring model: a known curve is recovered, the FEM is matched."""

import json

import numpy as np
from click.testing import CliRunner

from sim.calibrate import fit
from sim.models.plate_spring import PlateSpring, load_params
from studyctl.cli import cli
from tests.conftest import BRAIN_PARAMS


def test_fit_recovers_a_curve_the_model_can_make():
    base = load_params(BRAIN_PARAMS)
    target = PlateSpring(base)
    xs = np.linspace(0.001, 0.03, 25)
    forces = np.array([target.force(x) for x in xs])
    start = type(base)(**(base.as_dict() | {"h1": 0.003, "alpha": 1.6, "q": 1.2, "x_c1": 0.004}))
    fitted, rep = fit(start, xs, forces)
    assert rep["within_jnd"] == 1.0
    assert rep["max_jnd_units"] < 0.2
    for k in ("alpha", "q"):
        assert 1.0 <= getattr(fitted, k) <= (2.0 if k == "alpha" else 1.5)  # within the paper's bounds


def test_cli_calibrates_to_the_converged_reference_and_to_a_csv(tmp_path, monkeypatch):
    # the converged reference on the bench's six calibration pulls; here on the two coarser
    # shipped meshes (the shipped fit used all three: the 4 mm P2 solves take a minute)
    monkeypatch.setattr("analysis.verification.accuracy.DEFAULT_SIZES_MM", (8.0, 6.0))  # where the calibration curve reads them
    res = CliRunner().invoke(cli, ["calibrate", "plate-spring", "--max-displacement", "0.004", "--samples", "8", "--json",
                                   "--out", str(tmp_path / "cal.toml")])
    assert res.exit_code == 0, res.output
    rep = json.loads(res.stdout)
    # only the samples where the truth is decided are fitted (0.5-4 mm: most of the 48), and the text says how many
    import re

    found = re.search(r"at the (\d+) of 48 samples where the truth is decided", rep["reference"])
    assert found
    assert rep["points"] == int(found.group(1))
    assert 20 <= rep["points"] < 48
    assert "converged reference" in rep["reference"]
    assert "8, 6 mm" in rep["reference"]
    assert "extrapolated" in rep["reference"]
    assert rep["within_jnd"] >= 0.2  # one force curve for six pulls of different stiffness: not all within
    fitted = load_params(tmp_path / "cal.toml")  # a valid parameter file
    assert fitted.alpha == rep["fitted"]["alpha"]
    # which says where its points end: the stack's force past them is the fit's extrapolation
    assert "# Past 4 mm no point is fitted" in (tmp_path / "cal.toml").read_text()
    (tmp_path / "curve.csv").write_text("displacement_m,force_n\n0.005,0.05\n0.01,0.11\n0.015,0.18\n0.02,0.26\n")
    rep = json.loads(CliRunner().invoke(cli, ["calibrate", "plate-spring", "--reference", str(tmp_path / "curve.csv"), "--json"]).stdout)
    assert rep["points"] == 4
    assert rep["within_jnd"] == 1.0
    (tmp_path / "bad.csv").write_text("displacement_m,force_n\n0.005,-1\n")
    res = CliRunner().invoke(cli, ["calibrate", "plate-spring", "--reference", str(tmp_path / "bad.csv")])
    assert res.exit_code == 1
    assert "line 2" in res.output
