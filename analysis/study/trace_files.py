"""A trial's trace file: every tick of one trial (time; per hand position, force, button;
events; the frames' deformation times) in a side folder next to the study database.

A trace is written durably (temporary file, fsync, rename, fsync of the folder) before its
trial's row is committed, and the row holds its path (relative to the database's folder) and
SHA-256, so a crash leaves at worst an unreferenced file that the re-run trial replaces. Files
are compressed NumPy archives named by session, condition position and trial, never by model.
The rows that name the files are the store's (studyctl.session.traces).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.errors import StoreError
from sim.servo.loop import Event


def home(db: str | Path) -> Path:
    """The folder the database file really lives in (a link to it resolved): its traces are
    there, wherever the link is, and the rows' paths are relative to it."""
    return Path(os.path.realpath(db)).parent


def trace_file(db: str | Path, rel: str) -> Path:
    """Where a trial row's trace (`rel`) is: beside the real file, else beside the link as
    given, where software that did not resolve links wrote it (its rows relative to the link's
    folder); the real file's place when neither holds it (what an error names)."""
    real = home(db) / rel
    if real.exists():
        return real
    given = Path(db).parent / rel
    return given if given.exists() else real


def beside(db: str | Path, suffix: str) -> Path:
    """What the store keeps beside the database's real file (a link resolved): `S.db` + `suffix`."""
    real = Path(os.path.realpath(db))
    return real.with_name(real.name + suffix)


def trace_dir(db: str | Path) -> Path:
    return beside(db, ".traces")


@dataclass
class Trace:
    """A stored trial's trace, with the attributes of a `sim.run.RunResult` that analyses use."""

    hand_names: list[str]
    times: np.ndarray  # (ticks,) s from the trial's start
    positions: np.ndarray  # (ticks, hands, 3) m
    forces: np.ndarray  # (ticks, hands, 3) N, as sent to the devices
    buttons: np.ndarray  # (ticks, hands) bool
    deformation_s: np.ndarray
    events: list = field(default_factory=list)  # sim.servo.loop.Event
    frame_flops: np.ndarray = field(default_factory=lambda: np.zeros(0))  # per frame, the model's count (older traces: none)


def encode(result) -> bytes:
    events = [[e.t, e.hand, e.kind, e.detail] for e in result.events]
    buf = io.BytesIO()
    np.savez_compressed(
        buf, times=np.asarray(result.times, dtype=np.float64), positions=np.asarray(result.positions, dtype=np.float64),
        forces=np.asarray(result.forces, dtype=np.float64), buttons=np.asarray(result.buttons, dtype=bool),
        deformation_s=np.asarray(result.deformation_s, dtype=np.float64),
        frame_flops=np.asarray(getattr(result, "frame_flops", np.zeros(0)), dtype=np.float64), hand_names=np.asarray(result.hand_names, dtype=str),
        events=np.asarray(json.dumps(events)),
    )
    return buf.getvalue()


def write_durably(path: Path, data: bytes) -> None:
    """`data` in `path` (its folders made), surviving a power cut: a temporary file, fsync,
    rename, fsync of the folder and its parent."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    for d in (path.parent, path.parent.parent):  # the rename and the new folder survive a power cut
        fd = os.open(d, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_trace(db: str | Path, session_id: int, position: int, trial: int, result, name: str | None = None) -> dict:
    """Write the trial's trace durably; returns the trial row's trace fields. `name`: the file's
    name in the session's folder, when it is not a free trial's (a task's interval)."""
    data = encode(result)
    folder = trace_dir(db) / f"session-{session_id:04d}"
    path = folder / (name or f"condition-{position + 1}-trial-{trial + 1}.npz")
    try:
        write_durably(path, data)
    except OSError as exc:
        raise StoreError(f"{folder}: cannot write the trial's trace: {exc.strerror}") from None
    return {"trace_path": str(path.relative_to(home(db))), "trace_sha256": hashlib.sha256(data).hexdigest(),
            "trace_ticks": int(len(result.times))}


def read_trace(db: str | Path, rel: str, sha256: str) -> Trace:
    """The stored trace, checked against the SHA-256 its trial row holds."""
    path = trace_file(db, rel)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise StoreError(f"{path}: cannot read the trial's trace: {exc.strerror}") from None
    if hashlib.sha256(data).hexdigest() != sha256:
        raise StoreError(f"{path}: the trace does not match the SHA-256 stored with its trial (changed or damaged)")
    z = np.load(io.BytesIO(data), allow_pickle=False)
    events = [Event(float(t), int(h), str(k), str(d)) for t, h, k, d in json.loads(str(z["events"]))]
    return Trace(hand_names=[str(n) for n in z["hand_names"]], times=z["times"], positions=z["positions"], forces=z["forces"],
                 buttons=z["buttons"], deformation_s=z["deformation_s"], events=events,
                 frame_flops=z["frame_flops"] if "frame_flops" in z.files else np.zeros(0))
