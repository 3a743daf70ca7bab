"""Every movement of every trial, read back through the store: a session's traces and the
table of all of them. The trace files themselves are analysis.study.trace_files's."""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.study.trace_files import Trace, read_trace
from studyctl.store.trials import all_trace_rows, trace_rows


def trial_traces(store, session_id: int, model: str, trial: int | None = None) -> list[Trace]:
    """Every stored trace of one condition of a session (or of its one `trial`), in trial order."""
    rows = trace_rows(store, session_id, model, trial)
    return [read_trace(store.path, r["trace_path"], r["trace_sha256"]) for r in rows]


TRACE_COLUMNS = ["session_id", "model", "trial", "t", "hand", "x", "y", "z", "fx", "fy", "fz", "button"]


def traces_frame(store):
    """Every stored trace as one tidy table (TRACE_COLUMNS), one row per tick and hand."""
    frames = []
    rows = all_trace_rows(store)
    for r in rows:
        tr = read_trace(store.path, r["trace_path"], r["trace_sha256"])
        n, h = tr.positions.shape[:2]
        frames.append(pd.DataFrame({
            "session_id": r["session_id"], "model": r["model"], "trial": r["trial"],
            "t": np.repeat(tr.times, h), "hand": np.tile(np.asarray(tr.hand_names, dtype=object), n),
            "x": tr.positions[:, :, 0].ravel(), "y": tr.positions[:, :, 1].ravel(), "z": tr.positions[:, :, 2].ravel(),
            "fx": tr.forces[:, :, 0].ravel(), "fy": tr.forces[:, :, 1].ravel(), "fz": tr.forces[:, :, 2].ravel(),
            "button": tr.buttons.ravel().astype(int),
        }))
    if not frames:
        return pd.DataFrame({c: [] for c in TRACE_COLUMNS})
    return pd.concat(frames, ignore_index=True)[TRACE_COLUMNS]
