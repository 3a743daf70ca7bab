"""How well the discrimination fit recovers the Weber fractions synthetic participants were made
with (docs/study.md, "How good are 40 trials?").

    .venv/bin/python scripts/jnd_recovery.py [--seeds 1,2,3] [--participants 20] [--trials 40]
        [--functions thurstone,gaussian,weibull] [--dir /tmp/jnd]

Runs a SYNTHETIC study per seed (the shipped discrimination protocol on the plate-spring, QUEST+,
1 s intervals; about a minute each on 2 cores), then fits every participant with each function
and prints the median absolute relative error per seed and the 95% intervals' coverage.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def protocol(folder: Path, trials: int, shipped: bool = False) -> Path:
    """The shipped discrimination protocol on the plate-spring alone, 1 s intervals, no training;
    `shipped`: as shipped (three models, 3 s intervals), `trials` aside."""
    text = (ROOT / "protocols/stiffness_jnd.toml").read_text()
    if shipped:
        path = folder / "jnd.toml"
        path.write_text(text.replace('scene = "scenes/brain_pull.toml"', f'scene = "{ROOT}/protocols/scenes/brain_pull.toml"')
                        .replace("trials = 40", f"trials = {trials}"))
        return path
    text = text.replace('scene = "scenes/brain_pull.toml"', f'scene = "{ROOT}/protocols/scenes/brain_pull.toml"')
    text = text.replace('conditions = ["fem", "mass_spring", "plate_spring"]', 'conditions = ["plate_spring"]')
    text = text.replace("trials = 40", f"trials = {trials}").replace("training_minutes = 2.0", "training_minutes = 0.0")
    text = text.replace("trial_seconds = 3.0", "trial_seconds = 1.0")
    path = folder / "jnd.toml"
    path.write_text(text)
    return path


def main() -> None:
    from analysis.discrimination import jnd
    from analysis.discrimination.pooled import pooled_webers
    from analysis.discrimination.psychometric import weber_table
    from studyctl.store import Store
    from studyctl.store.snapshot import read_study
    from studyctl.synthetic.synth_run import run_synthetic_study

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--participants", type=int, default=20)
    ap.add_argument("--trials", type=int, default=40)
    ap.add_argument("--functions", default="thurstone,pooled,gaussian", help="fits: thurstone, gaussian, weibull, and pooled (the hierarchical estimate)")
    ap.add_argument("--dir", type=Path, default=Path("/tmp/jnd_recovery"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--shipped", action="store_true", help="the shipped protocol as it is: fem, mass_spring and plate_spring, 3 s intervals")
    a = ap.parse_args()
    out = {}
    studies = {}
    for seed in (int(s) for s in a.seeds.split(",")):
        folder = a.dir / f"seed{seed}"
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        run_synthetic_study(folder / "s.db", a.participants, seed=seed, jobs=a.jobs, protocol_path=protocol(folder, a.trials, a.shipped))
        with Store(folder / "s.db", mode="read") as store:
            studies[seed] = read_study(store)
    for fn in a.functions.split(","):
        if fn == "pooled":
            errors, covered = {}, []
            for seed, study in studies.items():
                p = pooled_webers(jnd.trials(study, 0))
                made = study.traits[study.traits["trait"] == "stiffness_weber"].set_index("code")["value"]
                g = np.array([made[c] for c in p["code"]])
                errors[seed] = float(np.median(np.abs(p["weber_pooled"].to_numpy() - g) / g))
                covered += list((p["pooled_low"].to_numpy() <= g) & (g <= p["pooled_high"].to_numpy()))
            out[fn] = {"median_abs_rel_error": errors, "coverage": float(np.mean(covered)), "fits": len(covered)}
            continue
        errors, covered = {}, []
        for seed, study in studies.items():
            table = weber_table(jnd.trials(study, 0), function=fn)
            traits = study.traits
            made = traits[traits["trait"] == "stiffness_weber"].set_index("code")["value"]
            g = np.array([made[c] for c in table["code"]])
            errors[seed] = float(np.median(np.abs(table["weber"].to_numpy() - g) / g))
            covered += list((table["ci_low"].to_numpy() <= g) & (g <= table["ci_high"].to_numpy()))
            for cond, rows in table.groupby("condition"):  # per condition as well
                gc = np.array([made[c] for c in rows["code"]])
                errors[f"{seed} {cond}"] = float(np.median(np.abs(rows["weber"].to_numpy() - gc) / gc))
        out[fn] = {"median_abs_rel_error": errors, "coverage": float(np.mean(covered)), "fits": len(covered)}
    print(json.dumps({"synthetic": True, "participants": a.participants, "trials": a.trials, "functions": out}, indent=2))


if __name__ == "__main__":
    main()
