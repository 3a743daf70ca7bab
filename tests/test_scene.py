"""Scene files: validation, and building only what a scene asks for."""

import json
import subprocess
import sys
import textwrap

import pytest

from sim.errors import SceneError
from sim.scene import load_scene
from tests.conftest import ROOT, SCENE
from tests.helpers import localise


def test_shipped_scene(root):
    s = load_scene(SCENE)
    assert s.model == "plate_spring"
    assert len(s.hands) == 2
    assert s.mesh_path == root / "data" / "brain_fsaverage5.npz"
    law = s.material.law  # human cortex, fitted to Budday et al. 2017 (protocols/materials/human_cortex.toml)
    assert law.law == "ogden"  # the joint fit (issue 55)
    assert 1250 < law.shear_modulus < 1450
    assert -22 < law.alpha[0] < -19
    assert law.bulk_ratio == 50
    # the linear models' modulus is the law's small-strain limit at their Poisson ratio: E = 2 mu (1 + nu)
    assert not s.material.young_given
    assert s.material.poisson == 0.45
    assert s.material.young == pytest.approx(2 * law.shear_modulus * 1.45, rel=1e-12)
    assert s.renderer.kind == "offscreen"
    assert s.servo_rate_hz == 1000.0


def _scene_text(**replace) -> str:
    text = SCENE.read_text()
    for old, new in replace.items():
        assert old in text
        text = text.replace(old, new)
    return text


@pytest.mark.parametrize(
    "old, new, message",
    [
        ('kind = "offscreen"', 'kind = "window"', r"renderer.kind: 'window' is not one of none, offscreen"),
        ("[servo]", "[view]\nfront = [0.0, 0.0, 1.0]\nup = [0.0, 0.0, 2.0]\n\n[servo]", r"view.up: \[0.0, 0.0, 2.0\] must not be zero or parallel to front"),
        ("[servo]", "[view]\nzoom = 9.0\n\n[servo]", r"view.zoom: 9.0 is out of range; allowed: \[0.05, 5\]"),
        ('device = "simulated"\nstart = [-0.0313', 'device = "openhaptics"\ndevice_scale = 20.0\nstart = [-0.0313',
         r"hands\[0\].device_scale: 20.0 is out of range; allowed: \[0.1, 10\]"),
        ("density = 1040.0", "young = -3.0\ndensity = 1040.0", r"material.young: -3.0 is out of range; allowed: \[1, 1e\+09\] Pa"),
        ('file = "../materials/human_cortex.toml"', 'law = "ogden"\nmu = [1500.0]\nalpha = [0.0]', r"material.alpha: 0 is not an exponent"),
        ('file = "../materials/human_cortex.toml"', 'law = "ogden"\nmu = [1500.0, 10.0]\nalpha = [-18.0]', r"material.alpha: 1 exponent\(s\) for 2 mu term"),
        ('file = "../materials/human_cortex.toml"', 'law = "neo-hookean"\nmu = 1500.0\nalpha = [-18.0]', r"material.alpha: not a parameter of the neo-hookean law"),
        ('file = "../materials/human_cortex.toml"', 'file = "../materials/human_cortex.toml"\nmu = [1500.0]', r"material.mu: give the law in the material `file` or inline, not both"),
        ('file = "../materials/human_cortex.toml"', 'file = "nowhere.toml"', r"material.file: .*nowhere.toml does not exist"),
        ('file = "../materials/human_cortex.toml"', 'law = "ogden"\nmu = [-5.0]\nalpha = [-18.0]', r"material.mu: -5.0 is out of range"),
        ("poisson = 0.45", "poisson = 0.7", r"material.poisson: 0.7 is out of range; allowed: \[0, 0.5\)"),
        ('name = "plate_spring"', 'name = "rubber"', r"model.name: 'rubber' has no \[models.rubber\] section"),
        ("[models.plate_spring]", "[models.rubber]", r"models.rubber: unknown model 'rubber'"),
        ("distance = 0.012\ngrasp_at = 0.3\npull_start = 0.5\npull_time = 1.2\nrelease_at = 2.6\n\n[[hands]]",
         'distance = "far"\ngrasp_at = 0.3\npull_start = 0.5\npull_time = 1.2\nrelease_at = 2.6\n\n[[hands]]',
         r"hands\[0\].distance: 'far' is not a finite number"),
        ("[fixed]", "[fixd]", r"fixed: missing section"),
        ('device = "simulated"', 'device = "phantom"', r"device: 'phantom' is not one of simulated"),
        ("rate_hz = 1000", "rate_hz = 1000 =", r"invalid TOML"),
        ('acceleration = "none"', 'acceleration = "aitken"',
         r"models.mass_spring.acceleration: 'aitken' is not one of none, chebyshev, anderson, newton"),
        ("x_c1", "x_c1", r""),
    ],
)
def test_broken_scenes(tmp_path, old, new, message):
    if old == "x_c1":  # plate-spring parameter errors surface with the parameter file's name
        params = tmp_path / "p.toml"
        params.write_text((ROOT / "protocols/models/plate_spring_handset.toml").read_text().replace("alpha = 1.25", "alpha = 3.0"))
        text = _scene_text(**{'"../models/plate_spring_brain.toml"': f'"{params}"'})
        message = r"p.toml:\d+: alpha: 3.0 is out of range; allowed: \[1, 2\]"
    else:
        text = _scene_text(**{old: new})
    text = localise(text)
    path = tmp_path / "scene.toml"
    path.write_text(text)
    with pytest.raises(Exception) as exc:
        load_scene(path)
    from sim.errors import SimError

    assert isinstance(exc.value, SimError)
    import re

    assert re.search(message, str(exc.value)), str(exc.value)
    lines = str(exc.value).splitlines()  # every problem on its own line, FILE:LINE: field: message
    assert isinstance(exc.value, SceneError)
    assert exc.value.problems == lines
    assert all(re.match(r"\S+\.toml:\d+: \S", line) for line in lines), lines


def test_three_hands_refused(tmp_path):
    text = localise(SCENE.read_text())
    block = text[text.index("[[hands]]"):]
    path = tmp_path / "s.toml"
    path.write_text(text + "\n" + block.replace('name = "left"', 'name = "third"'))
    with pytest.raises(SceneError, match="one or two"):
        load_scene(path)


def _run_python(code: str) -> dict:
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, cwd=ROOT, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_headless_plate_spring_scene_never_imports_open3d_the_renderer_or_other_models(tmp_path):
    # the FEM module is never imported, so no stiffness matrix is ever assembled
    scene = tmp_path / "headless.toml"
    scene.write_text(localise(SCENE.read_text().replace('kind = "offscreen"', 'kind = "none"')))
    got = _run_python(f"""
        import json, sys
        from sim.scene import build_scene
        from sim.run import run_scene
        scene = build_scene({str(scene)!r})
        result = run_scene(scene, duration=0.5, time_scale=0)
        print(json.dumps({{
            "open3d": sorted(m for m in sys.modules if m.startswith("open3d"))[:3],
            "render": sorted(m for m in ("sim.view.pictures", "sim.view.renderer", "sim.view.window", "moderngl", "glfw") if m in sys.modules),
            "models": sorted(m for m in ("sim.models.plate_spring", "sim.models.fem", "sim.models.mass_spring") if m in sys.modules),
            "ticks": len(result.times),
        }}))
    """)
    assert got == {"open3d": [], "render": [], "models": ["sim.models.plate_spring"], "ticks": 500}


def test_one_hand_scene_opens_one_device(tmp_path):
    text = localise(SCENE.read_text())
    text = text[: text.rindex("[[hands]]")]  # drop the right hand
    scene = tmp_path / "one.toml"
    scene.write_text(text)
    got = _run_python(f"""
        import json
        from sim.scene import build_scene
        from sim.run import run_scene
        from sim.devices.simulated import SimulatedOmni
        result = run_scene(build_scene({str(scene)!r}), duration=0.2, time_scale=0)
        print(json.dumps({{"opened": SimulatedOmni.opened, "hands": result.hand_names}}))
    """)
    assert got == {"opened": 1, "hands": ["left"]}


def test_headless_fem_scene_meshes_in_a_child_and_assembles_once_per_hemisphere(tmp_path):
    scene = tmp_path / "fem.toml"
    text = localise(SCENE.read_text().replace('kind = "offscreen"', 'kind = "none"'))
    scene.write_text(text.replace('name = "plate_spring"               #', 'name = "fem"  #').replace("resolution = 0.004", "resolution = 0.008"))
    got = _run_python(f"""
        import json, sys
        from sim.scene import build_scene
        from sim.run import run_scene
        scene = build_scene({str(scene)!r})
        result = run_scene(scene, duration=0.3, time_scale=0)
        import sim.models.fem as fem
        print(json.dumps({{"open3d": any(m.startswith("open3d") for m in sys.modules), "assemblies": fem.ASSEMBLIES[0],
                          "render": "sim.view.pictures" in sys.modules}}))
    """)
    assert got == {"open3d": False, "assemblies": 2, "render": False}


# -- every problem at once, each as FILE:LINE: field: message ---------------------------------


def _line_of(text: str, needle: str) -> int:
    """The 1-based number of the first line containing `needle`."""
    return next(i for i, ln in enumerate(text.splitlines(), start=1) if needle in ln)


def _write_scene(tmp_path, text: str, name: str = "s.toml"):
    path = tmp_path / name
    path.write_text(localise(text))
    return path, path.read_text()


def _problems(path) -> list[str]:
    with pytest.raises(SceneError) as exc:
        load_scene(path)
    assert str(exc.value) == "\n".join(exc.value.problems)
    return exc.value.problems


def test_three_independent_problems_all_reported_with_their_lines(tmp_path):
    path, text = _write_scene(tmp_path, _scene_text(**{
        "poisson = 0.45": "poisson = 0.7",
        'kind = "offscreen"': 'kind = "window"',
        "pull = [1.0, 0.0, 0.0]\ndistance = 0.012": "pull = [1.0, 0.0, 0.0]\ndistance = 0.5",
    }))
    assert _problems(path) == [
        f"{path}:{_line_of(text, 'poisson = 0.7')}: material.poisson: 0.7 is out of range; allowed: [0, 0.5)",
        f"{path}:{_line_of(text, 'kind = ')}: renderer.kind: 'window' is not one of none, offscreen",
        f"{path}:{_line_of(text, 'distance = 0.5')}: hands[1].distance: 0.5 is out of range; allowed: [0, 0.2]",
    ]
    assert _line_of(text, "poisson = 0.7") == 15  # the shipped scene's layout (white_matter above it), checked once by hand


@pytest.mark.parametrize(
    "old, new, needle, field, allowed",
    [
        ("density = 1040.0", "youngs = 3000.0\ndensity = 1040.0", "youngs", "material.youngs",
         "file, law, mu, mu1, mu2, alpha, bulk_ratio, young, poisson, density, white_matter, pia_arachnoid"),
        ("rate_hz = 1000\n", "rate_hz = 1000\nrate = 2\n", "rate = 2", "servo.rate", "rate_hz"),
        ("grasp_radius = 0.005                # a grasp", "grasp_radius = 0.005\nradius = 0.01  # a grasp", "radius = 0.01",
         "models.fem.radius", "resolution, formulation, grasp_radius, order"),
        ('name = "right"\n', 'name = "right"\nspeed = 2.0\n', "speed", "hands[1].speed",
         "name, device, start, pull, distance, grasp_at, pull_start, pull_time, release_at, device_name, device_scale, "
         "device_origin, trace, trace_hand, target"),
        ("[servo]", "[sevro]\nrate_hz = 1000\n\n[servo]", "[sevro]", "sevro",
         "scene, mesh, material, fixed, model, models, servo, visual, renderer, view, hands"),
    ],
)
def test_unknown_keys_refused_with_the_allowed_ones(tmp_path, old, new, needle, field, allowed):
    path, text = _write_scene(tmp_path, _scene_text(**{old: new}))
    what = "section" if field == "sevro" else "key"
    expected = f"{path}:{_line_of(text, needle)}: {field}: unknown {what}; allowed: {allowed}"
    problems = _problems(path)
    assert expected in problems
    assert problems == [expected]  # young is optional (the law's small-strain limit), so only the misspelling is reported


def test_unknown_and_missing_keys_of_the_parameter_file_named_by_its_lines(tmp_path):
    params = tmp_path / "p.toml"
    params.write_text((ROOT / "protocols/models/plate_spring_brain.toml").read_text()
                      .replace("layers = 6", "layers = 6\nstiffness = 3.0").replace("omega = 1.2", ""))
    path, _ = _write_scene(tmp_path, _scene_text(**{'"../models/plate_spring_brain.toml"': f'"{params}"'}))
    ptext = params.read_text()
    assert _problems(path) == [
        f"{params}:1: missing key omega; required: b, h1, l1, alpha, q, layers, B, E, x_c1, delta, t1, omega",
        f"{params}:{_line_of(ptext, 'stiffness')}: stiffness: unknown key; allowed: b, h1, l1, alpha, q, layers, B, E, x_c1, delta, t1, omega",
    ]


def test_poisson_bound_is_the_fems(tmp_path):
    path, text = _write_scene(tmp_path, _scene_text(**{"poisson = 0.45": "poisson = 0.5"}))
    assert _problems(path) == [f"{path}:{_line_of(text, 'poisson =')}: material.poisson: 0.5 is out of range; allowed: [0, 0.5)"]
    ok, _ = _write_scene(tmp_path, _scene_text(**{"poisson = 0.45": "poisson = 0.499"}), "ok.toml")
    assert load_scene(ok).material.poisson == 0.499
    neg, _ = _write_scene(tmp_path, _scene_text(**{"poisson = 0.45": "poisson = -0.1"}), "neg.toml")
    assert _problems(neg)[0].endswith("material.poisson: -0.1 is out of range; allowed: [0, 0.5)")
    from sim.errors import ParameterError
    from sim.models.fem import check_material

    check_material(3000.0, 0.499)
    for nu in (0.5, -0.1):  # the FEM refuses what the scene refuses, in the same words
        with pytest.raises(ParameterError, match=rf"^poisson: {nu} is out of range; allowed: \[0, 0.5\)$"):
            check_material(3000.0, nu)


def test_file_problems_are_one_line_naming_the_file(tmp_path):
    bad = tmp_path / "latin1.toml"
    bad.write_bytes(localise(SCENE.read_text()).replace('"Two simulated', '"Zw\xf6lf simulated').encode("latin-1"))
    assert _problems(bad) == [f"{bad}:6: not UTF-8: byte 0xf6 at column 18; TOML files must be UTF-8"]

    syntax, text = _write_scene(tmp_path, _scene_text(**{"rate_hz = 1000": "rate_hz = 1000 ="}), "syntax.toml")
    (problem,) = _problems(syntax)
    assert problem.startswith(f"{syntax}:{_line_of(text, 'rate_hz = 1000 =')}: invalid TOML: ")

    missing = tmp_path / "none.toml"
    assert _problems(missing) == [f"{missing}: not found"]

    # the parameter file a scene names: the same, with that file's name and line
    params = tmp_path / "p.toml"
    params.write_bytes(b"b = 0.01\nh1 = \xff\n")
    path, _ = _write_scene(tmp_path, _scene_text(**{'"../models/plate_spring_brain.toml"': f'"{params}"'}))
    assert _problems(path) == [f"{params}:2: not UTF-8: byte 0xff at column 6; TOML files must be UTF-8"]
    params.write_text("b = 0.01\nh1 = = 2\n")
    (problem,) = _problems(path)
    assert problem.startswith(f"{params}:2: invalid TOML: ")
    params.unlink()
    path, text = _write_scene(tmp_path, _scene_text(**{'"../models/plate_spring_brain.toml"': f'"{params}"'}))
    assert _problems(path) == [f"{path}:{_line_of(text, 'params =')}: models.plate_spring.params: {params} does not exist"]


def test_cli_prints_every_problem_without_a_traceback(tmp_path):
    from click.testing import CliRunner

    from studyctl.cli import cli

    path, text = _write_scene(tmp_path, _scene_text(**{
        "poisson = 0.45": "poisson = 0.5", "density = 1040.0": "youngs = 3000.0\ndensity = 1040.0", "pull_start = 0.5": "pull_start = 0.1"}))
    problems = _problems(path)
    assert len(problems) == 4  # youngs unknown, poisson, and both hands' pull_start
    for scene in (path, tmp_path / "none.toml"):
        res = CliRunner().invoke(cli, ["sim", "run", "--scene", str(scene), "--duration", "0.1", "--time-scale", "0"])
        assert res.exit_code == 1, res.output
        assert "Traceback" not in res.output
        assert not isinstance(res.exception, SceneError)
        expected = problems if scene == path else [f"{scene}: not found"]
        assert res.output.removeprefix("Error: ").splitlines() == expected
    bad = tmp_path / "bytes.toml"
    bad.write_bytes(b"[scene]\nname = \"\xff\"\n")
    res = CliRunner().invoke(cli, ["sim", "run", "--scene", str(bad), "--duration", "0.1", "--time-scale", "0"])
    assert res.exit_code == 1
    assert "Traceback" not in res.output
    assert res.output == f"Error: {bad}:2: not UTF-8: byte 0xff at column 9; TOML files must be UTF-8\n"


def test_a_scene_and_a_protocol_word_the_same_problem_alike(tmp_path):
    """One reader for every TOML file (sim/tomltable.py): the same mistake reads the same in a
    scene and in a protocol (issue 45: the protocol's own checker worded its ranges and types
    differently)."""
    from studyctl.protocol import check_protocol
    from tests.helpers import PROTOCOL

    path, text = _write_scene(tmp_path, _scene_text(**{"rate_hz = 1000": 'rate_hz = "fast"', "poisson = 0.45": "poisson = 0.7"}))
    scene = _problems(path)
    assert f"{path}:{_line_of(text, 'rate_hz')}: servo.rate_hz: 'fast' is not a finite number" in scene
    assert f"{path}:{_line_of(text, 'poisson = 0.7')}: material.poisson: 0.7 is out of range; allowed: [0, 0.5)" in scene
    protocol = PROTOCOL.read_text().replace("trial_seconds = 3.0", 'trial_seconds = "fast"').replace("training_minutes = 5.0",
                                                                                                     "training_minutes = 500.0")
    _, problems = check_protocol(PROTOCOL, protocol)
    where = f"{PROTOCOL}:"
    assert f"{where}{_line_of(protocol, 'trial_seconds')}: design.trial_seconds: 'fast' is not a finite number" in problems
    assert f"{where}{_line_of(protocol, 'training_minutes')}: design.training_minutes: 500.0 is out of range; allowed: [0, 120]" in problems
