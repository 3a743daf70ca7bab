"""Files written whole or not at all."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def save_npz(path, /, compressed: bool = False, **arrays) -> Path:
    """NumPy arrays to `path`, through a temporary file of this process beside it, renamed over
    it: a concurrent reader, or a run killed halfway, never sees half a file (caches, shipped
    tables)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
    (np.savez_compressed if compressed else np.savez)(tmp, **arrays)
    os.replace(tmp, path)
    return path
