"""The compiled lockstep ticks (sim/lockstep.py) give the Python tick's trace to the bit."""

import dataclasses

import numpy as np
import pytest

import sim.lockstep as lockstep
from sim.run import run_scene
from sim.scene import Scene, load_scene
from tests.conftest import ROOT

SCENE = ROOT / "protocols" / "scenes" / "brain_pull.toml"


def _operators(scene, **changes):
    """The scene's scripted hands with a synthetic operator's extras (tremor, a corrective
    movement back, restraint near a safe force), different per hand."""
    out = []
    for i in range(len(scene.spec.hands)):
        s = scene.spec.hands[i].script(scene.mesh)
        extra = {"tremor_m": 4e-5 * (i + 1), "tremor_hz": 9.0 + i, "tremor_phase": (0.3, 1.1 + i, 2.0),
                 "back": tuple(-0.15 * c for c in s.pull), "back_start": s.pull_start + s.pull_time + 0.1, "back_time": 0.4,
                 "restraint": 0.5 * i, "safe_force": 0.4}
        out.append(dataclasses.replace(s, **{**extra, **changes}))
    return out


def _trace(scene, enabled: bool, monkeypatch):
    counted = {"compiled": 0}
    kernel = lockstep._ticks

    def counting(*args):
        done = kernel(*args)
        counted["compiled"] += done
        return done

    monkeypatch.setattr(lockstep, "ENABLED", enabled)
    monkeypatch.setattr(lockstep, "_ticks", counting)
    r = run_scene(scene, duration=3.0, time_scale=0)
    return r, counted["compiled"]


def _same(a, b):
    assert a.forces.tobytes() == b.forces.tobytes()
    assert a.positions.tobytes() == b.positions.tobytes()
    assert np.array_equal(a.buttons, b.buttons) and np.array_equal(a.times, b.times)
    assert [(e.t, e.hand, e.kind, e.detail) for e in a.events] == [(e.t, e.hand, e.kind, e.detail) for e in b.events]


@pytest.mark.parametrize("model", ["plate_spring", "mass_spring", "fem"])
def test_compiled_ticks_give_the_python_ticks_trace_to_the_bit(model, monkeypatch):
    scene = Scene(load_scene(SCENE), model=model)
    scene.operators = _operators(scene)
    python, none = _trace(scene, False, monkeypatch)
    compiled, ran = _trace(scene, True, monkeypatch)
    assert none == 0
    assert ran > 0.9 * len(compiled.times)  # most ticks are quiet: they ran compiled
    _same(python, compiled)
    assert np.abs(compiled.forces).max() > 0.1  # the hands felt the tissue


def test_ticks_where_safety_rules_act_run_in_python_and_match(monkeypatch):
    """A tissue 40 times stiffer: the force is clamped at the device's peak and the continuous
    budget holds it (events), and a hand slips (a glitch): those ticks are the Python tick's."""
    base = Scene(load_scene(SCENE), model="plate_spring")
    scene = base.with_stiffness(40.0)
    scene.operators = _operators(base)
    python, _ = _trace(scene, False, monkeypatch)
    compiled, ran = _trace(scene, True, monkeypatch)
    kinds = {e.kind for e in compiled.events}
    assert "force_clamped" in kinds and 0 < ran < len(compiled.times)
    _same(python, compiled)
    scene.operators = _operators(base, jump_at=1.0, jump=(0.03, 0.0, 0.0), glitch=True)
    python, _ = _trace(scene, False, monkeypatch)
    compiled, ran = _trace(scene, True, monkeypatch)
    assert ran == 0 and "position_jump" in {e.kind for e in compiled.events}  # a scripted glitch: every tick in Python
    _same(python, compiled)
