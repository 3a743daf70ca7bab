"""The shipped stiffness field of the location-aware plate-spring model: where it is and how it
is read (K per pascal at every vertex of the surface it was made for). How it is made, from the
reference's P2 solves, is analysis/verification/field_fit.py (`studyctl calibrate field`)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from brainsim_assets import path as _asset
from sim.errors import ParameterError

FIELD_FILE = _asset("data/plate_spring_field.npz")


def mesh_digest(mesh) -> str:
    """Identifies the surface a field belongs to (vertices to 1 um, triangles)."""
    h = hashlib.sha256()
    h.update(np.round(np.asarray(mesh.vertices) * 1e6).astype(np.int64).tobytes())
    h.update(np.asarray(mesh.triangles, dtype=np.int64).tobytes())
    return h.hexdigest()[:16]


def load_field(path, mesh) -> np.ndarray:
    """K per pascal (n, 3, 3) for `mesh`'s vertices; refuses a field made for another surface."""
    path = Path(path)
    try:
        with np.load(path) as z:
            k6, digest = z["K_per_pa"].astype(np.float64), str(z["mesh_digest"])
    except (OSError, KeyError, ValueError) as e:
        raise ParameterError(f"{path}: not a stiffness field ({e})") from None
    if digest != mesh_digest(mesh) or len(k6) != len(mesh.vertices):
        raise ParameterError(f"{path}: made for another surface mesh ({len(k6)} vertices, digest {digest}); "
                             f"rebuild it with `studyctl calibrate field --out {path} --force`")
    if not np.all(np.isfinite(k6)):
        raise ParameterError(f"{path}: K_per_pa holds a non-finite value")
    K = np.zeros((len(k6), 3, 3))
    iu = np.triu_indices(3)
    K[:, iu[0], iu[1]] = k6
    K[:, iu[1], iu[0]] = k6
    return K
