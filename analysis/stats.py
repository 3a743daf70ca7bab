"""Paired statistics for Table 1: McNemar and Wilcoxon pairs with Holm, Friedman, effect sizes,
and the check of a published table. Tidy DataFrames with stable columns (docs/analysis.md).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats


def holm(p_values) -> list[float]:
    from statsmodels.stats.multitest import multipletests

    p = list(p_values)
    if not p:
        return []
    return [float(x) for x in multipletests(p, method="holm")[1]]  # the default is Holm-Sidak


def pairwise_mcnemar(wide: pd.DataFrame) -> pd.DataFrame:
    """Exact McNemar tests between every pair of columns of 0/1 answers (rows: participants).
    Columns: a, b, n01 (a no, b yes), n10, p_value, p_holm, odds_ratio (n10 / n01, Haldane-corrected)."""
    from statsmodels.stats.contingency_tables import mcnemar

    rows = []
    for a, b in itertools.combinations(wide.columns, 2):
        x, y = wide[a].to_numpy(int), wide[b].to_numpy(int)
        n01, n10 = int(np.sum((x == 0) & (y == 1))), int(np.sum((x == 1) & (y == 0)))
        table = [[int(np.sum((x == 1) & (y == 1))), n10], [n01, int(np.sum((x == 0) & (y == 0)))]]
        p = float(mcnemar(table, exact=True).pvalue) if n01 + n10 > 0 else 1.0
        rows.append({"a": a, "b": b, "n01": n01, "n10": n10, "p_value": p, "odds_ratio": (n10 + 0.5) / (n01 + 0.5)})
    df = pd.DataFrame(rows, columns=["a", "b", "n01", "n10", "p_value", "odds_ratio"])
    df.insert(5, "p_holm", holm(df["p_value"]))
    return df


def friedman(matrix: np.ndarray) -> dict:
    """Friedman test over columns (treatments) for rows (blocks), with and without the tie
    correction (scipy applies it), and Kendall's W (from the corrected statistic)."""
    m = np.asarray(matrix, dtype=float)
    n, k = m.shape
    ranks = np.apply_along_axis(stats.rankdata, 1, m)
    r = ranks.sum(axis=0)
    uncorrected = 12.0 / (n * k * (k + 1)) * float(np.sum(r**2)) - 3.0 * n * (k + 1)
    res = stats.friedmanchisquare(*m.T)
    return {
        "statistic": float(res.statistic), "p_value": float(res.pvalue),
        "statistic_uncorrected": uncorrected, "p_value_uncorrected": float(stats.chi2.sf(uncorrected, k - 1)),
        "df": k - 1, "n": n, "kendall_w": float(res.statistic) / (n * (k - 1)),
    }


def pairwise_wilcoxon(wide: pd.DataFrame) -> pd.DataFrame:
    """Wilcoxon signed-rank tests between every pair of columns, Holm-adjusted; effect size:
    matched-pairs rank-biserial correlation."""
    rows = []
    for a, b in itertools.combinations(wide.columns, 2):
        d = wide[a].to_numpy(float) - wide[b].to_numpy(float)
        d = d[d != 0]
        if len(d) == 0:
            rows.append({"a": a, "b": b, "statistic": 0.0, "p_value": 1.0, "rank_biserial": 0.0})
            continue
        res = stats.wilcoxon(wide[a], wide[b])
        rk = stats.rankdata(np.abs(d))
        rb = (rk[d > 0].sum() - rk[d < 0].sum()) / rk.sum()
        rows.append({"a": a, "b": b, "statistic": float(res.statistic), "p_value": float(res.pvalue), "rank_biserial": float(rb)})
    df = pd.DataFrame(rows, columns=["a", "b", "statistic", "p_value", "rank_biserial"])
    df.insert(4, "p_holm", holm(df["p_value"]))
    return df


def study_stats(db, r: pd.DataFrame | None = None, q: pd.DataFrame | None = None) -> dict:
    """Everything `studyctl report stats --json` prints (`r`, `q`: rates and cochran already
    computed by the caller, so a report does not compute them twice)."""
    from analysis.table1 import _query, answers_wide, cochran, rates, study_facts

    r = rates(db) if r is None else r
    q = cochran(db) if q is None else q
    answers = _query(db, "select code, model, item, answer from answers")
    lat = _query(db, "select s.code, l.model, avg(l.value) as value from latency l join sessions s on s.id = l.session_id "
                     "where l.measure = 'deformation_ms' group by s.code, l.model")
    protocol_models = list(dict.fromkeys(r["model"]))
    items = {}
    for item, g in r.groupby("item", sort=False):
        wide = answers_wide(answers, item, protocol_models)
        pairs = pairwise_mcnemar(wide) if len(wide) else pd.DataFrame(columns=["a", "b", "p_value", "p_holm"])
        qrow = q[q["item"] == item].iloc[0]
        items[item] = {
            "question": g["question"].iloc[0],
            "cochran_q": qrow["cochran_q"], "df": int(qrow["df"]), "p_value": qrow["p_value"], "n_complete": int(qrow["n_complete"]),
            "rates": {row["model"]: {k: row[k] for k in ("yes", "no", "rate", "wilson_low", "wilson_high")} for _, row in g.iterrows()},
            "pairs": pairs.to_dict(orient="records"),
        }
    latency = None
    wide = lat.pivot(index="code", columns="model", values="value").reindex(columns=protocol_models).dropna()
    if len(wide) >= 2 and len(protocol_models) >= 2:
        latency = {"measure": "deformation_ms", **friedman(wide.to_numpy()), "pairs": pairwise_wilcoxon(wide).to_dict(orient="records")}
    return {"facts": study_facts(db), "items": items, "latency": latency}


def _percent(text: str) -> float:
    t = text.strip().rstrip("%")
    return float(t) / 100.0


def published(path: str | Path) -> dict:
    """Check a published table (columns item, question, model, yes, no, printed_rate): every
    printed rate recomputed from its counts; what aggregated counts allow, and what not."""
    from studyctl.csvfiles import read_csv
    from studyctl.errors import InputError

    path = Path(path)
    rows = read_csv(path, ("item", "question", "model", "yes", "no", "printed_rate"), ("item", "model", "yes", "no", "printed_rate"))
    if not rows:
        raise InputError(f"{path}: no rows (only a header)")
    flags, table = [], {}
    for line, r in rows:
        try:
            yes, no, printed = int(r["yes"]), int(r["no"]), _percent(r["printed_rate"])
        except ValueError:
            raise InputError(f"{path}: line {line}: yes/no must be integers and printed_rate a percentage") from None
        if yes < 0 or no < 0 or yes + no == 0:
            raise InputError(f"{path}: line {line}: yes {yes}, no {no}: counts must be >= 0 with at least one answer")
        if not 0.0 <= printed <= 1.0:
            raise InputError(f"{path}: line {line}: printed_rate {r['printed_rate']!r} is out of range; allowed: 0%..100%")
        if (r["item"], r["model"]) in {(i, m) for i, ms in table.items() for m in ms}:
            raise InputError(f"{path}: line {line}: {r['item']}/{r['model']} appears twice")
        computed = yes / (yes + no)
        # printed to 0.1%: anything further than half a unit of the last digit disagrees
        decimals = len(r["printed_rate"].strip().rstrip("%").partition(".")[2])
        if abs(printed - computed) > 0.5 * 10 ** (-decimals - 2) + 1e-12:
            flags.append({"item": r["item"], "model": r["model"], "printed": r["printed_rate"].strip(), "computed": f"{computed:.1%}",
                          "yes": yes, "no": no, "line": line})
        table.setdefault(r["item"], {})[r["model"]] = (yes, no)
    homogeneity = []
    for item, by_model in table.items():
        counts = np.array([[y, n] for y, n in by_model.values()])
        note = "chi-square homogeneity of the models' yes rates; ignores that the same participants rated every model"
        if len(counts) < 2 or (counts.sum(axis=0) == 0).any():  # one model, or every answer alike: nothing to test
            homogeneity.append({"item": item, "chi2": float("nan"), "df": max(len(counts) - 1, 0), "p_value": float("nan"),
                                "note": "not computable: " + ("one model" if len(counts) < 2 else "every answer was the same")})
            continue
        chi2, p, dof, _ = stats.chi2_contingency(counts, correction=False)
        homogeneity.append({"item": item, "chi2": float(chi2), "df": int(dof), "p_value": float(p), "note": note})
    return {
        "table": str(path), "rows": len(rows), "flags": flags, "homogeneity": homogeneity,
        "not_computable": "Cochran's Q and McNemar tests need each participant's answers to every model (paired data); "
                          "aggregated counts do not give them, and intervals for differences between models need them too.",
    }


__all__ = ["holm", "pairwise_mcnemar", "friedman", "pairwise_wilcoxon", "study_stats", "published"]
