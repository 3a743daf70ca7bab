"""What the parent (sim/servo/process.py) and the servo process (sim/servo/child.py) send each
other over their pipe, the device recipes the servo process opens its devices from, and a run's
result.

Every class is a module-level dataclass, so it pickles under the "spawn" start method. The
spawned interpreter imports this module, so it imports nothing at run time beyond the standard
library; the names below TYPE_CHECKING are for the annotations only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

    from sim.devices.base import DeviceFrame
    from sim.devices.simulated import PullScript
    from sim.laws import PairTable
    from sim.servo.loop import Event

# -- device recipes: picklable descriptions of a scene's devices, opened in the servo process --


@dataclass(frozen=True, slots=True)
class SimulatedRecipe:
    script: PullScript  # the scripted operator; played from its start each run
    name: str


@dataclass(frozen=True, slots=True)
class ReplayRecipe:
    trace: str  # the recorded trace's path
    trace_hand: str  # the hand in the trace to play back


@dataclass(frozen=True, slots=True)
class MouseRecipe:
    hand: int  # its slots on the board, where the parent writes the pointer's target
    name: str
    start: tuple[float, float, float]  # where it rests until the pointer moves it


@dataclass(frozen=True, slots=True)
class OpenHapticsRecipe:
    name: str  # the HD device's name
    frame: DeviceFrame | None
    rig_index: int  # its index in the servo process's one rig
    library: str | None  # the HD library's path (None: the default)


DeviceRecipe = SimulatedRecipe | ReplayRecipe | MouseRecipe | OpenHapticsRecipe

# -- parent to servo ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class PairLaw:
    """Two held hands whose forces come from one table (they pull on the same tissue)."""

    a: int
    b: int
    table: PairTable


@dataclass(frozen=True, slots=True)
class NewContact:
    """A new grasp: its anchor point and force law; `t` is the grasp's time on the run's clock."""

    hand: int
    point: tuple
    law: object
    t: float


@dataclass(frozen=True, slots=True)
class LawUpdate:
    """The held contacts' laws after a visual step (by hand index)."""

    laws: dict
    pair: PairLaw | None
    unstable: bool


@dataclass(frozen=True, slots=True)
class Pulse:
    """The device check: a constant `force` (N) on `hand` for `seconds`."""

    hand: int
    force: tuple
    seconds: float


@dataclass(frozen=True, slots=True)
class BeginRun:
    """A new run of `n_ticks`; with `wait` its clock starts at a grasp or a key, not at once."""

    seq: int
    n_ticks: int
    wait: bool
    recipes: tuple[DeviceRecipe, ...]
    timed: bool = False  # the run's model uses time (sim.models.api, `uses_time`)


@dataclass(frozen=True, slots=True)
class StartClock:
    """The experimenter's start key: a waiting run's clock starts."""


@dataclass(frozen=True, slots=True)
class StopRun:
    """End the run now; its log comes back as `RunDone`."""


@dataclass(frozen=True, slots=True)
class Close:
    """End the run, if any, and the servo process."""


ToServo = NewContact | LawUpdate | Pulse | BeginRun | StartClock | StopRun | Close

# -- servo to parent ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RunLog:
    """A finished run's servo log: one row per tick, the servo's events, each tick's start
    (perf_counter), missed deadlines, wall time, what started its clock and after how long, and
    what paced the ticks ("process" or "hd-scheduler"; None: the run never came back)."""

    rows: np.ndarray
    events: tuple[Event, ...]
    starts: np.ndarray
    misses: int
    wall: float
    started_by: str | None
    waited_s: float
    pacer: str | None


@dataclass(frozen=True, slots=True)
class Ready:
    """The devices are open; `priority` is the scheduling the OS granted."""

    priority: str


@dataclass(frozen=True, slots=True)
class StartFailed:
    """The devices could not be opened."""

    reason: str


@dataclass(frozen=True, slots=True)
class RunDone:
    result: RunLog


@dataclass(frozen=True, slots=True)
class Notice:
    """A device's word for the experimenter (calibration, warm motors)."""

    text: str


FromServo = Ready | StartFailed | RunDone | Notice

__all__ = [
    "BeginRun",
    "Close",
    "DeviceRecipe",
    "FromServo",
    "LawUpdate",
    "MouseRecipe",
    "NewContact",
    "Notice",
    "OpenHapticsRecipe",
    "PairLaw",
    "Pulse",
    "Ready",
    "ReplayRecipe",
    "RunDone",
    "RunLog",
    "SimulatedRecipe",
    "StartClock",
    "StartFailed",
    "StopRun",
    "ToServo",
]
