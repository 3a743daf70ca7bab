"""Check the truth in time's borrowed mesh correction (docs/viscoelastic.md, Counter-checks): over
every pull shipped in time and timeless on both the 20 and the 8 mm mesh, at a bench speed,
the 20-over-8 mm force ratio of the time solves against the timeless solves' at 2, 4, ... 12 mm
and in each hold (against the timeless ratio at 12 mm). Reads the shipped solves (the timeless
ones through `truth_samples`, which solves nothing that is shipped).

    .venv/bin/python scripts/check_mesh_correction_in_time.py [--speed typical|fast]
"""

import argparse
import json

import numpy as np

from analysis.verification.tissue_pulls import RECORD_XS
from analysis.verification.truth_band import truth_samples
from analysis.verification.truth_in_time import QUASI_STATIC, SPEED_NAMES, bench_speeds, stored_bench_pull
from brainsim_assets import path as asset
from sim.pulls import make_pulls, scene_with, test_pulls
from sim.scene import DEFAULT_SCENE

EVERY_2_MM = slice(3, None, 4)  # RECORD_XS every 0.5 mm from 0.5: 2, 4, ... 12 mm


def timeless_forces(pulls, sizes_mm) -> dict:
    """Per pull, the force magnitude per pascal on the coarsest of `sizes_mm` at every record."""
    st = truth_samples(DEFAULT_SCENE, pulls, RECORD_XS, sizes_mm, jobs=1)
    return {p.name: np.linalg.norm(np.asarray(st["refs"]["pulls"][p.name]["force_per_pa"])[0], axis=1) for p in pulls}


def time_forces(pull, size_mm: float, speed) -> np.ndarray:
    """The pull in time's force magnitude per pascal at every record, ramp then holds."""
    solve = stored_bench_pull(DEFAULT_SCENE, pull, size_mm, speed)
    if solve is None:
        raise SystemExit(f"no pull in time of {pull.name} on {size_mm:g} mm; make it: scripts/make_pulls_in_time.py --sets {size_mm:g}:{speed.name}")
    return np.linalg.norm(np.asarray(solve["force_per_pa"]), axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description="Check the truth in time's borrowed mesh correction at one bench speed")
    parser.add_argument("--speed", default="typical", choices=[n for n in SPEED_NAMES if n != QUASI_STATIC])
    args = parser.parse_args()
    ref = json.loads(asset("data/reference_pulls.json").read_text())
    have20 = {e["pull"] for e in ref["entries"] if e["size_mm"] == 20.0 and e["shape"] == 0}
    scene = scene_with(DEFAULT_SCENE)
    pulls = [p for p in make_pulls(scene) + test_pulls(scene) if p.name in have20]
    speed = bench_speeds([args.speed])[0]
    coarse20, coarse8 = timeless_forces(pulls, (20.0, 16.0)), timeless_forces(pulls, (8.0, 6.0, 4.0))
    ramp, held = [], []
    for p in pulls:
        r_time = time_forces(p, 20.0, speed) / time_forces(p, 8.0, speed)
        r_static = coarse20[p.name] / coarse8[p.name]
        d_ramp = r_time[: len(RECORD_XS)][EVERY_2_MM] / r_static[EVERY_2_MM] - 1
        d_held = r_time[len(RECORD_XS):] / r_static[-1] - 1
        ramp += list(d_ramp[np.isfinite(d_ramp)])
        held += list(d_held[np.isfinite(d_held)])
        print(p.name, "ramp", np.round(d_ramp, 3), "held", np.round(d_held, 3))
    for name, d in (("ramp", ramp), ("held", held), ("both", ramp + held)):
        a = np.abs(np.array(d))
        print(f"{args.speed} {name}: {len(pulls)} pulls, {len(a)} samples, |time ratio / timeless ratio - 1| median {np.median(a):.4f}, "
              f"95th percentile {np.percentile(a, 95):.4f}, largest {a.max():.4f}")


if __name__ == "__main__":
    main()
