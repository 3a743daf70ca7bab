"""The benchmarks' machine-readable output: with --json, nothing but one JSON object of stable
keys on stdout (the measuring itself is not run here: it is slow and these machines are noisy)."""

import json

import numpy as np

from bench.common import main_with_json, percentile_keys, report


def _measure():
    print("a human-readable line that --json must swallow")
    return report("thing", np.array([0.001, 0.002, 0.003]), "ms", target=2.5)


def test_json_mode_prints_only_the_flat_keys(monkeypatch, capsys):
    monkeypatch.setattr("sys.argv", ["bench", "--json"])
    main_with_json(_measure, lambda row: percentile_keys("x.frame_ms", row, 2.5))
    keys = json.loads(capsys.readouterr().out)
    assert set(keys) == {"x.frame_ms_p50", "x.frame_ms_p95", "x.frame_ms_p99", "x.frame_ms_max", "x.frame_ms.target", "x.frame_ms_p99.ratio_to_target"}
    assert keys["x.frame_ms_p50"] == 2.0 and keys["x.frame_ms_max"] == 3.0
    assert abs(keys["x.frame_ms_p99.ratio_to_target"] - float(np.percentile([1, 2, 3], 99)) / 2.5) < 1e-12


def test_text_mode_prints_the_lines(monkeypatch, capsys):
    monkeypatch.setattr("sys.argv", ["bench"])
    main_with_json(_measure, lambda row: {"never": 1})
    out = capsys.readouterr().out
    assert "human-readable" in out and "never" not in out



def test_scene_budgets_time_the_scene_configuration_against_the_contract(capsys):
    """`python -m bench fem|mass_spring` report the shipped scene's configuration beside the
    model contract's budgets (here the cheap plate-spring, few calls: the keys, not the speed)."""
    from bench.common import scene_budgets
    from sim.models.api import BUDGETS

    out = scene_budgets("plate_spring", frames=6, force_calls=200)
    assert out["frame_ms.target"] == BUDGETS["deformation_ms_p99"] and out["force_us.target"] == BUDGETS["force_us_p99"]
    assert 0 < out["frame_ms_p50"] <= out["frame_ms_p99"] <= out["frame_ms_max"]
    assert out["frame_ms_p99.ratio_to_target"] == out["frame_ms_p99"] / BUDGETS["deformation_ms_p99"]
    assert out["options"]["variant"] == "continuous"  # the scene's own configuration
    assert "plate_spring (scene configuration) frame" in capsys.readouterr().out
