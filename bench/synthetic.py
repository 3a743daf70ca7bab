"""A whole synthetic study end to end: 35 participants x 3 models, 2 jobs (target: 2 minutes).

Prints the wall time and its breakdown by model (summed trial time over the workers)."""

from __future__ import annotations

import collections
import datetime as dt
import sqlite3
import tempfile
import time
from pathlib import Path

from studyctl.synthetic import run_synthetic_study

PROTOCOL = Path(__file__).resolve().parents[1] / "protocols" / "brain_pull_2015.toml"


def main(participants: int = 35, jobs: int = 2) -> None:
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
    print(f"{out['participants']} SYNTHETIC participants x 3 models, {jobs} jobs: {wall:.1f} s wall "
          f"(target 120 s: {'met' if wall < 120 else 'MISSED'}, {120 / wall:.2f}x); {answers} answers")
    total = sum(per_model.values())
    for model, s in sorted(per_model.items(), key=lambda kv: -kv[1]):
        print(f"  {model:<13} trials {s:7.1f} s summed over workers ({s / total:.0%} of trial time)")
    print(f"  other (model builds, questionnaires, database): {max(wall * jobs - total, 0):.1f} s summed")


if __name__ == "__main__":
    main()
