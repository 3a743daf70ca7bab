"""Rewrite the keys of the shipped reference solves (data/reference_pulls.npz and its record
data/reference_pulls.json) with `analysis.verification.tissue_pulls.pull_key`, from each solve's
stored inputs, without solving anything: the solved values do not depend on how the key is written.

Each entry's inputs: its pull (`pull`, the shipped scene's `sim.pulls.make_pulls` and
`test_pulls`), its mesh (`size_mm`, the shipped body-fitted mesh of the pull's hemisphere) and
its law (`shape`: the law of the record's `ensemble` member with that shape, as fitted when the
solves were made). Run it after a change of the key's form (not of the solver: that is
SOLVER_VERSION, and a re-solve with scripts/make_reference_pulls.py):

    .venv/bin/python scripts/rekey_reference_pulls.py
"""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np

from analysis.verification.regions import RegionalLaw, scene_regions
from analysis.verification.tissue_pulls import SHIPPED_PULLS, SHIPPED_PULLS_INFO, entry_keys
from sim.files import save_npz
from sim.hyperelastic import Hyperelastic
from sim.pulls import make_pulls, scene_with, test_pulls
from sim.scene import DEFAULT_SCENE


def new_keys(info: dict) -> list[str]:
    """Each entry's key from its stored inputs, in the record's order: the laws as the record holds them."""
    scene = scene_with(DEFAULT_SCENE)
    pulls = {p.name: p for p in make_pulls(scene) + test_pulls(scene)}
    laws = {m["shape"]: Hyperelastic(m["law"]["law"], tuple(m["law"]["mu"]), tuple(m["law"]["alpha"]), m["law"]["bulk_ratio"])
            for m in info["ensemble"]}
    # the regional contrasts: the grey law with the white matter the record names (None: one material)
    for c in info.get("contrast", []):
        grey = Hyperelastic.from_params(c["grey"])
        white = Hyperelastic.from_params(c["white"]) if c["white"] else None
        laws[c["shape"]] = RegionalLaw(grey, white, *scene_regions(scene).ranges_pair())
    # the pia-arachnoid's spread: the scene's body with the membrane scaled as the record says
    for m in info.get("pia_arachnoid_members", []):
        laws[m["shape"]] = dataclasses.replace(scene_regions(scene), pac_scale=m["pac_scale"])
    return entry_keys(info["entries"], scene, laws, pulls)


def main() -> None:
    info = json.loads(SHIPPED_PULLS_INFO.read_text())
    keys = new_keys(info)
    if len(set(keys)) != len(keys) or len({e["key"] for e in info["entries"]}) != len(keys):
        raise SystemExit("two entries would share a key; nothing written")
    rename = {e["key"]: k for e, k in zip(info["entries"], keys)}
    with np.load(SHIPPED_PULLS, allow_pickle=False) as z:
        arrays = {}
        for name in z.files:
            old, _, part = name.partition("__")
            arrays[f"{rename[old]}__{part}"] = z[name]
    save_npz(SHIPPED_PULLS, compressed=True, **arrays)
    for e, k in zip(info["entries"], keys):
        e["key"] = k
    info["sha256"] = hashlib.sha256(SHIPPED_PULLS.read_bytes()).hexdigest()
    SHIPPED_PULLS_INFO.write_text(json.dumps(info, indent=1) + "\n")
    changed = sum(old != new for old, new in rename.items())
    print(f"wrote {SHIPPED_PULLS} ({len(keys)} solves, {changed} keys changed)")


if __name__ == "__main__":
    main()
