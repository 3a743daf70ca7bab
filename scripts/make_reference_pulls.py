"""Make the shipped finite-strain reference solves: data/reference_pulls.npz and its record
data/reference_pulls.json (the file's SHA-256, what each entry is, how long it took).

Solves the accuracy bench's 26 pulls (`sim.pulls.make_pulls` and `test_pulls`) of the
shipped scene on each shipped mesh (8, 6, 4 mm: the full bench's Richardson triple) and the
first 18 (six test places) on the quick bench's pair (20, 16 mm: `--quick` benches and `model check --quick` then solve nothing on an
empty cache) with the scene's law (protocols/materials/human_cortex.toml), recording every
0.5 mm to 12 mm (`analysis.verification.tissue_pulls.RECORD_XS`) the force and the state's support, the hand
pulls with their condensed tangent stiffness too (the observer's truth reads them); then the
other laws of the truth's ensemble (`analysis.verification.truth_band.ensemble`) on each group's coarsest
mesh, as far as the finer meshes follow. A solve that stops is shipped with the records it
reached and its reason. Solves already cached ($BRAINSIM_CACHE/reference) are reused.

    .venv/bin/python scripts/make_reference_pulls.py [--jobs 2] [--finer stored|solve|skip]

First every solve is made into the cache in two balanced rounds (`prefill`: every group's
coarsest mesh; then every finer mesh, every other law and the regional contrast at once, the
slowest first), so that many cores stay busy; the groups are then assembled from the cache.
On a machine of many cores without this project's venv (Python 3.12, say), scikit-sparse 0.4.16
can be built here as a wheel for that Python (`python3.12 -m pip wheel scikit-sparse==0.4.16`)
and carried with Debian 12's SuiteSparse 5 libraries (libcholmod3 and what it links: `ldd`),
found through LD_LIBRARY_PATH; the package itself runs from its source folder with its
`brainsim_study.egg-info` beside it (the models' entry points). An interrupted run keeps what it
solved in $BRAINSIM_CACHE: run it again to go on.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import hashlib
import json
import time
from pathlib import Path

import numpy as np

from analysis.verification.tissue_pulls import (  # the private runners: this script is their only other caller
    QUICK_SIZES_MM,
    RECORD_XS,
    SHIPPED_PULLS,
    SHIPPED_PULLS_INFO,
    SUPPORT_FIELDS,
    _premesh,
    _run,
    follow_to,
    pull_references,
    stored_solve,
)
from analysis.verification.truth_band import (
    contrast_json,
    ensemble,
    members_json,
    pac_json,
    scene_contrast,
    scene_pac_spread,
    shape_index,
    shapes,
)
from brainsim_assets import version
from sim.geometry.regions import white_sha256
from sim.geometry.tetmesh import SHIPPED_MM
from sim.pulls import hand_pulls, make_pulls, scene_with, test_pulls
from sim.scene import DEFAULT_SCENE

QUICK_TEST_PLACES = 6


def prefill(scene, hands, others, jobs: int, start: float) -> None:
    """Every solve the groups below need, into the cache, in two rounds that keep `jobs` busy."""
    groups = [(sorted(SHIPPED_MM, reverse=True), make_pulls(scene) + test_pulls(scene)),
              (sorted(QUICK_SIZES_MM, reverse=True), make_pulls(scene) + test_pulls(scene, QUICK_TEST_PLACES))]
    for sizes, group in groups:
        _premesh(scene.mesh, sorted({p.hemisphere for p in group}), sizes, 1, jobs)
    where = str(DEFAULT_SCENE)
    first = [(where, p.hemisphere, sizes[0], p, RECORD_XS, p.name in hands, RECORD_XS[-1], "stored", None) for sizes, group in groups for p in group]
    coarse = _run(first, jobs, lambda k, n: print(f"coarsest meshes: {k}/{n}, {time.perf_counter() - start:.0f} s", flush=True))
    follow = {(t[2], t[3].name): follow_to(RECORD_XS, r, t[3].name in hands) for t, r in zip(first, coarse)}
    rest = []
    for sizes, group in groups:
        for p in group:
            upto = follow[(sizes[0], p.name)]
            rest += [(where, p.hemisphere, s, p, RECORD_XS, p.name in hands, upto, "stored", None) for s in sizes[1:]]
            rest += [(where, p.hemisphere, sizes[0], p, RECORD_XS, False, upto, "stored", law) for law in others]
    _run(rest, jobs, lambda k, n: print(f"finer meshes and other laws: {k}/{n}, {time.perf_counter() - start:.0f} s", flush=True))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--finer", choices=("stored", "solve", "skip"), default="stored",
                    help="where the coarsest mesh's solve stopped: keep a stored skip (default), solve the finer meshes, or skip them")
    args = ap.parse_args()
    scene = scene_with(DEFAULT_SCENE)
    pulls = make_pulls(scene) + test_pulls(scene)
    hands = {p.name for p in make_pulls(scene) if any(p.vertex == h.vertex and np.allclose(p.direction, h.direction) for h in hand_pulls(scene))}
    start = time.perf_counter()

    def progress(k, n):
        print(f"{k}/{n} solves, {time.perf_counter() - start:.0f} s", flush=True)

    law = scene.spec.material.law
    members = ensemble(scene.spec.material.law_source, law)
    others = shapes(members)[1:]
    contrast = scene_contrast(scene)  # the literature's other regional contrasts: solved like the ensemble, reported beside it
    pac = scene_pac_spread(scene)  # the pia-arachnoid's measured spread (a scene with one): in the band
    prefill(scene, hands, others + [c["law"] for c in contrast] + [m["law"] for m in pac], args.jobs, start)
    # each group as its benches read it: the finer meshes follow a pull as far as the group's coarsest got
    groups, solved = [], []
    # the quick benches judge two test places: their pairs hold the first six (QUICK_TEST_PLACES)
    quick_pulls = make_pulls(scene) + test_pulls(scene, QUICK_TEST_PLACES)
    for sizes, group in ((SHIPPED_MM, pulls), (QUICK_SIZES_MM, quick_pulls)):
        main_refs = pull_references(DEFAULT_SCENE, group, RECORD_XS, sizes, jobs=args.jobs, progress=progress, stiffness_for=hands,
                                    finer=args.finer)
        groups.append(main_refs)
        solved += [(p, s, None) for p in group for s in main_refs["pulls"][p.name]["solves"]]
        upto = {p.name: main_refs["pulls"][p.name]["follow_m"] for p in group}
        for k, shape in enumerate(others, start=1):
            refs = pull_references(DEFAULT_SCENE, group, RECORD_XS, (max(sizes),), jobs=args.jobs, progress=progress, law=shape, upto=upto)
            solved += [(p, s, k) for p in group for s in refs["pulls"][p.name]["solves"]]
        for j, c in enumerate(contrast + pac, start=len(others) + 1):
            refs = pull_references(DEFAULT_SCENE, group, RECORD_XS, (max(sizes),), jobs=args.jobs, progress=progress, law=c["law"], upto=upto)
            solved += [(p, s, j) for p in group for s in refs["pulls"][p.name]["solves"]]
    arrays, entries = {}, []
    for p, s, k in solved:
        key = s["key"]
        stiff = p.name in hands and k is None
        found = stored_solve(key, RECORD_XS, stiffness=stiff)  # cached, or shipped before
        if found is None and s.get("skipped"):  # shipped as a skip (no records), so that readers do not solve it
            found = {"force_per_pa": np.full((len(RECORD_XS), 3), np.nan), "support": np.full((len(RECORD_XS), len(SUPPORT_FIELDS)), np.nan),
                     "converged": False, "skipped": True, "reason": s["reason"], "reached_mm": 0.0}
        if found is None:  # stopped before its first record
            entries.append({"pull": p.name, "size_mm": s["size_mm"], "key": key, "shape": k or 0, "converged": False, "reason": s.get("reason", "")})
            continue
        reached = np.isfinite(np.asarray(found["force_per_pa"])).all(axis=1)
        if k is None and np.isnan(np.asarray(found["support"])[reached, SUPPORT_FIELDS.index("marginal_share_outside")]).any():
            # a solve of the scene's law stored before the marginal share was recorded: the truth's rule needs it
            raise SystemExit(f"{p.name} on the {s['size_mm']:g} mm mesh: a stored solve without the marginal share; move "
                             f"{SHIPPED_PULLS.name} and its record aside and use an empty $BRAINSIM_CACHE, so that it is solved again")
        meta = {m: v for m, v in found.items() if m not in ("force_per_pa", "stiffness_per_pa", "support")}
        arrays[f"{key}__xs"] = RECORD_XS
        arrays[f"{key}__force_per_pa"] = found["force_per_pa"]
        arrays[f"{key}__support"] = found["support"]
        if stiff and not found.get("skipped"):
            arrays[f"{key}__stiffness_per_pa"] = found["stiffness_per_pa"]
        arrays[f"{key}__meta"] = np.asarray(json.dumps(meta))
        entries.append({"pull": p.name, "size_mm": s["size_mm"], "key": key, "shape": k or 0, "stiffness": stiff} | meta)
    np.savez_compressed(SHIPPED_PULLS, **arrays)
    SHIPPED_PULLS_INFO.write_text(json.dumps({
        "sha256": hashlib.sha256(SHIPPED_PULLS.read_bytes()).hexdigest(),
        "made": datetime.date.today().isoformat(), "version": version(), "law": law.params(),
        "ensemble": [j | {"shape": i} for j, i in zip(members_json(members), shape_index(members))],
        "contrast": [c | {"shape": j} for j, c in enumerate(contrast_json(contrast), start=len(others) + 1)],
        "pia_arachnoid_members": [m | {"shape": j} for j, m in enumerate(pac_json(pac), start=len(others) + len(contrast) + 1)],
        "white_matter": f"protocols/materials/{Path(scene.spec.material.white_matter_source).name}" if scene.spec.material.white_matter else None, "white_surfaces_sha256": white_sha256() if scene.spec.material.white_matter else None,
        "pia_arachnoid": dataclasses.asdict(scene.spec.material.pia_arachnoid) if scene.spec.material.pia_arachnoid else None,
        "law_source": "protocols/materials/human_cortex.toml", "scene": "protocols/scenes/brain_pull.toml",
        "record_mm": [round(x * 1e3, 6) for x in RECORD_XS], "sizes_mm": list(SHIPPED_MM) + list(QUICK_SIZES_MM),
        "made_by": "scripts/make_reference_pulls.py", "wall_s": time.perf_counter() - start, "entries": entries}, indent=1) + "\n")
    print(f"wrote {SHIPPED_PULLS} ({len(entries)} solves)")


if __name__ == "__main__":
    main()
