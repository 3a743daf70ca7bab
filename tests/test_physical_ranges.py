"""Scenes at the edge (docs/scenes.md, "Physical ranges"): every physical value of a scene, its
material, its models and its hands has a stated range, and a value outside it is refused when
the scene is read (`protocol validate`, `sim run`, a condition on top of the scene), naming the
file, the field and the range, before a mesh is searched or a stiffness factorised with it."""

import dataclasses
import hashlib
import math
import re
import warnings

import pytest

from sim.errors import SceneError
from sim.models.api import option_kind
from sim.models.registry import model_class
from sim.scene import load_scene
from tests.conftest import ROOT
from tests.helpers import fast_protocol, localise, studyctl

SCENE = ROOT / "protocols/scenes/brain_pull.toml"


def _scene(tmp_path, old: str, new: str, name="scene.toml"):
    text = localise(SCENE.read_text()).replace('kind = "offscreen"', 'kind = "none"')
    assert old in text, old
    path = tmp_path / name
    path.write_text(text.replace(old, new, 1))
    return path


def _problems(path) -> list[str]:
    with pytest.raises(SceneError) as exc:
        load_scene(path)
    return exc.value.problems


def _hash(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


HUGE = [  # (old, new, field, range said): the largest double a unit slip or a typo can give
    ("density = 1040.0", "density = 1040.0\nyoung = 1e308", "material.young", "1e+308 is out of range; allowed: [1, 1e+09] Pa"),
    ("density = 1040.0", "density = 1e308", "material.density", "1e+308 is out of range; allowed: [100, 20000] kg/m3"),
    ("from_bottom = 0.08", "from_bottom = 1e300", "fixed.from_bottom", "1e+300 is out of range; allowed: [0, 1] m"),
    ("duration = 3.0", "duration = 1e300", "scene.duration", "1e+300 is out of range; allowed: (0, 3600] s"),
    ("start = [-0.0313, -0.0186, 0.0723]", "start = [1e300, 0.0, 0.0]", "hands[0].start",
     "[1e+300, 0.0, 0.0] is out of range; allowed: each in [-1, 1] m"),
    ("pull = [-1.0, 0.0, 0.0]", "pull = [-1e300, 1e300, 0.0]", "hands[0].pull", "[-1e+300, 1e+300, 0.0] is out of range; allowed: each in [-1000, 1000]"),
    ("pull = [-1.0, 0.0, 0.0]", "pull = [0.0, 0.0, 0.0]", "hands[0].pull", "[0.0, 0.0, 0.0] is not a direction; allowed: three numbers, not all 0"),
    ('device = "simulated"\nstart = [-0.0313', 'device = "simulated"\ndevice_origin = [0.0, 1e300, 0.0]\nstart = [-0.0313',
     "hands[0].device_origin", "[0.0, 1e+300, 0.0] is out of range; allowed: each in [-1, 1] m"),
    ("grasp_at = 0.3\npull_start = 0.5\npull_time = 1.2\nrelease_at = 2.6\n", "grasp_at = 1e300\n", "hands[0].grasp_at",
     "1e+300 is out of range; allowed: [0, 3600] s"),
    ("pull_time = 1.2", "pull_time = 1e300", "hands[0].pull_time", "1e+300 is out of range; allowed: (0, 3600] s"),
    ("release_at = 2.6", "release_at = 1e300", "hands[0].release_at", "1e+300 is out of range; allowed: (0.3, 3600] s"),
    ("[servo]", "[view]\nfront = [1e300, 0.0, 0.0]\n\n[servo]", "view.front", "[1e+300, 0.0, 0.0] is out of range; allowed: each in [-1000, 1000]"),
    ("dt = 0.033333", "dt = 1e300", "models.mass_spring.dt", "1e+300 is out of range; allowed: [1e-05, 0.05]"),
    ("damping = 5.0", "damping = 1e300", "models.mass_spring.damping", "1e+300 is out of range; allowed: [0, 10000]"),
    ("coupling = 300.0", "coupling = 1e300", "models.mass_spring.coupling", "1e+300 is out of range; allowed: (0, 700]"),
]


@pytest.mark.parametrize("old, new, field, said", HUGE, ids=[h[2] + ":" + h[1].split("=")[-1].strip()[:12] for h in HUGE])
def test_a_value_beyond_its_physical_range_is_refused_naming_the_field_and_the_range(tmp_path, old, new, field, said):
    path = _scene(tmp_path, old, new)
    problems = _problems(path)
    assert len(problems) == 1, problems
    assert re.fullmatch(rf"{re.escape(str(path))}:\d+: {re.escape(field)}: {re.escape(said)}", problems[0]), problems[0]


PLATE = [  # the plate-spring's parameter file, inline: (key, value, what is said)
    ("E", "1e300", "E: 1e+300 is out of range; allowed: (0, 1e+12] Pa"),
    ("h1", "1e300", "h1: 1e+300 is out of range; allowed: (0, 0.1] m"),
    ("x_c1", "5.0", "x_c1: 5.0 is out of range; allowed: (0, 0.1] m"),
    ("t1", "1e300", "t1: 1e+300 is out of range; allowed: (0, 1] s"),
    ("omega", "1e300", "omega: 1e+300 is out of range; allowed: (0, 10]"),
    ("delta", "1e300", "delta: 1e+300 is out of range; allowed: (0, 1000]"),
    ("layers", "1000000000000", "layers: 1000000000000 is out of range; allowed: an integer in 1..1000"),
]


@pytest.mark.parametrize("key, value, said", PLATE, ids=[p[0] for p in PLATE])
def test_a_plate_spring_parameter_beyond_its_range_is_refused_naming_its_file_and_line(tmp_path, key, value, said):
    params = (ROOT / "protocols/models/plate_spring_brain.toml").read_text()
    bad = tmp_path / "params.toml"
    bad.write_text(re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", params))
    path = _scene(tmp_path, f'params = "{ROOT}/protocols/models/plate_spring_brain.toml"', f'params = "{bad}"')
    problems = _problems(path)
    assert len(problems) == 1, problems
    assert re.fullmatch(rf"{re.escape(str(bad))}:\d+: {re.escape(said)}", problems[0]), problems[0]


def test_every_number_option_of_the_built_in_models_has_a_finite_range():
    for name in ("plate_spring", "fem", "mass_spring"):
        for f in dataclasses.fields(model_class(name).Options):
            if option_kind(f) in ("number", "integer"):
                lo, hi = f.metadata.get("lo"), f.metadata.get("hi")
                assert lo is not None and hi is not None and math.isfinite(lo) and math.isfinite(hi), (name, f.name)


def test_the_shipped_scenes_lie_within_every_range():
    for scene in sorted((ROOT / "protocols/scenes").glob("*.toml")):
        assert load_scene(scene).material.young >= 1.0, scene


def test_a_tiny_young_in_a_fem_scene_is_refused_by_sim_run_before_any_factorisation(tmp_path):
    """Before, young = 1e-300 reached the FEM's factorisation and hung there (300 s, nothing said)."""
    path = _scene(tmp_path, "density = 1040.0", "density = 1040.0\nyoung = 1e-300")
    before = _hash(path)
    res = studyctl("sim", "run", "--scene", path, "--model", "fem", "--time-scale", "0", "--duration", "0.2")
    assert res.exit_code == 1
    assert re.fullmatch(rf"Error: {re.escape(str(path))}:\d+: material\.young: 1e-300 is out of range; allowed: \[1, 1e\+09\] Pa\n",
                        res.output), res.output
    assert _hash(path) == before


def test_a_huge_young_is_refused_by_protocol_validate_without_runtime_warnings(tmp_path):
    proto = fast_protocol(tmp_path, conditions=("fem",), trials=1)
    scene = tmp_path / "scene.toml"
    scene.write_text(scene.read_text().replace("density = 1040.0", "density = 1040.0\nyoung = 1e308", 1))
    before = _hash(scene), _hash(proto)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        res = studyctl("protocol", "validate", proto)
    assert [w for w in seen if issubclass(w.category, RuntimeWarning)] == []
    assert res.exit_code == 1
    assert re.search(rf"{re.escape(str(scene))}:\d+: material\.young: 1e\+308 is out of range; allowed: \[1, 1e\+09\] Pa", res.output), res.output
    assert "RuntimeWarning" not in res.output
    assert (_hash(scene), _hash(proto)) == before


def test_a_condition_young_beyond_the_range_is_refused_naming_the_protocol(tmp_path):
    proto = fast_protocol(tmp_path, conditions=("plate_spring", "stiff_fem"), trials=1)
    proto.write_text(proto.read_text() + '\n[conditions.stiff_fem]\nmodel = "fem"\nyoung = 1e-300\n')
    before = _hash(proto)
    res = studyctl("protocol", "validate", proto)
    assert res.exit_code == 1
    assert re.search(rf"{re.escape(str(proto))}:\d+: conditions\.stiff_fem\.young: 1e-300 is out of range; allowed: \[1, 1e\+09\] Pa",
                     res.output), res.output
    assert _hash(proto) == before


def test_a_hand_starting_at_1e300_is_refused_by_sim_run_without_an_index_error(tmp_path):
    path = _scene(tmp_path, "start = [-0.0313, -0.0186, 0.0723]", "start = [1e300, 0.0, 0.0]")
    res = studyctl("sim", "run", "--scene", path, "--time-scale", "0", "--duration", "0.2")
    assert res.exit_code == 1
    assert "IndexError" not in res.output
    assert re.fullmatch(rf"Error: {re.escape(str(path))}:\d+: hands\[0\]\.start: \[1e\+300, 0\.0, 0\.0\] is out of range; "
                        r"allowed: each in \[-1, 1\] m\n", res.output), res.output


def test_a_law_of_a_vanishing_modulus_is_refused_before_the_fem_factorises_it(tmp_path):
    """mu = 1e-300 is within the law's own bounds (a term >= 0 Pa, their sum > 0): the linear
    models' young, 2 mu (1 + poisson), would be 2.9e-300 Pa and hang the factorisation."""
    path = _scene(tmp_path, f'file = "{ROOT}/protocols/materials/human_cortex.toml"', 'law = "neo-hookean"\nmu = 1e-300')
    res = studyctl("sim", "run", "--scene", path, "--model", "fem", "--time-scale", "0", "--duration", "0.2")
    assert res.exit_code == 1
    assert re.fullmatch(rf"Error: {re.escape(str(path))}:\d+: material\.mu: the law's small-strain Young's modulus 2 mu \(1 \+ poisson\) "
                        r"= 2\.9e-300 Pa is out of range; allowed: \[1, 1e\+09\] Pa \(a shear modulus mu in \[0\.345, 3\.45e\+08\] Pa\)\n",
                        res.output), res.output


def test_a_material_file_of_a_vanishing_modulus_is_refused_naming_the_scene_key(tmp_path):
    material = tmp_path / "soft.toml"
    material.write_text('[material]\nlaw = "ogden"\nmu = [1e-300]\nalpha = [-20.0]\n')
    path = _scene(tmp_path, f'file = "{ROOT}/protocols/materials/human_cortex.toml"', f'file = "{material}"')
    problems = _problems(path)
    assert len(problems) == 1, problems
    assert re.fullmatch(rf"{re.escape(str(path))}:\d+: material\.file: the law's small-strain Young's modulus .* = 2\.9e-300 Pa is out of range; "
                        r"allowed: \[1, 1e\+09\] Pa .*", problems[0]), problems[0]


def test_a_law_within_range_with_its_young_given_still_loads(tmp_path):
    path = _scene(tmp_path, "density = 1040.0", "density = 1040.0\nyoung = 6000.0")
    assert load_scene(path).material.young == 6000.0
