"""A lab's own tissue model through the public API (sim/models/api.py): discovery by entry point
and by "package.module:Class", plugins that break the contract (each named by `model check`,
each harmless in a session), and the walk-through of docs/models.md in a fresh virtual
environment with the example plugin (examples/brainsim-halfspace)."""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROOT
from tests.helpers import BAD, build_wheel, fast_protocol, plugin_scene

ENTRY_POINTS = f"""[brainsim.models]
spring = {BAD}:Spring
nan_force = {BAD}:NanForce
slow_force = {BAD}:SlowForce
slow_build = {BAD}:SlowBuild
grasp_raises = {BAD}:GraspRaises
other_version = {BAD}:OtherVersion
missing_class = {BAD}:NoSuchModel
broken_import = tests.plugins.broken_import:Model
"""


@pytest.fixture(scope="module")
def plugin_env(tmp_path_factory):
    """An environment whose Python path holds a distribution `fakeplugins` registering the test
    plugins under brainsim.models (what `pip install` of a plugin package writes)."""
    site = tmp_path_factory.mktemp("site")
    info = site / "fakeplugins-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: fakeplugins\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(ENTRY_POINTS)
    env = {k: v for k, v in os.environ.items() if k != "STUDYCTL_DB"}
    env["PYTHONPATH"] = f"{site}{os.pathsep}{ROOT}"
    return env


def _studyctl(env, *args, cwd=None):
    return subprocess.run([sys.executable, "-m", "studyctl", *map(str, args)], env=env, cwd=cwd, capture_output=True, text=True, timeout=600)


def test_model_list_shows_every_model_that_loads_and_one_line_for_each_that_does_not(plugin_env):
    res = _studyctl(plugin_env, "model", "list", "--json")
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    names = {m["name"]: m for m in out["models"]}
    assert {"plate_spring", "fem", "mass_spring", "spring", "nan_force", "slow_force", "grasp_raises"} <= set(names)
    assert names["fem"]["builtin"]
    assert names["spring"]["source"] == "fakeplugins 0.1"
    assert not names["spring"]["builtin"]
    problems = sorted(out["problems"])
    assert len(problems) == 3
    assert all("\n" not in p for p in problems)
    assert problems[0].startswith("model 'broken_import' (from fakeplugins 0.1): cannot import tests.plugins.broken_import: "
                                  "ModuleNotFoundError: No module named 'brainsim_no_such_dependency'")
    assert problems[1] == f"model 'missing_class' (from fakeplugins 0.1): {BAD} has no class 'NoSuchModel'"
    assert problems[2] == "model 'other_version' (from fakeplugins 0.1): declares model API version 2; this brainsim runs version 1"
    text = _studyctl(plugin_env, "model", "list")
    assert text.returncode == 0
    assert "not loaded: model 'missing_class'" in text.stdout
    assert "Traceback" not in text.stdout + text.stderr


@pytest.mark.parametrize(("name", "violation"), [
    ("nan_force", "VIOLATION finite, continuous force along the pull: non-finite force at 0.10 mm"),
    ("slow_force", "VIOLATION force_us_p99: "),
    ("grasp_raises", "VIOLATION grasp: raised RuntimeError: no grip on this tissue"),
])
def test_model_check_names_each_violation_and_exits_non_zero(plugin_env, name, violation):
    res = _studyctl(plugin_env, "model", "check", name)
    assert res.returncode == 1, res.stdout + res.stderr
    assert violation in res.stdout, res.stdout
    assert "violation" in res.stderr
    assert "Traceback" not in res.stdout + res.stderr
    if name == "slow_force":  # 50 us a call against a budget of 20: decisive on any machine
        card = json.loads(_studyctl(plugin_env, "model", "check", name, "--json").stdout)
        force = next(b for b in card["budgets"] if b["budget"] == "force_us_p99")
        assert force["median"] >= 50.0
        assert not force["ok"]


@pytest.mark.parametrize(("name", "cause"), [
    ("broken_import", "model 'broken_import' (from fakeplugins 0.1): cannot import tests.plugins.broken_import: ModuleNotFoundError"),
    ("missing_class", f"model 'missing_class' (from fakeplugins 0.1): {BAD} has no class 'NoSuchModel'"),
    ("tests.plugins.nowhere:Model", "model 'tests.plugins.nowhere:Model': cannot import tests.plugins.nowhere: ModuleNotFoundError"),
])
def test_a_model_that_does_not_load_is_one_line_naming_it_and_the_cause(plugin_env, name, cause):
    res = _studyctl(plugin_env, "model", "check", name)
    assert res.returncode == 1, res.stderr
    assert res.stderr.startswith(f"Error: {cause}"), res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
    assert "Traceback" not in res.stderr


def test_a_model_on_the_python_path_keeps_the_contract():
    from analysis.verification.model_check import _scene, contract
    from sim.scene import DEFAULT_SCENE

    rows, _ = contract(_scene(f"{BAD}:Spring", DEFAULT_SCENE))
    assert all(r["ok"] for r in rows), rows
    assert [r["check"] for r in rows][:4] == ["build", "grasp", "force: three floats", "zero force at zero displacement"]


@pytest.mark.parametrize("time_scale", [0.0, 1.0])
def test_in_a_session_a_plugin_that_sends_nan_renders_zero_force_and_logs_it(tmp_path, time_scale):
    """In the servo loop (lockstep) and in the servo process (real time, the model's copy
    pickled to it at the grasp): zero force and a nan_force event, never a crash."""
    from sim.run import run_scene
    from sim.scene import build_scene

    path = plugin_scene(tmp_path, f"{BAD}:NanForce")
    scene = build_scene(path, f"{BAD}:NanForce")
    result = run_scene(scene, duration=1.0, time_scale=time_scale)
    kinds = [e.kind for e in result.events]
    assert "grasp" in kinds, kinds
    assert "nan_force" in kinds, kinds
    assert np.all(result.forces == 0.0)


def test_in_a_session_a_plugin_whose_grasp_raises_logs_a_fault_and_renders_nothing(tmp_path):
    from sim.run import run_scene
    from sim.scene import build_scene

    path = plugin_scene(tmp_path, f"{BAD}:GraspRaises")
    result = run_scene(build_scene(path, f"{BAD}:GraspRaises"), duration=1.0, time_scale=0.0)
    faults = [e for e in result.events if e.kind == "model_fault"]
    assert faults
    assert "grasp: no grip on this tissue" in faults[0].detail
    assert np.all(result.forces == 0.0)
    # the other models are unaffected: the same scene's plate-spring pulls as ever
    other = run_scene(build_scene(path, "plate_spring"), duration=1.0, time_scale=0.0)
    assert np.abs(other.forces).max() > 0.01
    assert not [e for e in other.events if e.kind == "model_fault"]


def test_a_plugins_bad_option_is_refused_with_file_line_and_range_like_a_builtin_one(tmp_path):
    from sim.errors import SceneError
    from sim.scene import load_scene

    path = plugin_scene(tmp_path, f"{BAD}:Spring")
    text = path.read_text().replace("stiffness = 300.0", "stiffness = 9000.0\ncolour = 1")
    path.write_text(text)
    with pytest.raises(SceneError) as exc:
        load_scene(path)
    line = text.splitlines().index("stiffness = 9000.0") + 1
    assert f"{path}:{line}: models.{BAD}:Spring.stiffness: 9000.0 is out of range; allowed: [1, 700]" in exc.value.problems
    assert any(p.endswith(f"models.{BAD}:Spring.colour: unknown key; allowed: stiffness") for p in exc.value.problems)


def test_a_condition_stores_the_plugins_distribution_version_and_source_hash(plugin_env, tmp_path):
    path = fast_protocol(tmp_path, conditions=("plate_spring", "own"))
    path.write_text(path.read_text().replace("[inclusion]", '[conditions.own]\nmodel = "spring"\nstiffness = 250.0\n\n[inclusion]'))
    code = f"""
import json
from studyctl.conditions import condition_scene_spec, resolved_config
from studyctl.protocol import load_protocol
p = load_protocol({str(path)!r})
print(json.dumps({{c: resolved_config(c, condition_scene_spec(p, c)) for c in p.conditions}}))
"""
    res = subprocess.run([sys.executable, "-c", code], env=plugin_env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    configs = json.loads(res.stdout)
    own = configs["own"]
    assert own["model"] == "spring"
    assert own["options"] == {"stiffness": 250.0}
    assert own["plugin"]["distribution"] == "fakeplugins"
    assert own["plugin"]["version"] == "0.1"
    assert own["plugin"]["target"] == f"{BAD}:Spring"
    assert len(own["plugin"]["source_sha256"]) == 64
    assert "plugin" not in configs["plate_spring"]  # built in: the study's own version says it


def test_no_caller_probes_a_model_with_hasattr_or_getattr():
    """Every optional capability is declared by sim/models/api.py: nothing outside it asks a
    model whether it has an attribute."""
    offenders = []
    for path in [*ROOT.glob("sim/**/*.py"), *ROOT.glob("studyctl/**/*.py"), *ROOT.glob("analysis/**/*.py")]:
        if path.name == "api.py" and path.parent.name == "models":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("hasattr", "getattr") and node.args:
                if "model" in ast.unparse(node.args[0]).lower():
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)}")
    assert offenders == []


DOCS = ROOT / "docs" / "models.md"


def test_the_shipped_example_plugin_in_a_fresh_environment(tmp_path):
    """The shipped example (examples/brainsim-halfspace), docs/models.md's commands with its
    name: brainsim's wheel and the example installed into a new venv (seeing this venv's
    third-party packages through a path file, as tests/test_wheel.py does), every command run
    from a folder outside the checkout. The page's own package: tests/test_model_from_docs.py."""
    import shutil
    import sysconfig

    docs = DOCS.read_text()
    wheel = build_wheel(tmp_path)
    example = shutil.copytree(ROOT / "examples" / "brainsim-halfspace", tmp_path / "example")  # builds leave files beside the source
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path / "dist"), str(example)], check=True, capture_output=True)
    (plugin,) = (tmp_path / "dist").glob("brainsim_halfspace-*.whl")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    py = venv / "bin" / "python"
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], check=True, capture_output=True, text=True).stdout.strip()
    Path(site, "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps", str(wheel), str(plugin)], check=True, capture_output=True)
    work = tmp_path / "lab"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "STUDYCTL_DB")}

    def run(command: str, *extra: str, ok: bool = True) -> str:
        page = "~/lab/bin/" + command.replace("halfspace", "stiffening")  # the page's model, in the page's venv
        assert page in docs, f"docs/models.md no longer says {page!r}"
        args = command.split()
        res = subprocess.run([str(venv / "bin" / args[0]), *args[1:], *extra], cwd=work, env=env, capture_output=True, text=True, timeout=900)
        assert (res.returncode == 0) == ok, f"{command}: {res.stdout[-3000:]}{res.stderr[-3000:]}"
        return res.stdout

    models = json.loads(run("studyctl model list", "--json"))
    half = next(m for m in models["models"] if m["name"] == "halfspace")
    assert half["source"] == "brainsim-halfspace 0.1.0"
    assert not half["builtin"]
    assert "grasp_radius" in run("studyctl model describe halfspace")
    contract = json.loads(run("studyctl model check halfspace --contract", "--json"))
    assert contract["violations"] == []
    assert contract["stability"] is None
    assert len(contract["budgets"]) == 3
    card = json.loads(run("studyctl model check halfspace --quick", "--json"))
    assert card["violations"] == []
    assert all(r["ok"] for r in card["contract"])
    assert card["stability"]["safety_held"]
    assert {r["calibration"] for r in card["accuracy"]["rows"]} == {"raw", "calibrated"}
    run("studyctl protocol new --kind yes_no --out mystudy")
    protocol = work / "mystudy" / "protocol.toml"
    edit = '[conditions.half_space]\nmodel = "halfspace"\ngrasp_radius = 0.005\n'
    text = protocol.read_text().replace('conditions = ["fem", "mass_spring", "plate_spring"]', 'conditions = ["plate_spring", "fem", "half_space"]')
    # shorter sessions than the page's (one 1 s trial per condition): the machinery, not the statistics, is under test
    text = text.replace("trials_per_condition = 3", "trials_per_condition = 1").replace("trial_seconds = 3.0", "trial_seconds = 1.0")
    protocol.write_text(text.replace("[inclusion]", edit + "\n[inclusion]"))
    run("studyctl protocol validate mystudy/protocol.toml")
    run("studyctl synth --db mystudy/study.db --protocol mystudy/protocol.toml --participants 6")
    table1 = run("studyctl report table1 --db mystudy/study.db")
    assert "half_space" in table1
    assert "SYNTHETIC" in table1.upper()
    sweep = json.loads(run("studyctl bench stability --quick --models halfspace,plate_spring", "--json"))
    assert {c["model"].split("/")[0] for c in sweep["cases"]} == {"halfspace", "plate_spring"}
    assert sweep["meta"]["nan_sent"] == 0
    assert sweep["meta"]["over_limit_sent"] == 0
    bench = json.loads(run("studyctl bench accuracy --quick --models halfspace,plate_spring", "--json"))
    assert {r["model"] for r in bench["rows"]} == {"halfspace", "plate_spring"}


def test_a_discrimination_study_refuses_a_model_that_does_not_scale_its_stiffness(tmp_path):
    """The spring plugin declares no stiffness scaling: the protocol says so before any session."""
    from studyctl.protocol import check_protocol

    path = tmp_path / "p"
    path.mkdir()
    res = subprocess.run([sys.executable, "-m", "studyctl", "protocol", "new", "--kind", "discrimination", "--out", str(path)],
                         capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    protocol = path / "protocol.toml"
    text = protocol.read_text()
    start = text.index("conditions = [")
    text = text[:start] + 'conditions = ["own"]' + text[text.index("\n", start):]
    protocol.write_text(text.replace("[inclusion]", f'[conditions.own]\nmodel = "{BAD}:Spring"\n\n[inclusion]', 1)
                        if "[inclusion]" in text else text + f'\n[conditions.own]\nmodel = "{BAD}:Spring"\n')
    _, problems = check_protocol(protocol)
    assert any(f"design.conditions: condition 'own': model '{BAD}:Spring' does not scale its stiffness" in p for p in problems), problems


def test_model_describe_prints_the_declared_options(plugin_env):
    out = json.loads(_studyctl(plugin_env, "model", "describe", "spring", "--json").stdout)
    assert out["options"] == [{"name": "stiffness", "kind": "number", "default": 200.0, "unit": "N/m", "allowed": "[1, 700]",
                               "doc": "the spring's stiffness"}]
    assert (out["distribution"], out["version"], out["builtin"]) == ("fakeplugins", "0.1", False)
    fem = json.loads(_studyctl(plugin_env, "model", "describe", "fem", "--json").stdout)
    assert [o["name"] for o in fem["options"]] == ["resolution", "formulation", "grasp_radius", "order"]
    assert fem["options"][0]["allowed"] == "[0.003, 0.008]"
    assert fem["material_keys"] == ["young", "poisson"]


def test_model_check_of_a_built_in_model_gives_its_whole_scorecard(tmp_path):
    """The plate-spring on the shipped scene: the contract, budgets, the quick sweep's cases of
    both its rows and the quick accuracy bench's row; Markdown and JSON say the same."""
    from tests.helpers import studyctl

    res = studyctl("model", "check", "plate_spring", "--quick", "--json", "--out", tmp_path / "card.md")
    assert res.exit_code == 0, res.output
    card = json.loads(res.stdout)  # the stages went to stderr
    assert card["violations"] == []
    assert len(card["contract"]) == 9
    assert all(r["ok"] for r in card["contract"])
    assert {c["model"] for c in card["stability"]["cases"]} == {"plate_spring/continuous", "plate_spring/paper"}
    assert card["stability"]["safety_held"]
    assert {r["calibration"] for r in card["accuracy"]["rows"]} == {"raw", "calibrated"}
    md = (tmp_path / "card.md").read_text()
    assert md.startswith("# Model check: plate_spring")
    assert "The model keeps the contract and its budgets on this machine." in md


def test_model_check_prints_its_stages_and_contract_runs_only_the_contract_and_budgets(plugin_env):
    """The stages on stderr as they start and end (the estimate after the budgets), the card on
    stdout; --contract stops after the budgets and says so."""
    res = _studyctl(plugin_env, "model", "check", "spring", "--quick")
    assert res.returncode == 0, res.stderr
    lines = res.stderr.splitlines()
    starts = [ln for ln in lines if ln.endswith(" ...")]
    assert starts == ["[1/4] contract ...", "[2/4] budgets (this machine) ...", "[3/4] stability (quick sweep) ...",
                      "[4/4] accuracy against the tissue truth ..."], res.stderr
    assert any(ln.startswith("[1/4] contract: 8 of 8 checks held (") for ln in lines), res.stderr  # no stiffness scaling: 8
    assert any("estimated from this model's measured costs" in ln and "the reference solves shipped or cached" in ln for ln in lines), res.stderr
    assert "## Accuracy against the tissue truth" in res.stdout
    only = _studyctl(plugin_env, "model", "check", "spring", "--contract", "--json")
    assert only.returncode == 0, only.stderr
    card = json.loads(only.stdout)
    assert card["contract_only"]
    assert card["stability"] is None
    assert card["accuracy"] is None
    assert card["skipped"].startswith("--contract")
    assert set(card["stage_seconds"]) == {"contract", "budgets"}
    assert [ln for ln in only.stderr.splitlines() if ln.endswith(" ...")] == ["[1/2] contract ...", "[2/2] budgets (this machine) ..."]


def test_model_check_interrupted_keeps_the_stages_that_finished(plugin_env, tmp_path):
    """Ctrl-C (SIGINT) in the stability sweep (a plugin whose every build takes a second): exit
    130, the card with the contract and the budgets written to --out and printed, marked
    interrupted; nothing claims a verdict on the rest."""
    import signal

    out = tmp_path / "card.json"
    # pytest-xdist's workers ignore SIGINT, and an ignored signal stays so across exec: the command
    # starts as from a terminal, with Ctrl-C at its default
    proc = subprocess.Popen([sys.executable, "-m", "studyctl", "model", "check", "slow_build", "--out", str(out)], env=plugin_env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    seen = ""
    while "[3/4] stability (quick sweep) ..." not in seen:  # stderr, line by line
        line = proc.stderr.readline()
        assert line, f"model check ended before its stability stage: {seen}"
        seen += line
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, seen + stderr
    card = json.loads(out.read_text())
    assert card["interrupted"] == "stability"
    assert len(card["contract"]) == 8
    assert len(card["budgets"]) == 3
    assert "stability" not in card
    assert "accuracy" not in card
    assert "## Budgets" in stdout  # stdout: the same card as Markdown
    assert "INTERRUPTED during stability (quick sweep)" in stdout
    assert "Traceback" not in stderr
    assert stderr.strip().splitlines()[-1].startswith("Error: model check slow_build: interrupted during stability (quick sweep)")


def test_a_plugin_whose_build_raises_is_one_line(tmp_path):
    path = plugin_scene(tmp_path, f"{BAD}:Spring")
    path.write_text(path.read_text().replace(f'[models."{BAD}:Spring"]', f'[models."{BAD}:BuildRaises"]'))
    env = {k: v for k, v in os.environ.items() if k != "STUDYCTL_DB"} | {"PYTHONPATH": str(ROOT)}
    res = _studyctl(env, "sim", "run", "--scene", path, "--model", f"{BAD}:BuildRaises", "--time-scale", "0", "--duration", "0.5")
    assert res.returncode == 1, res.stderr
    assert res.stderr.strip() == (f"Error: model '{BAD}:BuildRaises': build raised RuntimeError: "
                                                          "no tissue parameters for this brain"), res.stderr


def test_a_plugin_whose_copy_cannot_reach_the_servo_process_is_a_fault_not_a_crash(tmp_path):
    from sim.run import run_scene
    from sim.scene import build_scene

    path = plugin_scene(tmp_path, f"{BAD}:Spring")
    path.write_text(path.read_text().replace(f'[models."{BAD}:Spring"]', f'[models."{BAD}:Unpicklable"]'))
    result = run_scene(build_scene(path, f"{BAD}:Unpicklable"), duration=1.0, time_scale=1.0)
    faults = [e for e in result.events if e.kind == "model_fault"]
    assert faults
    assert faults[0].detail.startswith("model_fault: law: TypeError")
    assert np.all(result.forces == 0.0)


def test_options_are_checked_by_kind_and_a_declaration_the_reader_cannot_read_does_not_load(tmp_path, plugin_env):
    from sim.errors import SceneError
    from sim.models.registry import ModelLoadError, model_class
    from sim.scene import load_scene

    with pytest.raises(ModelLoadError, match=r"Options is not a dataclass"):
        model_class(f"{BAD}:NotADataclass")
    path = plugin_scene(tmp_path, f"{BAD}:Spring")
    path.write_text(path.read_text().replace(f'[models."{BAD}:Spring"]\nstiffness = 300.0',
                                             f'[models."{BAD}:Flagged"]\nmirrored = "yes"\nlayers = 3'))
    with pytest.raises(SceneError) as exc:
        load_scene(path)
    assert any(p.endswith(f"models.{BAD}:Flagged.mirrored: 'yes' is not true or false") for p in exc.value.problems), exc.value.problems
    assert any(p.endswith(f"models.{BAD}:Flagged.layers: 3 is not one of 1, 2") for p in exc.value.problems), exc.value.problems
    # a model whose option has no default: the benches leave it out of their default rows, and say why
    from analysis.verification.accuracy import plugin_problem

    assert "stiffness has no default" in plugin_problem(f"{BAD}:NoDefault")


def test_a_discrimination_protocol_with_a_malformed_condition_is_refused_in_one_line(tmp_path):
    from studyctl.protocol import check_protocol

    path = tmp_path / "p"
    path.mkdir()
    subprocess.run([sys.executable, "-m", "studyctl", "protocol", "new", "--kind", "discrimination", "--out", str(path)], check=True,
                   capture_output=True, cwd=ROOT)
    protocol = path / "protocol.toml"
    text = protocol.read_text()
    start = text.index("conditions = [")
    protocol.write_text(text[:start] + 'conditions = [["fem"], "plate_spring"]' + text[text.index("\n", start):])
    _, problems = check_protocol(protocol)
    assert any("design.conditions: ['fem'] is not a condition's name" in p for p in problems), problems


def test_the_built_in_models_keep_the_contract_and_their_budgets_here():
    """Contract and budgets (not the sweeps) of the three on the shipped scene: the budgets'
    margins are 10x or more on this machine (docs/models.md), not marginal."""
    from analysis.verification.model_check import CheckConfig, _scene, budgets, contract
    from sim.scene import DEFAULT_SCENE

    for name in ("plate_spring", "fem", "mass_spring"):
        rows, parts = contract(_scene(name, DEFAULT_SCENE))
        assert all(r["ok"] for r in rows), (name, rows)
        timed = budgets(parts, CheckConfig(scene=DEFAULT_SCENE, force_calls=2000, frames=10))
        assert [b["budget"] for b in timed] == ["force_us_p99", "deformation_ms_p99", "grasp_ms_p99"]
        assert all("raised" not in b for b in timed)
