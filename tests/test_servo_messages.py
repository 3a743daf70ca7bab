"""The servo process's typed messages, device recipes and run log (sim/servo/messages.py)."""

import dataclasses
import pickle
import subprocess
import sys

import numpy as np
import pytest

from sim.laws import Constant, PairTable
from sim.servo.child import LawModel, RemoteContact
from sim.servo.loop import Event
from sim.servo.messages import (
    BeginRun,
    Close,
    LawUpdate,
    MouseRecipe,
    NewContact,
    Notice,
    OpenHapticsRecipe,
    PairLaw,
    Pulse,
    Ready,
    ReplayRecipe,
    RunDone,
    RunLog,
    SimulatedRecipe,
    StartClock,
    StartFailed,
    StopRun,
)
from tests.conftest import ROOT, SCENE


def _log(**changes) -> RunLog:
    fields = dict(rows=np.zeros((2, 17)), events=(Event(0.5, 1, "grasp", "grasp 12"),), starts=np.arange(2.0), misses=1,
                  wall=0.25, started_by="grasp", waited_s=0.1, pacer="process")
    return RunLog(**(fields | changes))


def _messages():
    pair = PairLaw(0, 1, PairTable(K=[0.0] * 36))
    recipes = (ReplayRecipe(trace="t.csv", trace_hand="left"), MouseRecipe(hand=1, name="right (mouse)", start=(0.0, 0.1, 0.0)),
               OpenHapticsRecipe(name="Left Device", frame=None, rig_index=0, library=None))
    return [NewContact(hand=0, point=(0.0, 0.0, 0.0), law=Constant((1.0, 0.0, 0.0)), t=0.5),
            LawUpdate(laws={0: Constant((0.0, 1.0, 0.0))}, pair=pair, unstable=False), Pulse(hand=1, force=(0.0, 0.5, 0.0), seconds=0.3),
            BeginRun(seq=2, n_ticks=1000, wait=True, recipes=recipes), StartClock(), StopRun(), Close(), Ready("nice -5"),
            StartFailed("no device"), Notice("Left Device: calibrated"), *recipes, pair]


@pytest.mark.parametrize("msg", _messages(), ids=lambda m: type(m).__name__)
def test_a_message_pickles_whole_and_is_frozen_with_slots(msg):
    assert pickle.loads(pickle.dumps(msg)) == msg
    assert not hasattr(msg, "__dict__")  # slots
    name = dataclasses.fields(msg)[0].name if dataclasses.fields(msg) else "anything"
    with pytest.raises((dataclasses.FrozenInstanceError, AttributeError, TypeError)):
        setattr(msg, name, None)


def test_the_run_log_pickles_inside_its_message_and_is_frozen():
    back = pickle.loads(pickle.dumps(RunDone(_log()))).result
    assert np.array_equal(back.rows, np.zeros((2, 17)))
    assert np.array_equal(back.starts, [0.0, 1.0])
    assert back.events == (Event(0.5, 1, "grasp", "grasp 12"),)
    assert (back.misses, back.wall, back.started_by) == (1, 0.25, "grasp")
    assert (back.waited_s, back.pacer) == (0.1, "process")
    with pytest.raises(dataclasses.FrozenInstanceError):
        back.misses = 2


def test_the_messages_module_loads_only_the_standard_library():
    # the spawned servo process imports it: nothing heavy, no numpy, no other sim module
    code = "import sys; import sim.servo.messages; print(' '.join(sorted(sys.modules)))"
    loaded = set(subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split())
    assert "numpy" not in loaded  # the package: a docstring
    assert {m for m in loaded if m.startswith("sim")} == {"sim", "sim.servo", "sim.servo.messages"}


def test_the_servo_process_imports_no_heavy_modules():
    code = "import sys; import sim.servo.child; print(' '.join(sorted(sys.modules)))"
    loaded = set(subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split())
    for heavy in ("scipy", "open3d", "matplotlib", "numba", "sim.models.api", "sim.run", "sim.scene", "sim.servo.process"):
        assert heavy not in loaded, heavy


def test_device_recipes_name_their_fields():
    from sim.scene import build_scene
    from sim.servo.process import device_recipes

    scene = build_scene(SCENE)
    names = [h.name for h in scene.spec.hands]
    recipes = device_recipes(scene)
    assert all(isinstance(r, SimulatedRecipe) for r in recipes)
    assert [r.name for r in recipes] == [f"{n} (simulated)" for n in names]
    assert recipes[1].script == scene.script(1)
    mouse = device_recipes(scene.with_device("mouse"))
    assert mouse == tuple(MouseRecipe(hand=i, name=f"{n} (mouse)", start=scene.script(i).start) for i, n in enumerate(names))
    real = device_recipes(scene.with_device("openhaptics"), library="libHD.so")
    assert [(r.name, r.rig_index, r.library) for r in real] == [(scene.device_name(i), i, "libHD.so") for i in range(len(names))]
    assert all(isinstance(r, OpenHapticsRecipe) and r.frame is not None for r in real)


class _Table:
    def forces(self, d1, d2):
        return [("pair", d1), ("pair", d2)]


def test_the_servo_model_uses_a_pair_table_only_for_its_two_hands():
    model = LawModel()
    contacts = [RemoteContact(0, (0.0, 0.0, 0.0), Constant((1.0, 0.0, 0.0))), RemoteContact(1, (0.0, 0.0, 0.0), Constant((2.0, 0.0, 0.0)))]
    assert model.forces(contacts, [(0.1, 0, 0), (0.2, 0, 0)]) == [(1.0, 0.0, 0.0), (2.0, 0.0, 0.0)]
    model.pair = PairLaw(0, 1, _Table())
    assert model.forces(contacts, ["d1", "d2"]) == [("pair", "d1"), ("pair", "d2")]
    model.pair = PairLaw(1, 0, _Table())  # another order of hands: each its own law
    assert model.forces(contacts, ["d1", "d2"]) == [(1.0, 0.0, 0.0), (2.0, 0.0, 0.0)]


def test_a_servo_process_serves_typed_runs_started_by_clock_key_or_stopped():
    from sim.run import VisualStep
    from sim.scene import build_scene
    from sim.servo.process import ServoProcess

    scene = build_scene(SCENE)
    rate = scene.spec.servo_rate_hz

    def visual():
        scene.model.reset()
        return VisualStep(model=scene.model, hands=[], events=[])

    with ServoProcess(scene) as sp:
        assert sp.priority in ("SCHED_FIFO", "nice -5", "default")
        out, _ = sp.run(scene, visual(), 200, scene.spec.visual_rate_hz)
        assert isinstance(out, RunLog)
        assert (out.started_by, out.pacer, out.waited_s) == ("clock", "process", 0.0)
        assert len(out.rows) == 200
        assert len(out.starts) == 200
        assert isinstance(out.events, tuple)
        out, _ = sp.run(scene, visual(), 100, scene.spec.visual_rate_hz, frame=lambda sp_, v: "start", wait=True)
        assert out.started_by == "key"
        assert len(out.rows) == 100
        assert out.waited_s >= 0.0
        stopped, _ = sp.run(scene, visual(), int(100 * rate), scene.spec.visual_rate_hz, frame=lambda sp_, v: "stop", wait=True)
        assert stopped.started_by is None
        assert len(stopped.rows) == 0
        assert len(stopped.starts) == 0
        assert stopped.events == ()
