"""The regions' mesh study (docs/reference.md, Regions): chosen pulls solved with the brain
homogeneous (the scene's law) and regional (the same scene with `[material] white_matter`), on
the shipped 8, 6 and 4 mm meshes, records every 0.5 mm to 5 mm; prints per pull, x and mesh
both forces and the change, then Richardson and the GCI of each (`tissue_pulls.combined_sample`).

    BRAINSIM_CACHE=/tmp/cache .venv/bin/python scripts/region_mesh_study.py \
        [--scene protocols/scenes/brain_pull.toml] [--white protocols/materials/human_white_matter.toml] \
        [--pulls left-lateral,test4-across] [--at 2,5] [--sizes 8,6,4]

The homogeneous solves are the shipped ones where the scene is the shipped one; the regional
ones are solved (one process) and cached. A copy of the scene with absolute paths and the white
matter is written to the cache folder.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np

from analysis.verification.tissue_pulls import RECORD_XS, combined_sample, pull_references
from sim.geometry.volume import cache_dir
from sim.pulls import make_pulls, scene_with, test_pulls

ROOT = Path(__file__).resolve().parents[1]


def regional_copy(scene: Path, white: Path) -> Path:
    """The scene with every relative path made absolute and `white_matter` in its [material]."""
    text = scene.read_text()
    text = re.sub(r'"(\.\.?/[^"]+)"', lambda m: f'"{(scene.parent / m.group(1)).resolve()}"', text)
    text = text.replace("[material]", f'[material]\nwhite_matter = "{white.resolve()}"', 1)
    out = cache_dir() / "reference" / "regional_scene.toml"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", type=Path, default=ROOT / "protocols/scenes/brain_pull.toml")
    ap.add_argument("--white", type=Path, default=ROOT / "protocols/materials/human_white_matter.toml")
    ap.add_argument("--pulls", default="left-lateral,test4-across")
    ap.add_argument("--at", default="2,5", help="mm")
    ap.add_argument("--sizes", default="8,6,4", help="mm, coarse to fine")
    a = ap.parse_args()
    scene = scene_with(a.scene)
    mu = scene.spec.material.law.shear_modulus
    names = a.pulls.split(",")
    pulls = [p for p in make_pulls(scene) + test_pulls(scene) if p.name in names]
    at = [float(x) * 1e-3 for x in a.at.split(",")]
    xs = RECORD_XS[RECORD_XS <= max(at) + 1e-9]
    sizes = [float(s) for s in a.sizes.split(",")]
    refs = {tag: pull_references(path, pulls, xs, sizes, jobs=1)["pulls"]
            for tag, path in (("homogeneous", a.scene), ("regional", regional_copy(a.scene, a.white)))}
    print("| pull | x | mesh | homogeneous N | regional N | change |\n|---|---|---|---|---|---|")
    for p in pulls:
        for x in at:
            i = int(np.argmin(np.abs(xs - x)))
            for k, size in enumerate(sizes):
                f = {t: float(np.linalg.norm(refs[t][p.name]["force_per_pa"][k][i])) * mu for t in refs}
                print(f"| {p.name} | {x * 1e3:g} mm | {size:g} mm | {f['homogeneous']:.4f} | {f['regional']:.4f} | "
                      f"{100 * (f['regional'] / f['homogeneous'] - 1):+.1f}% |")
    for p in pulls if len(sizes) > 1 else ():  # Richardson needs two meshes at least
        for x in at:
            i = int(np.argmin(np.abs(xs - x)))
            for t in refs:
                r = refs[t][p.name]
                c = combined_sample([r["force_per_pa"][k][i] * mu for k in range(len(sizes))], r["h_m"])
                print(f"{p.name} {x * 1e3:g} mm {t}: extrapolated {c['force_n']:.4f} N, GCI {100 * c['band_rel']:.1f}% ({c['status']}, p {c['order']:.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
