"""`studyctl model plate-spring`: outputs, JSON keys, and one-line errors for bad input."""

import json
import subprocess
import sys

import pytest
from click.testing import CliRunner

from studyctl.cli import cli
from tests.conftest import BRAIN_PARAMS, write_params


def run(*args):
    return CliRunner().invoke(cli, ["model", "plate-spring", *args])


def test_force_json():
    res = run("--params", str(BRAIN_PARAMS), "--force", "0.5", "--json")
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert {"dcl", "deformation", "layer_deformation", "overstretched", "saturated"} <= set(out)
    assert out["dcl"] == 3
    assert len(out["layer_deformation"]) == 6
    assert out["layer_deformation"][:2] == pytest.approx([0.002, 0.006])  # n_i * x_c1
    assert sum(out["layer_deformation"]) == pytest.approx(out["deformation"])
    assert out["overstretched"] is False
    assert out["saturated"] is False


def test_displacement_json_inverts_force():
    x = json.loads(run("--params", str(BRAIN_PARAMS), "--force", "0.5", "--json").output)["deformation"]
    out = json.loads(run("--params", str(BRAIN_PARAMS), "--displacement", str(x), "--json").output)
    assert out["force"] == pytest.approx(0.5, rel=1e-12)


def test_saturated_force():
    out = json.loads(run("--params", str(BRAIN_PARAMS), "--force", "50", "--json").output)
    assert out["dcl"] == 6
    assert out["overstretched"]
    assert out["saturated"]


def test_layer_table_and_paper_jumps():
    res = run("--params", str(BRAIN_PARAMS))
    assert res.exit_code == 0
    assert "Plate-spring layers (continuous)" in res.output
    assert "no jumps" in res.output
    res = run("--params", str(BRAIN_PARAMS), "--variant", "paper", "--json")
    table = json.loads(res.output)
    assert len(table["layers"]) == 6
    assert table["delay_budget"]["layers_in_budget"] == 6
    assert [j["layer"] for j in table["jumps"]] == [2, 3, 4, 5]
    assert all(j["kind"] == "forward" for j in table["jumps"])
    assert "jumps forward" in run("--params", str(BRAIN_PARAMS), "--variant", "paper").output


@pytest.mark.parametrize(
    "overrides, args, expected",
    [
        ({"alpha": 2.5}, [], "alpha: 2.5 is out of range; allowed: [1, 2]"),
        ({"q": 0.9}, [], "q: 0.9 is out of range; allowed: [1, 1.5]"),
        ({"layers": 0}, [], "layers: 0 is out of range; allowed: an integer in 1..1000"),
        ({"l1": 0.003}, [], "B: 0.01 m is out of range; Eq. (1) needs 2*L_i > 0.6*B"),
        ({"q": 1.5, "layers": 60}, [], "layers: 60 is out of range for these parameters; allowed: 1.."),
        ({}, ["--force", "-1"], "force: -1 is out of range; allowed: >= 0 N"),
        ({"x_c1": None}, [], "missing key 'x_c1'"),
        ({"E": "soft"}, [], "E: 'soft' is not a number"),
        ({"layers": 2.5}, [], "layers: 2.5 is not an integer"),
        ({"stiffness": 3.0}, [], "unknown key 'stiffness'"),
    ],
)
def test_bad_input_is_one_line_naming_the_field(tmp_path, overrides, args, expected):
    path = write_params(tmp_path / "p.toml", **overrides)
    res = run("--params", str(path), *args)
    assert res.exit_code == 1
    lines = res.output.strip().splitlines()
    assert len(lines) == 1, res.output
    assert lines[0].startswith("Error: "), res.output
    assert expected in lines[0], res.output
    if "force" not in expected:
        assert str(path) in lines[0]  # the file is named


def test_usage_errors(tmp_path):
    res = run("--params", str(BRAIN_PARAMS), "--force", "1", "--displacement", "0.01")
    assert res.exit_code == 2
    assert "not both" in res.output
    res = run("--params", str(tmp_path / "none.toml"))
    assert res.exit_code == 1
    assert "none.toml: not found" in res.output
    (tmp_path / "broken.toml").write_text("alpha = = 1\n")
    res = run("--params", str(tmp_path / "broken.toml"))
    assert res.exit_code == 1
    assert "invalid TOML" in res.output
    assert "line 1" in res.output


def test_console_script_prints_no_traceback(tmp_path):
    path = write_params(tmp_path / "p.toml", alpha=2.5)
    proc = subprocess.run(
        [sys.executable, "-m", "studyctl.cli", "model", "plate-spring", "--params", str(path)],
        capture_output=True, text=True,
    )
    assert proc.returncode == 1
    assert proc.stdout == ""
    assert proc.stderr.strip() == f"Error: {path}: alpha: 2.5 is out of range; allowed: [1, 2]"
