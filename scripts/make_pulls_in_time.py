"""Make the shipped pulls in time: data/reference_pulls_in_time.npz and its record
data/reference_pulls_in_time.json (the file's SHA-256, what each entry is, how long it took).

Solves the accuracy bench's 26 pulls (`sim.pulls.make_pulls` and `test_pulls`) of the shipped
scene, each a ramp at the bench's typical and fast speeds (data/pull_speeds.json) through the
samples every 0.5 mm to 12 mm, then held 0.25 to 2 s (`analysis.verification.pulls_in_time`),
on each mesh size asked (default 8 mm, the full bench's coarsest), the regional viscoelastic
tissue of protocols/materials/*_rheology.toml. Every solve goes into the cache
($BRAINSIM_CACHE/reference) as it ends, so an interrupted run goes on where it stopped; the
shipped file is written only when every solve asked for is there (`--status` counts them), and
says which speeds it holds (the bench judges a speed only where all its pulls are shipped).

    .venv/bin/python scripts/make_pulls_in_time.py [--jobs 1] [--sizes 8] [--speeds typical,fast] [--status]

On 2 cores a pull at one speed on the 8 mm mesh takes about 4 minutes (the element pass uses
both: one job at a time): the whole set is a job for the device machine
(scripts/make_reference_pulls.py says how to carry the solver there).
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

import numpy as np

from analysis.verification.pulls_in_time import (
    HOLDS_S,
    MAX_DT_S,
    PARTS,
    SHIPPED,
    SHIPPED_INFO,
    pull_in_time_task,
    shipped_rheology,
)
from analysis.verification.tissue_pulls import RECORD_XS
from brainsim_assets import path as asset
from brainsim_assets import version
from sim.files import save_npz
from sim.pulls import make_pulls, scene_with, test_pulls
from sim.scene import DEFAULT_SCENE


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--sizes", default="8", help="mesh sizes (mm), comma-separated")
    ap.add_argument("--speeds", default="typical,fast", help="the speeds of data/pull_speeds.json, comma-separated")
    ap.add_argument("--status", action="store_true", help="count the solves already stored; solve nothing")
    args = ap.parse_args()
    speeds = json.loads(asset("data/pull_speeds.json").read_text())["speeds"]
    names = [n.strip() for n in args.speeds.split(",")]
    if not names or any(n not in speeds for n in names):
        raise SystemExit(f"--speeds: {args.speeds!r}; allowed: {', '.join(speeds)}")
    scene = scene_with(DEFAULT_SCENE)
    pulls = make_pulls(scene) + test_pulls(scene)
    sizes = [float(s) for s in args.sizes.split(",")]
    named = [(name, (str(DEFAULT_SCENE), p, size, float(speeds[name]["speed_m_s"]), RECORD_XS, HOLDS_S, MAX_DT_S))
             for size in sizes for name in names for p in pulls]
    tasks = [t for _, t in named]
    start = time.perf_counter()
    results = []
    if args.status:
        from analysis.verification.pulls_in_time import stored_pull_in_time
        from analysis.verification.solve_keys import pull_in_time_key
        from sim.geometry.tetmesh import hemisphere_surface, mesh_hemisphere
        from sim.scene import grasp_radius

        grey, white = shipped_rheology()
        have = 0
        for t in tasks:
            verts, tris, _ = hemisphere_surface(scene.mesh, t[1].hemisphere)
            key = pull_in_time_key(mesh_hemisphere(verts, tris, t[2] * 1e-3), scene, grey, white, grasp_radius(scene), t[1], t[3], t[4], t[5], t[6])
            have += stored_pull_in_time(key) is not None
        print(f"{have} of {len(tasks)} pulls in time stored")
        return
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = {pool.submit(pull_in_time_task, t): (name, t) for name, t in named}
        for k, f in enumerate(as_completed(futures), 1):
            name, t = futures[f]
            r = f.result() | {"speed_name": name}
            results.append(r)
            took = "stored" if r["cached"] else f"{r['meta'].get('seconds', 0.0):.0f} s"
            print(f"{k}/{len(tasks)} {t[1].name} {t[2]:g} mm {name}: {took}, {time.perf_counter() - start:.0f} s in all", flush=True)
    stopped = [f"{r['pull']} {r['size_mm']:g} mm {r['speed_name']} ({r['meta'].get('reason') or 'no convergence'})"
               for r in results if not r["meta"].get("converged")]
    if stopped:
        raise SystemExit(f"{len(stopped)} solves stopped, nothing shipped: {'; '.join(stopped)}")
    arrays, entries = {}, []
    for r in sorted(results, key=lambda r: (r["size_mm"], r["speed_name"], r["pull"])):
        for part in PARTS:
            arrays[f"{r['key']}__{part}"] = np.asarray(r[part])
        arrays[f"{r['key']}__meta"] = np.asarray(json.dumps(r["meta"]))
        entries.append({"key": r["key"], "pull": r["pull"], "size_mm": r["size_mm"], "speed": r["speed_name"], "speed_m_s": r["speed_m_s"],
                        "converged": bool(r["meta"].get("converged")), "seconds": r["meta"].get("seconds")})
    save_npz(SHIPPED, **arrays)
    record = {"what": "the bench's pulls in time on the shipped scene's regional viscoelastic brain (docs/viscoelastic.md)",
              "sha256": hashlib.sha256(SHIPPED.read_bytes()).hexdigest(), "software_version": version(),
              "made": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
              "rheology": [law.describe() for law in shipped_rheology()], "holds_s": list(HOLDS_S), "max_dt_s": MAX_DT_S,
              "speeds": {n: speeds[n] for n in names}, "entries": entries}
    SHIPPED_INFO.write_text(json.dumps(record, indent=2) + "\n")
    print(f"wrote {SHIPPED} ({len(entries)} solves)")


if __name__ == "__main__":
    main()
