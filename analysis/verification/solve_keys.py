"""The key of a reference solve (`analysis.verification.tissue_pulls`): a hash of everything
that decides its forces (the mesh's content, the law's shape, the clamp, the grasp, the pull,
the data's stretch range, the white matter's law and surfaces, the pia-arachnoid), each number
written one way on every machine; and the shipped solves read back by key (`keyed_solves`)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from analysis.verification.regions import region_key
from sim.errors import SimError
from sim.geometry.regions import white_sha256
from sim.geometry.tetmesh import BodyMesh
from sim.scene import clamp_limit


class ReferenceDataError(SimError):
    """The shipped reference solves are damaged (their hash differs) or a solve did not converge."""


SOLVER_VERSION = 2  # part of every solve's key: bump when the solver, element or law form changes (2: the convex volumetric energy)

# The geometry's arithmetic differs between machines at 1e-16 (test9-across's y component is
# +6.9e-18 on one, -0.0 on another) and a law fitted at run time at 1e-7 relative (the ogden-2 fit,
# its alpha at the bound): the precisions sit far above both and far below what moves a force.
KEY_DECIMALS = 9  # lengths (m) and direction components: 1 nm, 1e-9 rad
LAW_DIGITS = 5  # significant digits of a law's shape: 1e-5 of alpha moves a force by under 1e-4; its 95% box spans 6%


def key_number(x: float, decimals: int = KEY_DECIMALS) -> float:
    """`x` rounded to `decimals`, a zero always +0.0: one float, one key, on every machine."""
    v = round(float(x), decimals)
    return 0.0 if v == 0.0 else v


def key_digits(x: float, digits: int = LAW_DIGITS) -> float:
    """`x` to `digits` significant digits (decimal, so the same on every machine), a zero always +0.0."""
    v = float(f"{float(x):.{digits}g}")
    return 0.0 if v == 0.0 else v


def law_shape_key(law) -> list:
    """The law up to its scale: forces are stored per pascal of shear modulus."""
    mu = law.shear_modulus
    return [law.law, [key_digits(m / mu) for m in law.mu], [key_digits(a) for a in law.alpha], key_digits(law.bulk_ratio)]


def pull_key_inputs(mesh_key: str, scene, law, radius: float, pull, stretch_range=None, regional=None) -> list:
    """What a solve's key is the hash of, each number canonical (`key_number`, `key_digits`);
    a regional solve's white matter (`regions.region_key`) added."""
    axis, limit = clamp_limit(scene)
    return ([SOLVER_VERSION, mesh_key, law_shape_key(law), int(axis), key_number(limit), key_number(radius), int(pull.vertex),
             [key_number(c) for c in pull.direction]] + ([[key_number(r) for r in stretch_range]] if stretch_range else [])
            + body_key(scene, regional))


def body_key(scene, regional=None) -> list:
    """What the brain adds to a key beyond one material ([] for one material without a membrane):
    the white matter (`regions.region_key`) and the pia-arachnoid, its mu t per pascal of the
    scene's grey mu (m; a member's membrane scales with it, and with its `pac_scale`) and its alpha."""
    pac, grey_mu = scene.spec.material.pia_arachnoid, scene.spec.material.law.shear_modulus
    scale = regional.pac_scale if regional is not None else 1.0
    return ((region_key(regional, law_shape_key, key_digits) if regional is not None else [])
            + ([["pia-arachnoid", key_digits(pac.mu * pac.thickness * scale / grey_mu), key_digits(pac.alpha)]] if pac else []))


def pull_key(mesh: BodyMesh, scene, law, radius: float, pull, stretch_range=None, regional=None) -> str:
    key = json.dumps(pull_key_inputs(mesh.key, scene, law, radius, pull, stretch_range, regional))
    return hashlib.sha256(key.encode()).hexdigest()[:24]


TIME_SOLVER_VERSION = 3  # part of every pull-in-time key: bump when the viscoelastic step or its driver changes


def rheology_key(grey, white=None) -> list:
    """The regional viscoelastic laws (`sim.material.Viscoelastic`) up to the grey matter's
    equilibrium modulus (forces are stored per pascal of it): every law's shape, every modulus
    over it, every time, and the white surfaces' hash where there is white matter."""
    g = grey.equilibrium.shear_modulus

    def one(law):
        return [law_shape_key(law.equilibrium), key_digits(law.equilibrium.shear_modulus / g),
                [[key_digits(b.mu / g), key_digits(b.alpha), key_digits(b.tau)] for b in law.branches]]

    return [one(grey)] + ([["white", one(white), white_sha256()]] if white is not None else [])


def pull_in_time_key(mesh: BodyMesh, scene, grey, white, radius: float, pull, speed: float, xs, holds, max_dt: float) -> str:
    """The key of a pull in time (`analysis.verification.pulls_in_time`): the mesh, the clamp, the
    grasp, the pull, the regional rheology, the speed, the records and the largest step."""
    axis, limit = clamp_limit(scene)
    inputs = ["time", SOLVER_VERSION, TIME_SOLVER_VERSION, mesh.key, rheology_key(grey, white), int(axis), key_number(limit), key_number(radius),
              int(pull.vertex), [key_number(c) for c in pull.direction], key_digits(speed), [key_number(x) for x in xs],
              [key_digits(h) for h in holds], key_digits(max_dt)]
    return hashlib.sha256(json.dumps(inputs).encode()).hexdigest()[:24]


def keyed_solves(npz: Path, info: Path, script: str) -> dict:
    """Shipped solves stored as `KEY__PART` arrays, by key ({key: {part: array, "meta": dict}}), the
    file's SHA-256 checked against its record `info` (ReferenceDataError naming `script` if not); {} when not shipped."""
    found: dict = {}
    if npz.exists() and info.exists():
        try:
            want = json.loads(info.read_text())["sha256"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ReferenceDataError(f"{info}: not the shipped solves' record ({exc}); reinstall") from None
        if (have := hashlib.sha256(npz.read_bytes()).hexdigest()) != want:
            raise ReferenceDataError(f"{npz}: SHA-256 {have[:12]}... differs from {info.name}'s {str(want)[:12]}...; the file is damaged "
                                     f"(reinstall, or rebuild it with {script})")
        with np.load(npz, allow_pickle=False) as z:
            for name in z.files:
                key, _, part = name.partition("__")
                found.setdefault(key, {})[part] = json.loads(str(z[name])) if part == "meta" else z[name]
    return found
