"""A whole synthetic study end to end: 35 participants x 3 models, 2 jobs (target: 60 s).

Prints the wall time and its breakdown by model (summed trial time over the workers);
`python -m bench synthetic [--json]` (stable keys `synthetic.*`)."""

from __future__ import annotations

import collections
import datetime as dt
import json
import sqlite3
import sys
import tempfile
import time
from pathlib import Path

from studyctl.synthetic.synth_run import run_synthetic_study

PROTOCOL = Path(__file__).resolve().parents[1] / "protocols" / "brain_pull_2015.toml"
TARGET_S = 60.0  # issue 19


def measure(participants: int = 35, jobs: int = 2) -> dict:
    with tempfile.TemporaryDirectory() as d:
        db = Path(d) / "study.db"
        t0 = time.perf_counter()
        out = run_synthetic_study(db, participants, seed=1, jobs=jobs, protocol_path=PROTOCOL)
        wall = time.perf_counter() - t0
        con = sqlite3.connect(db)
        per_model = collections.defaultdict(float)
        for model, a, b in con.execute("select model, started_at, ended_at from trials"):
            per_model[model] += (dt.datetime.fromisoformat(b) - dt.datetime.fromisoformat(a)).total_seconds()
        answers = con.execute("select count(*) from answers").fetchone()[0]
        con.close()
    trials = sum(per_model.values())
    return {"participants": out["participants"], "jobs": jobs, "wall_s": wall, "answers": answers,
            **{f"trial_s.{m}": s for m, s in sorted(per_model.items())}, "other_s": max(wall * jobs - trials, 0.0)}


def main() -> None:
    out = measure()
    if "--json" in sys.argv:
        keys = {f"synthetic.{k}": v for k, v in out.items()}
        keys |= {"synthetic.wall_s.target": TARGET_S, "synthetic.wall_s.ratio_to_target": out["wall_s"] / TARGET_S}
        print(json.dumps(keys, indent=2))
        return
    wall = out["wall_s"]
    print(f"{out['participants']} SYNTHETIC participants x 3 models, {out['jobs']} jobs: {wall:.1f} s wall "
          f"(target {TARGET_S:g} s: {'met' if wall < TARGET_S else f'MISSED, {wall / TARGET_S:.1f}x over'}); {out['answers']} answers")
    total = sum(v for k, v in out.items() if k.startswith("trial_s."))
    for k, s in sorted(((k, v) for k, v in out.items() if k.startswith("trial_s.")), key=lambda kv: -kv[1]):
        print(f"  {k[8:]:<13} trials {s:7.1f} s summed over workers ({s / total:.0%} of trial time)")
    print(f"  other (model builds, questionnaires, database): {out['other_s']:.1f} s summed")


if __name__ == "__main__":
    main()
