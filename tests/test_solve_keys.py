"""The shipped reference solves are found on any machine: a solve's key is a hash of its inputs,
each number written canonically (analysis.verification.tissue_pulls.key_number), and every
shipped key is rebuilt here from inputs computed on this machine, as the benches compute them."""

import dataclasses
import json

import pytest

from analysis.verification import tissue_pulls
from analysis.verification.truth_band import scene_contrast, scene_ensemble, scene_pac_spread, shapes
from sim import pulls as pull_sets
from sim.pulls import scene_with
from sim.scene import DEFAULT_SCENE


@pytest.mark.parametrize("x", [6.938893903907228e-18, -6.938893903907228e-18, 0.0, -0.0])
def test_a_zero_and_what_rounds_to_it_give_one_key_number(x):
    assert json.dumps(tissue_pulls.key_number(x)) == "0.0"


@pytest.mark.parametrize("x", [0.0, -0.0])
def test_a_law_parameter_at_zero_is_written_one_way(x):
    assert json.dumps(tissue_pulls.key_digits(x)) == "0.0"


def test_a_direction_with_a_signed_zero_gives_the_same_key():
    """test9-across's y component: +6.9e-18 on one machine, -0.0 on another."""
    scene = scene_with(DEFAULT_SCENE)
    pull = next(p for p in pull_sets.test_pulls(scene) if p.name == "test9-across")
    keys = set()
    for y in (6.938893903907228e-18, -6.938893903907228e-18, 0.0, -0.0):
        moved = dataclasses.replace(pull, direction=(pull.direction[0], y, pull.direction[2]))
        keys.add(json.dumps(tissue_pulls.pull_key_inputs("mesh", scene, scene.spec.material.law, 0.005, moved)))
    assert len(keys) == 1


def test_every_shipped_key_is_rebuilt_from_its_inputs_on_this_machine():
    """Each shipped entry's key from its pull (the scene's geometry, `make_pulls` and
    `test_pulls`), its shipped mesh and its law (the truth's ensemble, `scene_ensemble`), as the
    benches and the truth compute them: every one is found among the shipped solves."""
    scene = scene_with(DEFAULT_SCENE)
    pulls = {p.name: p for p in pull_sets.make_pulls(scene) + pull_sets.test_pulls(scene)}
    laws = (shapes(scene_ensemble(scene)) + [c["law"] for c in scene_contrast(scene)]  # fitted here, not read from the record
            + [m["law"] for m in scene_pac_spread(scene)])
    info = json.loads(tissue_pulls.SHIPPED_PULLS_INFO.read_text())
    shipped = set(tissue_pulls.shipped_solves())
    keys = tissue_pulls.entry_keys(info["entries"], scene, laws, pulls)
    missing = [(e["pull"], e["size_mm"], e["shape"]) for e, key in zip(info["entries"], keys)
               if key != e["key"] or (key not in shipped and e.get("reached_mm", 0.0) > 0)]
    assert len(info["entries"]) == 378
    assert missing == []
