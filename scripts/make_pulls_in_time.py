"""Make the shipped pulls in time: data/reference_pulls_in_time.npz and its record
data/reference_pulls_in_time.json (the file's SHA-256, what each entry is, how long it took).

Solves the accuracy bench's 26 pulls (`sim.pulls.make_pulls` and `test_pulls`) of the shipped
scene, each a ramp at one of the bench's speeds (data/pull_speeds.json) through the samples every
0.5 mm to 12 mm, then held 0.25 to 2 s (`analysis.verification.pulls_in_time`), for each set
asked: a mesh size (the full bench's coarsest reference mesh, 8 mm; the quick bench's, 20 mm)
and a speed. The tissue is the regional viscoelastic law of protocols/materials/*_rheology.toml.
Every solve goes into the cache ($BRAINSIM_CACHE/reference) as it ends, so an interrupted run
goes on where it stopped. The shipped file holds every set asked whose 26 solves are all stored
(a solve that stopped, as some anterior pulls on the 8 mm mesh do, with the records it reached: its
entry says where and why), and keeps the sets it shipped before that were not asked; its record names the
sets left out (the bench judges a set only where shipped).

    .venv/bin/python scripts/make_pulls_in_time.py [--jobs 1] [--sets 20:typical,20:fast,8:typical,8:fast] [--status]

On 2 cores a pull on the 20 mm mesh takes about 30 s and on the 8 mm mesh 2 to 3 minutes on an
idle machine; a pull that stops takes 10 to 40 minutes, its last step halved until Newton gives
up. Two jobs on 2 cores gave more throughput: `--jobs 2 --sets 8:fast` made the 26 in
39 minutes (1.4 to 3 minutes a solve, two at once; 5 for extra1-anterior, 13 for the longest
stop), where one job made the typical set at about 2.5 minutes a solve. The device machine, where
lent, is faster (scripts/make_reference_pulls.py says how to carry the solver there).
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
    pull_in_time_key_of,
    pull_in_time_task,
    reached,
    shipped_pulls_in_time,
    shipped_rheology,
    stored_pull_in_time,
)
from analysis.verification.tissue_pulls import RECORD_XS
from brainsim_assets import path as asset
from brainsim_assets import version
from sim.files import save_npz
from sim.pulls import make_pulls, scene_with, test_pulls
from sim.scene import DEFAULT_SCENE

DEFAULT_SETS = "20:typical,20:fast,8:typical,8:fast"


def _where(solve: dict) -> dict:
    """A shipped entry's account of how far its solve got (`reached`) and why it stopped there."""
    mm, at_s = reached(solve)
    return {"reason": solve["meta"].get("reason", ""), "reached_mm": mm, "reached_s": at_s}


def _sets(text: str, speeds: dict) -> list[tuple[float, str]]:
    out = []
    for item in text.split(","):
        size, _, name = item.strip().partition(":")
        try:
            mm = float(size)
        except ValueError:
            mm = -1.0
        if not mm > 0 or name not in speeds:
            raise SystemExit(f"--sets: {item!r}; allowed: SIZE_MM:SPEED, SPEED one of {', '.join(speeds)}")
        out.append((mm, name))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--sets", default=DEFAULT_SETS, help="SIZE_MM:SPEED pairs, comma-separated, solved in this order")
    ap.add_argument("--status", action="store_true", help="count the solves already stored per set; solve nothing")
    args = ap.parse_args()
    speeds = json.loads(asset("data/pull_speeds.json").read_text())["speeds"]
    sets = _sets(args.sets, speeds)
    scene = scene_with(DEFAULT_SCENE)
    pulls = make_pulls(scene) + test_pulls(scene)
    named = [((size, name), (str(DEFAULT_SCENE), p, size, float(speeds[name]["speed_m_s"]), RECORD_XS, HOLDS_S, MAX_DT_S))
             for size, name in sets for p in pulls]
    if args.status:
        for s in sets:
            have = sum(stored_pull_in_time(pull_in_time_key_of(t)) is not None for k, t in named if k == s)
            print(f"{s[0]:g} mm {s[1]}: {have} of {len(pulls)} pulls in time stored")
        return
    start = time.perf_counter()
    results = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = {pool.submit(pull_in_time_task, t): (k, t) for k, t in named}
        for n, f in enumerate(as_completed(futures), 1):
            (size, name), t = futures[f]
            r = f.result() | {"speed_name": name}
            results.append(r)
            took = "stored" if r["cached"] else f"{r['meta'].get('seconds', 0.0):.0f} s"
            print(f"{n}/{len(named)} {t[1].name} {size:g} mm {name}: {took}, {time.perf_counter() - start:.0f} s in all", flush=True)
    shipped, left = [], []
    for size, name in sets:
        mine = [r for r in results if r["size_mm"] == size and r["speed_name"] == name]
        # a solve that stopped ships the records it reached, as the timeless truth's do; one that
        # reached none leaves its set out
        empty = [r["pull"] for r in mine if reached(r)[0] == 0.0]
        if empty:
            left.append({"size_mm": size, "speed": name, "why": f"{len(empty)} solves reached no record: {', '.join(empty)}"})
        else:
            shipped += mine
    arrays, entries, kept = {}, [], []
    # the shipped sets not asked for stay shipped (their solves may be in no cache)
    old = json.loads(SHIPPED_INFO.read_text()) if SHIPPED_INFO.exists() else {"entries": [], "sets": []}
    have = shipped_pulls_in_time()
    for e in old["entries"]:
        if (e["size_mm"], e["speed"]) not in sets and e["key"] in have:
            solve = have[e["key"]]
            arrays.update({f"{e['key']}__{part}": np.asarray(solve[part]) for part in PARTS})
            arrays[f"{e['key']}__meta"] = np.asarray(json.dumps(solve["meta"]))
            entries.append(e | _where(solve))
            kept.append((e["size_mm"], e["speed"]))
    for r in sorted(shipped, key=lambda r: (r["size_mm"], r["speed_name"], r["pull"])):
        for part in PARTS:
            arrays[f"{r['key']}__{part}"] = np.asarray(r[part])
        arrays[f"{r['key']}__meta"] = np.asarray(json.dumps(r["meta"]))
        entries.append({"key": r["key"], "pull": r["pull"], "size_mm": r["size_mm"], "speed": r["speed_name"], "speed_m_s": r["speed_m_s"],
                        "converged": bool(r["meta"].get("converged")), "seconds": r["meta"].get("seconds")} | _where(r))
    save_npz(SHIPPED, **arrays)
    record = {"what": "the bench's pulls in time on the shipped scene's regional viscoelastic brain (docs/viscoelastic.md)",
              "sha256": hashlib.sha256(SHIPPED.read_bytes()).hexdigest(), "software_version": version(),
              "made": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
              "rheology": [law.describe() for law in shipped_rheology()], "holds_s": list(HOLDS_S), "max_dt_s": MAX_DT_S,
              "speeds": {n: speeds[n] for n in dict.fromkeys([name for _, name in sets] + [n for _, n in kept])},
              "sets": [{"size_mm": s, "speed": n} for s, n in dict.fromkeys(kept)]
              + [{"size_mm": s, "speed": n} for s, n in sets if not any(x["size_mm"] == s and x["speed"] == n for x in left)],
              "left_out": left, "entries": entries}
    SHIPPED_INFO.write_text(json.dumps(record, indent=2) + "\n")
    print(f"wrote {SHIPPED} ({len(entries)} solves; {len(left)} sets left out)")


if __name__ == "__main__":
    main()
