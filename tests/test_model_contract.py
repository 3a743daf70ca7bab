"""The model contract where a model runs, through the CLI: a plugin cannot take a built-in's name
(or another plugin's), a broken plugin hides no model, names are spelt with - or _ alike, a
default outside its own bounds does not load, a wrong return value is a model_fault and never a
traceback, calls over their budget are said, and `model wheel` builds a model's wheel offline."""

from __future__ import annotations

import ast
import hashlib
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from sim.models.api import BUDGETS
from sim.run import run_scene
from sim.scene import build_scene
from tests.conftest import ROOT
from tests.helpers import BAD, fast_protocol, plugin_scene, studyctl

# two distributions: one registers built-ins' names (one of them broken), both register `twice`
SHADOWS = f"""[brainsim.models]
fem = {BAD}:NoSuchModel
plate-spring = {BAD}:Fem
twice = {BAD}:Spring
bad_default = {BAD}:BadDefault
"""
OTHER = f"""[brainsim.models]
twice = {BAD}:Spring
wrong_shape = {BAD}:WrongShape
slow_force = {BAD}:SlowForce
"""


def _dist(site: Path, name: str, version: str, entry_points: str) -> None:
    info = site / f"{name}-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    (info / "entry_points.txt").write_text(entry_points)


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    site = tmp_path_factory.mktemp("site")
    _dist(site, "shadows", "0.1", SHADOWS)
    _dist(site, "other", "2.0", OTHER)
    out = {k: v for k, v in os.environ.items() if k != "STUDYCTL_DB"}
    out["PYTHONPATH"] = f"{site}{os.pathsep}{ROOT}"
    return out


def _studyctl(env, *args, cwd=None):
    return subprocess.run([sys.executable, "-m", "studyctl", *map(str, args)], env=env, cwd=cwd, capture_output=True, text=True,
                          timeout=600)


def _digest(*paths: Path) -> dict:
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in paths}


def test_a_plugin_cannot_take_a_builtins_name_and_the_builtins_stay(env):
    res = _studyctl(env, "model", "list", "--json")
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    rows = {m["name"]: m for m in out["models"]}
    for name in ("fem", "plate_spring", "mass_spring"):
        assert rows[name]["builtin"], rows[name]
        assert rows[name]["source"].startswith("brainsim-study "), rows[name]
    problems = out["problems"]
    assert all("\n" not in p for p in problems)
    assert ("model 'fem' (from shadows 0.1): refused: 'fem' is a built-in model's name, and the built-in stays; "
            "register the plugin under another name") in problems
    assert ("model 'plate_spring' (from shadows 0.1): refused: 'plate_spring' is a built-in model's name, and the built-in stays; "
            "register the plugin under another name") in problems


def test_a_name_two_plugins_register_is_neither_s(env):
    out = json.loads(_studyctl(env, "model", "list", "--json").stdout)
    assert "twice" not in {m["name"] for m in out["models"]}
    # the registrations named in order, whatever order the entry points are found in
    assert "model 'twice': refused: registered by other 2.0 and shadows 0.1; neither loads until one is uninstalled or renamed" in out["problems"]


def test_model_list_text_shows_every_builtin_and_one_line_per_refusal(env):
    res = _studyctl(env, "model", "list")
    assert res.returncode == 0
    assert "Traceback" not in res.stdout + res.stderr
    assert "refused: 'fem' is a built-in model's name" in res.stdout
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("not loaded: ")]
    assert len(lines) == 4, lines  # fem, plate_spring, twice, bad_default
    describe = json.loads(_studyctl(env, "model", "describe", "fem", "--json").stdout)
    assert describe["builtin"]
    assert describe["class"] == "sim.models.builtin:FemBase"


def test_a_protocol_naming_fem_runs_the_builtin_fem(env, tmp_path):
    path = fast_protocol(tmp_path, conditions=("fem", "plate-spring"))
    code = f"""
import json
from studyctl.conditions import condition_scene_spec, resolved_config
from studyctl.protocol import load_protocol
p = load_protocol({str(path)!r})
print(json.dumps({{c: resolved_config(c, condition_scene_spec(p, c)) for c in p.conditions}}))
"""
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    configs = json.loads(res.stdout)
    assert set(configs) == {"fem", "plate_spring"}  # plate-spring is plate_spring
    assert "plugin" not in configs["fem"]
    assert "plugin" not in configs["plate_spring"]


def test_a_default_outside_its_own_bounds_does_not_load_and_says_so_in_one_line(env, tmp_path):
    line = ("model 'bad_default' (from shadows 0.1): option stiffness: its default 900.0 is outside its own declaration; "
            "allowed: [1, 700]")
    out = json.loads(_studyctl(env, "model", "list", "--json").stdout)
    assert line in out["problems"]
    for args in (("model", "describe", "bad_default"), ("model", "check", "bad_default", "--contract")):
        card = tmp_path / "card.md"
        card.write_text("kept")
        before = _digest(card)
        res = _studyctl(env, *args, "--out", card) if args[1] == "check" else _studyctl(env, *args)
        assert res.returncode == 1, res.stdout + res.stderr
        assert res.stderr.strip() == f"Error: {line}", res.stderr
        assert _digest(card) == before
    # every other model loads as ever
    assert json.loads(_studyctl(env, "model", "describe", "mass_spring", "--json").stdout)["builtin"]


def test_names_are_spelt_with_dash_or_underscore_alike():
    res = studyctl("model", "describe", "plate-spring", "--json")
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["name"] == "plate_spring"
    check = studyctl("model", "check", "plate-spring", "--contract", "--json")
    assert check.exit_code == 0, check.output
    assert json.loads(check.output[check.output.index("{"):])["violations"] == []


@pytest.mark.parametrize("args", [("model", "describe", "plate--spring"), ("model", "check", "plate--spring", "--contract")])
def test_an_unknown_model_is_named_as_typed(args):
    res = studyctl(*args)
    assert res.exit_code == 1, res.output
    assert res.output.strip().splitlines() == [
        "Error: unknown model 'plate--spring'; installed: fem, mass_spring, plate_spring (or name a class as \"package.module:Class\")"]


def test_sim_run_names_a_model_the_scene_lacks_as_typed():
    res = studyctl("sim", "run", "--model", "plate--spring", "--time-scale", "0", "--duration", "0.1")
    assert res.exit_code == 1, res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1, res.output
    assert "models.plate--spring: not configured in this scene" in lines[0]


def test_a_protocol_lists_plate_spring_with_a_dash(tmp_path):
    path = fast_protocol(tmp_path, conditions=("fem", "plate-spring"))
    res = studyctl("protocol", "validate", path)
    assert res.exit_code == 0, res.output
    assert "2 conditions" in res.output


@pytest.mark.parametrize("time_scale", ["0", "1"])
def test_a_deformation_of_the_wrong_shape_is_a_model_fault_with_zero_force_not_a_traceback(tmp_path, time_scale):
    target = f"{BAD}:WrongShape"
    path = plugin_scene(tmp_path, target)
    env = {k: v for k, v in os.environ.items() if k != "STUDYCTL_DB"} | {"PYTHONPATH": str(ROOT)}
    res = _studyctl(env, "sim", "run", "--scene", path, "--model", target, "--time-scale", time_scale, "--duration", "1", "--json")
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    stats = json.loads(res.stdout)
    assert stats["events"].get("model_fault") == 1, stats["events"]
    assert stats["max_force_n"] == 0.0


def test_sim_run_says_why_a_model_fault_happened_after_its_table(tmp_path):
    target = f"{BAD}:WrongShape"
    path = plugin_scene(tmp_path, target)
    res = studyctl("sim", "run", "--scene", path, "--model", target, "--time-scale", "0", "--duration", "1")
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("model_fault: ")]
    assert len(lines) == 1, res.output
    assert "shape" in lines[0], lines[0]


def test_sim_run_json_lists_each_model_fault_s_detail(tmp_path):
    target = f"{BAD}:WrongShape"
    path = plugin_scene(tmp_path, target)
    res = studyctl("sim", "run", "--scene", path, "--model", target, "--time-scale", "0", "--duration", "1", "--json")
    assert res.exit_code == 0, res.output
    faults = json.loads(res.output)["faults"]
    assert [f["kind"] for f in faults] == ["model_fault"]
    assert "shape" in faults[0]["detail"], faults


def test_sim_run_says_a_nan_force_was_zeroed_and_for_which_hand(tmp_path):
    """The scene has two hands, both pulling: one line each."""
    target = f"{BAD}:NanForce"
    path = plugin_scene(tmp_path, target)
    res = studyctl("sim", "run", "--scene", path, "--model", target, "--time-scale", "0", "--duration", "1")
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("nan_force: ")]
    assert [ln.rsplit("(", 1)[1] for ln in lines] == ["left hand)", "right hand)"], res.output
    assert "not finite" in lines[0], lines[0]


def test_a_force_of_two_numbers_is_a_model_fault_in_the_servo(tmp_path):
    path = plugin_scene(tmp_path, f"{BAD}:TwoFloatForce")
    result = run_scene(build_scene(path, f"{BAD}:TwoFloatForce"), duration=1.0, time_scale=0.0)
    faults = [e.detail for e in result.events if e.kind == "model_fault"]
    assert faults == ["model_fault: force: returned 2 numbers; allowed: (fx, fy, fz), three floats in N"]
    assert np.all(result.forces == 0.0)


def test_sim_run_says_when_force_calls_are_over_their_budget(env, tmp_path):
    """The slow plugin's force takes 50 us a call against a budget of 20."""
    target = f"{BAD}:SlowForce"
    path = plugin_scene(tmp_path, target)
    res = _studyctl(env, "sim", "run", "--scene", path, "--model", target, "--time-scale", "0", "--duration", "1")
    assert res.returncode == 0, res.stderr
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("over_budget: ")]
    assert len(lines) == 1, res.stdout
    assert lines[0].startswith("over_budget: force: "), res.stdout
    assert "took over 20 us" in lines[0]
    stats = json.loads(_studyctl(env, "sim", "run", "--scene", path, "--model", target, "--time-scale", "0", "--duration", "1",
                                 "--json").stdout)
    assert len(stats["over_budget"]) == 1
    assert stats["over_budget"][0].startswith("over_budget: force: ")


def test_a_fast_model_is_not_said_to_be_over_budget():
    res = studyctl("sim", "run", "--time-scale", "0", "--duration", "1", "--json")
    assert res.exit_code == 0, res.output
    stats = json.loads(res.output)
    assert not [line for line in stats["over_budget"] if line.startswith("over_budget: force")], stats["over_budget"]


def _sim_imports(source: str) -> list[str]:
    """The modules of `sim` that Python source imports from, sorted."""
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "sim":
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names |= {a.name for a in node.names if a.name.split(".")[0] == "sim"}
    return sorted(names)


def test_a_model_s_author_imports_only_sim_models_api():
    """The docs' model, the shipped example and the test plugins take everything from one module."""
    docs = (ROOT / "docs" / "models.md").read_text()
    sources = {f"docs/models.md block {i}": block.split("```")[0] for i, block in enumerate(docs.split("```python\n")[1:])}
    for path in [ROOT / "examples/brainsim-halfspace/src/brainsim_halfspace/__init__.py", *sorted((ROOT / "tests/plugins").glob("*.py"))]:
        sources[str(path.relative_to(ROOT))] = path.read_text()
    imports = {name: _sim_imports(text) for name, text in sources.items()}
    assert {name: mods for name, mods in imports.items() if mods not in ([], ["sim.models.api"])} == {}


@pytest.mark.parametrize(("call", "key", "unit"), [("grasp", "grasp_ms_p99", "ms"), ("force", "force_us_p99", "us"),
                                                   ("deformation", "deformation_ms_p99", "ms")])
def test_the_budgets_docs_models_gives_are_the_api_s(call, key, unit):
    rows = [ln for ln in (ROOT / "docs" / "models.md").read_text().splitlines() if ln.startswith(f"| `{call}(")]
    assert len(rows) == 1, rows
    assert rows[0].rstrip(" |").rsplit("| ", 1)[1] == f"{BUDGETS[key]:g} {unit}"


def test_model_wheel_builds_an_installable_wheel_and_refuses_to_overwrite_one(tmp_path):
    out = tmp_path / "dist"
    res = studyctl("model", "wheel", ROOT / "examples" / "brainsim-halfspace", "--out", out)
    assert res.exit_code == 0, res.output
    wheel = out / "brainsim_halfspace-0.1.0-py3-none-any.whl"
    names = zipfile.ZipFile(wheel).namelist()
    assert "brainsim_halfspace/__init__.py" in names
    eps = zipfile.ZipFile(wheel).read("brainsim_halfspace-0.1.0.dist-info/entry_points.txt").decode()
    assert eps == '[brainsim.models]\nhalfspace = brainsim_halfspace:HalfSpace\n'
    before = _digest(wheel)
    again = studyctl("model", "wheel", ROOT / "examples" / "brainsim-halfspace", "--out", out)
    assert again.exit_code == 1
    assert again.output.strip() == f"Error: {wheel}: exists; --force overwrites it"
    assert _digest(wheel) == before


def test_model_wheel_refuses_a_folder_without_a_pyproject_in_one_line(tmp_path):
    res = studyctl("model", "wheel", tmp_path, "--out", tmp_path / "dist")
    assert res.exit_code == 1
    assert res.output.strip() == f"Error: {tmp_path / 'pyproject.toml'}: no such file; a model package has a pyproject.toml (docs/models.md)"
    assert not (tmp_path / "dist").exists()



HALFSPACE = (ROOT / "examples" / "brainsim-halfspace" / "pyproject.toml").read_text()
ENTRY = 'halfspace = "brainsim_halfspace:HalfSpace"'


@pytest.mark.parametrize(("old", "new", "line"), [
    ('[project.entry-points."brainsim.models"]\n' + ENTRY, '[project.entry-points]\n"brainsim.models" = "x"',
     'project.entry-points."brainsim.models": \'x\' is not a table; allowed: a table of name = "package:Class", '
     'e.g. mymodel = "mypackage:MyModel"'),
    ("dependencies = []", 'dependencies = "numpy"',
     'project.dependencies: \'numpy\' is not a list; allowed: a list of strings, e.g. ["numpy>=1.24"]'),
    ("dependencies = []", 'dependencies = ["numpy", 3]',
     'project.dependencies[1]: 3; allowed: a requirement, one line of text, e.g. "numpy>=1.24"'),
    (ENTRY, "halfspace = 3",
     'project.entry-points."brainsim.models".halfspace: 3; allowed: a string "package.module:Class", e.g. "mypackage:MyModel"'),
    (ENTRY, 'halfspace = "brainsim_halfspace:Half\\nSpace"',
     'project.entry-points."brainsim.models".halfspace: \'brainsim_halfspace:Half\\nSpace\'; '
     'allowed: a string "package.module:Class", e.g. "mypackage:MyModel"'),
    (next(ln for ln in HALFSPACE.splitlines() if ln.startswith("description =")), 'description = "a\\nb"',
     "project.description: 'a\\nb'; allowed: one line of text"),
    ('requires-python = ">=3.11"', "requires-python = 3.11",
     "project.requires-python: 3.11; allowed: one line of text"),
], ids=["entry points not a table", "dependencies a string", "a dependency not a string", "entry point target a number",
        "entry point target with a line break", "description with a line break", "requires-python a number"])
def test_model_wheel_refuses_a_value_of_the_wrong_type_in_one_line(tmp_path, old, new, line):
    folder = tmp_path / "pkg"
    shutil.copytree(ROOT / "examples" / "brainsim-halfspace", folder, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    assert old in HALFSPACE
    (folder / "pyproject.toml").write_text(HALFSPACE.replace(old, new, 1))
    before = _digest(*(p for p in folder.rglob("*") if p.is_file()))
    res = studyctl("model", "wheel", folder, "--out", tmp_path / "dist")
    assert res.exit_code == 1
    lines = res.output.strip().splitlines()
    assert len(lines) == 1, res.output
    assert lines[0] == f"Error: {folder / 'pyproject.toml'}: {line}"
    assert not (tmp_path / "dist").exists()
    assert _digest(*(p for p in folder.rglob("*") if p.is_file())) == before


def test_a_scene_configuring_a_model_that_does_not_load_still_runs_its_other_models(env, tmp_path):
    path = plugin_scene(tmp_path, "bad_default")
    ok = _studyctl(env, "sim", "run", "--scene", path, "--model", "plate_spring", "--time-scale", "0", "--duration", "0.5", "--json")
    assert ok.returncode == 0, ok.stderr
    assert json.loads(ok.stdout)["model"] == "plate_spring"
    res = _studyctl(env, "sim", "run", "--scene", path, "--model", "bad_default", "--time-scale", "0", "--duration", "0.5")
    assert res.returncode == 1
    assert res.stderr.strip() == (f"Error: {path}: models.bad_default: model 'bad_default' (from shadows 0.1): option stiffness: "
                                  "its default 900.0 is outside its own declaration; allowed: [1, 700]"), res.stderr


def test_a_real_time_run_logs_force_calls_over_their_budget_as_an_event(tmp_path):
    """The servo process times the copy of the slow plugin it evaluates: one over_budget event,
    kept in the trace a session stores."""
    target = f"{BAD}:SlowForce"
    path = plugin_scene(tmp_path, target)
    result = run_scene(build_scene(path, target), duration=1.0, time_scale=1.0)
    events = [e.detail for e in result.events if e.kind == "over_budget"]
    assert len(events) == 1, events
    assert events[0].startswith("over_budget: force: "), events
    assert result.over_budget == events


@pytest.mark.parametrize(("cls", "rc", "line"), [
    ("DiagnosticsRaise", 0, None),
    ("ResetRaises", 1, "model '{target}': reset raised RuntimeError: cannot rewind"),
])
def test_diagnostics_and_reset_that_raise_are_one_line_not_a_traceback(tmp_path, cls, rc, line):
    target = f"{BAD}:{cls}"
    path = plugin_scene(tmp_path, target)
    env = {k: v for k, v in os.environ.items() if k != "STUDYCTL_DB"} | {"PYTHONPATH": str(ROOT)}
    res = _studyctl(env, "sim", "run", "--scene", path, "--model", target, "--time-scale", "0", "--duration", "0.5", "--json")
    assert res.returncode == rc, res.stderr
    assert "Traceback" not in res.stderr
    if line is None:
        assert json.loads(res.stdout)["events"].get("model_fault") == 1
    else:
        assert res.stderr.strip() == "Error: " + line.format(target=target)


def test_a_real_time_session_says_a_condition_s_force_calls_are_over_their_budget(tmp_path):
    protocol = fast_protocol(tmp_path, conditions=("slow",), trials=1)
    protocol.write_text(protocol.read_text().replace("[inclusion]", f'[conditions.slow]\nmodel = "{BAD}:SlowForce"\n\n[inclusion]', 1))
    env = {k: v for k, v in os.environ.items() if k != "STUDYCTL_DB"} | {"PYTHONPATH": str(ROOT)}
    db = tmp_path / "s.db"
    assert _studyctl(env, "study", "init", "--protocol", protocol, "--db", db).returncode == 0
    assert _studyctl(env, "participants", "add", "P05", "--synthetic", "--db", db).returncode == 0
    res = _studyctl(env, "session", "run", "--db", db, "--participant", "P05", "--synthetic", "--time-scale", "1")
    assert res.returncode == 0, res.stderr
    said = [ln for ln in res.stderr.splitlines() if "over_budget" in ln]
    assert len(said) == 1, res.stderr
    assert said[0].startswith("condition A: trial 1: over_budget: force: "), res.stderr


def _contract_rows(cls: str) -> dict[str, dict]:
    from analysis.verification.model_check import _scene, contract
    from sim.scene import DEFAULT_SCENE

    rows, _ = contract(_scene(f"{BAD}:{cls}", DEFAULT_SCENE))
    return {r["check"]: r for r in rows}


def test_a_force_of_two_numbers_is_one_violation_named_as_its_shape():
    rows = _contract_rows("TwoFloatForce")
    failed = [(k, r["detail"]) for k, r in rows.items() if r["ok"] is False]
    assert failed == [("force: three floats", "force has shape (2,), must be (3,)")]


@pytest.mark.parametrize("check", ["zero force at zero displacement", "finite, continuous force along the pull", "two hands at once"])
def test_the_checks_that_need_a_sound_force_are_not_run_when_its_shape_is_wrong(check):
    row = _contract_rows("TwoFloatForce")[check]
    assert (row["ok"], row["detail"]) == (None, "skipped: the force's shape is wrong")


def test_a_model_with_no_law_is_checked_for_its_copy_not_for_a_per_tick_law():
    rows = _contract_rows("TwoFloatForce")
    assert "per-tick law pickles and agrees with force" not in rows
    assert rows["no per-tick law: the model's copy pickles"]["ok"] is True


def test_two_hands_at_once_says_no_force_for_a_model_whose_deformation_is_wrong():
    row = _contract_rows("WrongShape")["two hands at once"]
    assert (row["ok"], row["detail"]) == (None, "skipped: the deformation's shape is wrong")


def test_a_nan_force_is_one_violation_and_two_hands_at_once_is_not_run():
    rows = _contract_rows("NanForce")
    assert [k for k, r in rows.items() if r["ok"] is False] == ["finite, continuous force along the pull"]
    assert rows["two hands at once"]["detail"] == "skipped: the force is not finite along the pull"


def test_model_check_contract_prints_one_violation_for_a_force_of_two_numbers(tmp_path):
    res = studyctl("model", "check", f"{BAD}:TwoFloatForce", "--contract")
    assert res.exit_code == 1, res.output
    assert [ln for ln in res.output.splitlines() if ln.startswith("- VIOLATION")] == [
        "- VIOLATION force: three floats: force has shape (2,), must be (3,)"]
    assert "| two hands at once | not run | skipped: the force's shape is wrong |" in res.output


def test_a_force_raising_along_the_pull_is_one_violation_naming_the_exception():
    row = _contract_rows("ForceRaisesNear")["finite, continuous force along the pull"]
    assert (row["ok"], row["detail"]) == (False, "raised ValueError: no force under 1 mm")


def test_the_checks_after_a_force_raising_along_the_pull_name_the_exception_not_a_nan():
    row = _contract_rows("ForceRaisesNear")["two hands at once"]
    assert (row["ok"], row["detail"]) == (None, "skipped: the force along the pull raised ValueError: no force under 1 mm")


def test_the_checks_after_a_force_raising_at_its_first_call_name_the_exception_not_a_shape():
    row = _contract_rows("ForceRaises")["zero force at zero displacement"]
    assert (row["ok"], row["detail"]) == (None, "skipped: the force raised RuntimeError: no force today")
