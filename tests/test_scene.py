"""Scene files: validation, and building only what a scene asks for."""

import json
import subprocess
import sys
import textwrap

import pytest

from sim.errors import SceneError
from sim.scene import load_scene
from tests.conftest import ROOT, SCENE


def test_shipped_scene(root):
    s = load_scene(SCENE)
    assert s.model == "plate_spring" and len(s.hands) == 2
    assert s.mesh_path == root / "data" / "brain_fsaverage5.npz"
    assert s.material.young == 3000.0 and 0.45 <= s.material.poisson <= 0.49
    assert s.renderer.kind == "offscreen" and s.servo_rate_hz == 1000.0


def _localise(text: str) -> str:
    """Make the shipped scene's relative paths absolute, so a copy works from tmp_path."""
    return text.replace('"../../data/', f'"{ROOT}/data/').replace('"../models/', f'"{ROOT}/protocols/models/')


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
        ("young = 3000.0", "young = -3.0", r"material.young: -3.0 is out of range; allowed: \(0, inf\]"),
        ("poisson = 0.45", "poisson = 0.7", r"material.poisson: 0.7 is out of range; allowed: \[0, 0.5\]"),
        ('name = "plate_spring"', 'name = "rubber"', r"model.name: 'rubber' has no \[models.rubber\] section"),
        ("[models.plate_spring]", "[models.rubber]", r"models.rubber.: unknown model 'rubber'"),
        ("distance = 0.012\ngrasp_at = 0.3\npull_start = 0.5\npull_time = 1.2\nrelease_at = 2.6\n\n[[hands]]",
         'distance = "far"\ngrasp_at = 0.3\npull_start = 0.5\npull_time = 1.2\nrelease_at = 2.6\n\n[[hands]]',
         r"hands\[0\].distance: 'far' is not a finite number"),
        ("[fixed]", "[fixd]", r"fixed: missing section"),
        ('device = "simulated"', 'device = "phantom"', r"device: 'phantom' is not one of simulated"),
        ("rate_hz = 1000", "rate_hz = 1000 =", r"invalid TOML"),
        ("x_c1", "x_c1", r""),
    ],
)
def test_broken_scenes(tmp_path, old, new, message):
    if old == "x_c1":  # plate-spring parameter errors surface with the parameter file's name
        params = tmp_path / "p.toml"
        params.write_text((ROOT / "protocols/models/plate_spring_handset.toml").read_text().replace("alpha = 1.25", "alpha = 3.0"))
        text = _scene_text(**{'"../models/plate_spring_brain.toml"': f'"{params}"'})
        message = r"p.toml: alpha: 3.0 is out of range; allowed: \[1, 2\]"
    else:
        text = _scene_text(**{old: new})
    text = _localise(text)
    path = tmp_path / "scene.toml"
    path.write_text(text)
    with pytest.raises(Exception) as exc:
        load_scene(path)
    from sim.errors import SimError

    assert isinstance(exc.value, SimError)
    import re

    assert re.search(message, str(exc.value)), str(exc.value)
    assert "\n" not in str(exc.value)


def test_three_hands_refused(tmp_path):
    text = _localise(SCENE.read_text())
    block = text[text.index("[[hands]]"):]
    path = tmp_path / "s.toml"
    path.write_text(text + "\n" + block.replace('name = "left"', 'name = "third"'))
    with pytest.raises(SceneError, match="one or two"):
        load_scene(path)


def _run_python(code: str) -> dict:
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, cwd=ROOT, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_headless_plate_spring_scene_never_imports_open3d_or_other_models(tmp_path):
    # the FEM module is never imported, so no stiffness matrix is ever assembled
    scene = tmp_path / "headless.toml"
    scene.write_text(_localise(SCENE.read_text().replace('kind = "offscreen"', 'kind = "none"')))
    got = _run_python(f"""
        import json, sys
        from sim.scene import build_scene
        from sim.run import run_scene
        from sim.models import MODELS
        scene = build_scene({str(scene)!r})
        result = run_scene(scene, duration=0.5, time_scale=0)
        print(json.dumps({{
            "open3d": sorted(m for m in sys.modules if m.startswith("open3d"))[:3],
            "render": "sim.render" in sys.modules,
            "models": sorted(m for m in MODELS.values() if m in sys.modules),
            "ticks": len(result.times),
        }}))
    """)
    assert got == {"open3d": [], "render": False, "models": ["sim.models.plate_spring"], "ticks": 500}


def test_one_hand_scene_opens_one_device(tmp_path):
    text = _localise(SCENE.read_text())
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
    text = _localise(SCENE.read_text().replace('kind = "offscreen"', 'kind = "none"'))
    scene.write_text(text.replace('name = "plate_spring"               #', 'name = "fem"  #').replace("resolution = 0.004", "resolution = 0.008"))
    got = _run_python(f"""
        import json, sys
        from sim.scene import build_scene
        from sim.run import run_scene
        scene = build_scene({str(scene)!r})
        result = run_scene(scene, duration=0.3, time_scale=0)
        import sim.models.fem as fem
        print(json.dumps({{"open3d": any(m.startswith("open3d") for m in sys.modules), "assemblies": fem.ASSEMBLIES,
                          "render": "sim.render" in sys.modules}}))
    """)
    assert got == {"open3d": False, "assemblies": 2, "render": False}
