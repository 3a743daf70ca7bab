"""Replay: positions and button states recorded in a run (its trace.csv), played back.

A hand with ``device = "replay"`` and ``trace = "path/to/trace.csv"`` follows the recorded
hand of the same name (or ``trace_hand``): the sample at or before each time is returned, as
the recording device would have reported it. Forces written to it are recorded, not applied
(a recording cannot be pushed back).
"""

from __future__ import annotations

import bisect
import csv
import math
from pathlib import Path

import numpy as np

from sim.devices.base import DeviceState, OmniSpec
from sim.errors import DeviceError


def read_trace(path: str | Path, hand: str) -> tuple[list[float], list[tuple], list[bool]]:
    path = Path(path)
    if path.suffix == ".npz":
        return _read_npz(path, hand)
    times, positions, buttons = [], [], []
    try:
        with open(path, newline="") as fh:
            reader = csv.DictReader(fh)
            missing = {"t_s", "hand", "x_m", "y_m", "z_m", "button"} - set(reader.fieldnames or [])
            if missing:
                raise DeviceError(f"{path}: not a trace: missing column {sorted(missing)[0]!r}")
            for line, row in enumerate(reader, start=2):
                if row["hand"] != hand:
                    continue
                try:
                    t = float(row["t_s"])
                    p = (float(row["x_m"]), float(row["y_m"]), float(row["z_m"]))
                    b = row["button"].strip() in ("1", "true", "True")
                except ValueError:
                    raise DeviceError(f"{path}: line {line}: not a number") from None
                if times and t < times[-1]:
                    raise DeviceError(f"{path}: line {line}: t_s goes backwards")
                times.append(t)
                positions.append(p)
                buttons.append(b)
    except OSError as exc:
        raise DeviceError(f"{path}: cannot read: {exc.strerror}") from None
    if not times:
        raise DeviceError(f"{path}: no samples for hand {hand!r}")
    return times, positions, buttons


def _read_npz(path: Path, hand: str):
    """A trial trace stored by a study session (studyctl/session/traces.py)."""
    try:
        z = np.load(path, allow_pickle=False)
        names = [str(n) for n in z["hand_names"]]
        times, positions, buttons = z["times"], z["positions"], z["buttons"]
    except (OSError, KeyError, ValueError) as exc:
        raise DeviceError(f"{path}: not a trial trace: {exc}") from None
    if hand not in names:
        raise DeviceError(f"{path}: no hand {hand!r}; recorded: {', '.join(names)}")
    i = names.index(hand)
    if len(times) == 0:
        raise DeviceError(f"{path}: no samples for hand {hand!r}")
    return times.tolist(), [tuple(p) for p in positions[:, i].tolist()], buttons[:, i].tolist()


class ReplayDevice:
    def __init__(self, path, hand: str, name: str | None = None, spec: OmniSpec = OmniSpec()):
        self.spec = spec
        self.name = name or f"{hand} (replay)"
        self.times, self.positions, self.buttons = read_trace(path, hand)
        self.forces: list[tuple] = []

    def read(self, t: float) -> DeviceState:
        k = max(bisect.bisect_right(self.times, t + 1e-9) - 1, 0)
        return DeviceState(position=self.positions[k], button=self.buttons[k] and t <= self.times[-1])

    def write_force(self, force) -> None:
        fx, fy, fz = force
        self.forces.append((fx, fy, fz) if math.isfinite(fx + fy + fz) else (0.0, 0.0, 0.0))

    def close(self) -> None:
        pass


def open_devices(hands, mesh) -> list[ReplayDevice]:
    out = []
    for h in hands:
        if not h.trace:
            raise DeviceError(f"hands.{h.name}.trace: a replay device needs the trace.csv of a recorded run")
        out.append(ReplayDevice(h.trace, h.trace_hand or h.name))
    return out
