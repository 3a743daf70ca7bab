"""Check the truth in time's borrowed mesh correction (docs/viscoelastic.md, Counter-checks): over
every pull shipped in time and timeless on both the 20 and the 8 mm mesh, at the typical speed,
the 20-over-8 mm force ratio of the time solves against the timeless solves' at 2, 4, ... 12 mm.
Reads the shipped solves only.

    .venv/bin/python scripts/check_mesh_correction_in_time.py
"""
import json

import numpy as np

from analysis.verification.pulls_in_time import HOLDS_S, MAX_DT_S, pull_in_time_key_of, stored_pull_in_time
from analysis.verification.tissue_pulls import RECORD_XS
from analysis.verification.truth_band import truth_samples
from analysis.verification.truth_in_time import bench_speeds
from brainsim_assets import path as asset
from sim.pulls import make_pulls, scene_with, test_pulls
from sim.scene import DEFAULT_SCENE


def main() -> None:
    ref = json.loads(asset("data/reference_pulls.json").read_text())
    have20 = {e["pull"] for e in ref["entries"] if e["size_mm"] == 20.0 and e["shape"] == 0}
    scene = scene_with(DEFAULT_SCENE)
    pulls = [p for p in make_pulls(scene) + test_pulls(scene) if p.name in have20]
    xs = RECORD_XS[3::4]  # 2, 4, ... 12 mm
    idx = [int(np.argmin(abs(RECORD_XS - x))) for x in xs]
    sp = bench_speeds(["typical"])[0]
    coarse = {}
    for sizes in ((20.0, 16.0), (8.0, 6.0, 4.0)):
        st = truth_samples(DEFAULT_SCENE, pulls, xs, sizes, jobs=1)
        coarse[max(sizes)] = {p.name: np.linalg.norm(np.asarray(st["refs"]["pulls"][p.name]["force_per_pa"])[0], axis=1) for p in pulls}
    diffs = []
    for p in pulls:
        t = {}
        for size in (20.0, 8.0):
            s = stored_pull_in_time(pull_in_time_key_of((str(DEFAULT_SCENE), p, size, sp.speed_m_s, RECORD_XS, HOLDS_S, MAX_DT_S)))
            t[size] = np.linalg.norm(np.asarray(s["force_per_pa"])[idx], axis=1)
        r_time = t[20.0] / t[8.0]
        r_static = coarse[20.0][p.name] / coarse[8.0][p.name]
        d = r_time / r_static - 1
        ok = np.isfinite(d)
        diffs += list(d[ok])
        print(p.name, "time", np.round(r_time, 3), "timeless", np.round(r_static, 3), "diff", np.round(d, 3))
    diffs = np.abs(np.array(diffs))
    print(f"pulls {len(pulls)}, samples {len(diffs)}: |time/timeless - 1| median {np.median(diffs):.4f}, 95th {np.percentile(diffs, 95):.4f}, max {diffs.max():.4f}")


if __name__ == "__main__":
    main()
