"""Power and family-wise false-positive rate of the construct-validity group tests on SYNTHETIC
studies (issue 32, item 5): does `studyctl report validity` find the group differences built
into the synthetic skill profiles, and, with identical groups, reject at about alpha?

    python scripts/validity_calibration.py [--per-group 10] [--pool 20] [--reps 1000] [--jobs 2] [--json]

Two pools of synthetic participants are run with `studyctl synth` on the shipped
protocols/construct_validity.toml: one with its profiles (student, resident, neurosurgeon), one
with every group given the resident's profile (identical groups). Each replicate study draws
`--per-group` participants per group without replacement from the pool and runs the report's
group tests (`analysis.validity.groups.group_tests`: Kruskal-Wallis per metric, Holm over the family;
Mann-Whitney pairs, Holm over theirs). Under identical groups the group labels carry no
information, so a replicate draws 3 x per-group participants of the null pool and deals the
labels at random: a sample of the null exactly. Power per metric: the fraction of replicates
whose Holm-adjusted Kruskal-Wallis p is below alpha; the family-wise rate: the fraction of null
replicates with any such rejection (binomial 95% intervals, Wilson).

Replicates share participants (a finite pool), so their Monte Carlo error is larger than the
binomial interval says when the pool is small; `--pool` sets it.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
PROTOCOL = ROOT / "protocols/construct_validity.toml"


def identical_groups(text: str, like: str = "resident") -> str:
    """The protocol with every [synthetic.groups.NAME] table replaced by `like`'s."""
    blocks = re.split(r"(?m)^(?=\[)", text)
    tables = {m.group(1): b for b in blocks if (m := re.match(r"\[synthetic\.groups\.(\w+)\]", b))}
    if like not in tables:
        raise SystemExit(f"{PROTOCOL}: no [synthetic.groups.{like}] table")
    out = []
    for b in blocks:
        m = re.match(r"\[synthetic\.groups\.(\w+)\]", b)
        out.append(tables[like].replace(f"[synthetic.groups.{like}]", f"[synthetic.groups.{m.group(1)}]", 1) if m else b)
    return "".join(out)


def run_pool(protocol_text: str, participants: int, seed: int, jobs: int, where: Path) -> tuple[pd.DataFrame, pd.Series]:
    """Participant scores (analysis.validity.groups.participant_scores) and groups of a synthetic study."""
    from analysis.validity.groups import participant_scores
    from analysis.validity.metrics import metrics_table, study_goals
    from studyctl.store import Store
    from studyctl.store.snapshot import read_study

    path = where / "protocol.toml"
    path.write_text(protocol_text.replace('scene = "scenes/', f'scene = "{PROTOCOL.parent}/scenes/'))
    db = where / "study.db"
    subprocess.run([sys.executable, "-m", "studyctl", "synth", "--protocol", str(path), "--participants", str(participants),
                    "--seed", str(seed), "--jobs", str(jobs), "--db", str(db)], check=True, stdout=subprocess.DEVNULL)
    with Store(db, mode="read") as store:
        study = read_study(store)
    table = metrics_table(study, study_goals(study))
    fields = study.fields[study.fields["field"] == study.protocol.groups]
    groups = pd.Series(dict(zip(fields["code"], fields["value"])))
    return participant_scores(table), groups


def replicate(scores: pd.DataFrame, groups: pd.Series, order: list[str], alpha: float, n_perm: int, seed: int) -> dict:
    from analysis.validity.groups import group_tests

    t = group_tests(scores[scores["code"].isin(groups.index)], groups, order=order, n_boot=1, n_perm=n_perm, seed=seed)
    kw = t.kruskal.dropna(subset=["p"])
    out = {"kw_holm": dict(zip(kw["metric"], kw["p_holm"] < alpha)), "kw_raw": dict(zip(kw["metric"], kw["p"] < alpha)),
           "any_kw": bool((kw["p_holm"] < alpha).any()), "any_pair": bool((t.pairs["p_holm"] < alpha).any())}
    if n_perm:
        out |= {"kw_wy": dict(zip(kw["metric"], kw["p_wy"] < alpha)), "any_kw_wy": bool((kw["p_wy"] < alpha).any()),
                "any_pair_wy": bool((t.pairs["p_wy"] < alpha).any())}
    return out


def wilson(k: int, n: int) -> tuple[float, float]:
    from statsmodels.stats.proportion import proportion_confint

    lo, hi = proportion_confint(k, n, alpha=0.05, method="wilson")
    return float(lo), float(hi)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--per-group", type=int, default=10)
    ap.add_argument("--pool", type=int, default=20, help="synthetic participants per group in each pool")
    ap.add_argument("--reps", type=int, default=1000)
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--perms", type=int, default=500, help="Westfall-Young permutations per replicate (0: Holm only)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    if a.per_group > a.pool:
        raise SystemExit(f"--per-group {a.per_group} is larger than --pool {a.pool}")
    text = PROTOCOL.read_text()
    from studyctl.protocol import load_protocol

    order = list(load_protocol(PROTOCOL).group_field.values)
    rng = np.random.default_rng(a.seed)
    out: dict = {"synthetic": True, "per_group": a.per_group, "pool_per_group": a.pool, "reps": a.reps, "alpha": a.alpha}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        built_dir, null_dir = Path(tmp, "built"), Path(tmp, "null")
        built_dir.mkdir()
        null_dir.mkdir()
        scores, groups = run_pool(text, 3 * a.pool, a.seed, a.jobs, built_dir)
        null_scores, null_groups = run_pool(identical_groups(text), 3 * a.pool, a.seed + 1, a.jobs, null_dir)
    out["synth_s"] = round(time.perf_counter() - t0, 1)
    t0 = time.perf_counter()
    built = []
    for _ in range(a.reps):
        pick = pd.concat([groups[groups == g].sample(a.per_group, random_state=rng.integers(2**31)) for g in order])
        built.append(replicate(scores, pick, order, a.alpha, a.perms, int(rng.integers(2**31))))
    null = []
    codes = null_groups.index.to_numpy()
    for _ in range(a.reps):
        pick = rng.choice(codes, size=len(order) * a.per_group, replace=False)
        labels = pd.Series(np.repeat(order, a.per_group), index=pick)
        null.append(replicate(null_scores, labels, order, a.alpha, a.perms, int(rng.integers(2**31))))
    out["replicates_s"] = round(time.perf_counter() - t0, 1)
    metrics = sorted({m for r in built for m in r["kw_holm"]})
    out["power"] = {m: float(np.mean([r["kw_holm"].get(m, False) for r in built])) for m in metrics}
    if a.perms:
        out["power_wy"] = {m: float(np.mean([r["kw_wy"].get(m, False) for r in built])) for m in metrics}
    for name, reps in (("built_in", built), ("identical", null)):
        out[name] = {}
        for key, label in (("any_kw", "any_kruskal_holm"), ("any_pair", "any_pair_holm"), ("any_kw_wy", "any_kruskal_wy"),
                           ("any_pair_wy", "any_pair_wy")):
            if key in reps[0]:
                k = sum(r[key] for r in reps)
                out[name] |= {label: k / a.reps, f"{label}_ci": wilson(k, a.reps)}
    raw = [v for r in null for v in r["kw_raw"].values()]
    out["identical"]["per_test_unadjusted"] = float(np.mean(raw))
    out["identical"]["per_test_unadjusted_ci"] = wilson(int(np.sum(raw)), len(raw))
    if a.json:
        print(json.dumps(out, indent=1))
        return
    print(f"SYNTHETIC participants: {a.per_group} per group drawn from pools of {a.pool}, {a.reps} replicate studies, alpha {a.alpha}")
    print("power per metric (Kruskal-Wallis; Holm over the family" + (", Westfall-Young" if a.perms else "") + "):")
    for m, p in sorted(out["power"].items(), key=lambda kv: -kv[1]):
        print(f"  {m:22s} {p:.3f}" + (f"  {out['power_wy'][m]:.3f}" if a.perms else ""))
    for name in ("built_in", "identical"):
        for label, v in out[name].items():
            if not label.endswith("_ci"):
                lo, hi = out[name][f"{label}_ci"]
                print(f"{name}: {label} {v:.3f} [{lo:.3f}, {hi:.3f}]")
    r = out["identical"]
    print(f"identical: per-test unadjusted rate {r['per_test_unadjusted']:.3f} "
          f"[{r['per_test_unadjusted_ci'][0]:.3f}, {r['per_test_unadjusted_ci'][1]:.3f}]")
    print(f"synth {out['synth_s']} s, replicates {out['replicates_s']} s")


if __name__ == "__main__":
    main()
