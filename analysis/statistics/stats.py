"""Paired statistics for Table 1: McNemar and Wilcoxon pairs with Holm, Friedman, effect sizes,
and the check of a published table. Tidy DataFrames with stable columns (docs/analysis.md).
"""

from __future__ import annotations

import itertools
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import statsmodels.api as sm
import statsmodels.formula.api as smf
from scipy import stats
from scipy.stats import binomtest
from statsmodels.stats.contingency_tables import mcnemar
from statsmodels.stats.proportion import proportion_confint

from analysis.errors import InputError
from analysis.statistics.withhold import pair_reason, pair_warning
from analysis.study.csvfiles import read_csv

NAN = float("nan")


def holm(p_values) -> list[float]:
    """Holm's step-down adjusted p-values, in the given order (statsmodels' `multipletests(p,
    method="holm")`, which the tests check it against; that one runs a full garbage collection
    on every call, half of a `plan` simulated study's time)."""
    p = np.asarray(list(p_values), dtype=float)
    if not p.size:
        return []
    # a test withheld (NaN: its prerequisites did not hold, analysis/statistics/withhold.py) is not in the
    # family: the others are adjusted over the tests actually run
    tested = np.flatnonzero(np.isfinite(p))
    adjusted = np.full_like(p, np.nan)
    q = p[tested]
    order = np.argsort(q)
    out = np.empty_like(q)
    out[order] = np.minimum(np.maximum.accumulate(q[order] * np.arange(q.size, 0, -1)), 1.0)
    adjusted[tested] = out
    return [float(x) for x in adjusted]


def holm_family(per_question: list[list[float]], scope: str = "family") -> list[list[dict]]:
    """Each pairwise test's Holm p-values, a list per question as `per_question` gives their
    p-values: within its question (`p_holm_question`), over the whole family
    (`p_holm_family`), and the one the reports print (`p_holm`: the family's, or the question's
    when `scope` is "question")."""
    within = [holm(ps) for ps in per_question]
    family = iter(holm([p for ps in per_question for p in ps]))
    out = []
    for ps in within:
        row = []
        for q in ps:
            f = next(family)
            row.append({"p_holm_question": q, "p_holm_family": f, "p_holm": f if scope == "family" else q})
        out.append(row)
    return out


def named(pair: dict, test: str, problems=()) -> dict:
    """What a pair lacks to name its test (`test`) and, one that could not be made, why
    (`reason`), as the rank and McNemar tests already do."""
    out = {} if "test" in pair else {"test": test}
    if "reason" not in pair and (pair.get("p_value") is None or not np.isfinite(pair["p_value"])):
        out["reason"] = "; ".join(problems) or "not estimable"
    return out


def records(df: pd.DataFrame) -> list[dict]:
    """A table's rows as dicts, a missing text (a reason, a warning) as None, never a float nan
    a report would print."""
    out = df.to_dict(orient="records")
    text = [c for c in df.columns if not pd.api.types.is_numeric_dtype(df[c])]  # object or pandas' string dtype
    for row in out:
        for c in text:
            if isinstance(row[c], float) and not np.isfinite(row[c]):
                row[c] = None
    return out


def tests_run(pairs) -> int:
    """How many of these pairwise tests (analysis/statistics/result_records.py) were run (a finite p-value): the
    size of the Holm family that `holm_family` adjusts over, as every report counts it."""
    return sum(1 for p in pairs if p.p_value is not None and np.isfinite(p.p_value))


def wilson(yes: int, n: int, alpha: float = 0.05) -> tuple[float, float]:
    """Wilson interval of a proportion (NaN for no observations)."""
    if n == 0:
        return (float("nan"), float("nan"))
    lo, hi = proportion_confint(yes, n, alpha=alpha, method="wilson")  # the default is the normal interval
    return float(lo), float(hi)


def pairwise_mcnemar(wide: pd.DataFrame) -> pd.DataFrame:
    """Exact McNemar tests between every pair of columns of 0/1 answers (rows: participants).
    Columns: a, b, n01 (a no, b yes), n10, p_value, p_holm, odds_ratio (n10 / n01, Haldane-corrected)."""
    rows = []
    for a, b in itertools.combinations(wide.columns, 2):
        x, y = wide[a].to_numpy(int), wide[b].to_numpy(int)
        n01, n10 = int(np.sum((x == 0) & (y == 1))), int(np.sum((x == 1) & (y == 0)))
        table = [[int(np.sum((x == 1) & (y == 1))), n10], [n01, int(np.sum((x == 0) & (y == 0)))]]
        # one participant cannot be tested (as Cochran's Q in the same row says), discordant or not
        reason = (pair_reason(len(wide)) if len(wide) < 2 else
                  None if n01 + n10 > 0 else "no participant answered the two differently: nothing to test")
        p = float(mcnemar(table, exact=True).pvalue) if reason is None else NAN
        rows.append({"a": a, "b": b, "test": "exact McNemar", "n01": n01, "n10": n10, "p_value": p,
                     "odds_ratio": (n10 + 0.5) / (n01 + 0.5), "reason": reason})
    df = pd.DataFrame(rows, columns=["a", "b", "test", "n01", "n10", "p_value", "odds_ratio", "reason"])
    df.insert(6, "p_holm", holm(df["p_value"]))
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


WILCOXON = "Wilcoxon signed-rank (statistic: the smaller signed-rank sum)"


def pairwise_wilcoxon(wide: pd.DataFrame) -> pd.DataFrame:
    """Wilcoxon signed-rank tests between every pair of columns, Holm-adjusted; effect size:
    matched-pairs rank-biserial correlation."""
    rows = []
    for a, b in itertools.combinations(wide.columns, 2):
        d = wide[a].to_numpy(float) - wide[b].to_numpy(float)
        reason = pair_reason(len(d), d)
        d = d[d != 0]
        row = {"a": a, "b": b, "test": WILCOXON, "statistic": NAN, "p_value": NAN, "rank_biserial": NAN, "reason": reason, "warning": None}
        if reason is not None:
            if len(d) == 0 and len(wide) >= 2:  # no pair differs: the effect is none, the test has nothing to rank
                row["rank_biserial"] = 0.0
            rows.append(row)
            continue
        res = stats.wilcoxon(wide[a], wide[b])
        rk = stats.rankdata(np.abs(d))
        rb = (rk[d > 0].sum() - rk[d < 0].sum()) / rk.sum()
        rows.append(row | {"statistic": float(res.statistic), "p_value": float(res.pvalue), "rank_biserial": float(rb),
                           "warning": pair_warning(len(d))})
    df = pd.DataFrame(rows, columns=["a", "b", "test", "statistic", "p_value", "rank_biserial", "reason", "warning"])
    df.insert(5, "p_holm", holm(df["p_value"]))
    return df


HOLM_SCOPES = ("family", "question")
MIN_GEE_PARTICIPANTS = 5  # a sandwich covariance from fewer clusters is not worth printing


def gee_fit(df: pd.DataFrame, models: list[str], with_period: bool = True, with_item: bool = False) -> dict:
    """Logistic GEE (statsmodels): answer ~ model [+ period] [+ item], participants as
    clusters, exchangeable working correlation, robust (sandwich) covariance. Returns the
    odds ratio of every pair of models (b vs a: the odds of yes with b over those with a) with
    its 95% interval and Wald p-value, the working correlation, and whether it converged."""
    data = df.copy()
    data["model"] = pd.Categorical(data["model"], categories=models)
    terms = ["C(model)"] + (["C(period)"] if with_period else []) + (["C(item)"] if with_item else [])
    data = data.sort_values(["code"]).reset_index(drop=True)
    out = {"formula": "answer ~ " + " + ".join(terms), "n_participants": int(data["code"].nunique()), "n_answers": int(len(data)),
           "correlation": "exchangeable", "covariance": "robust (sandwich)"}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            model = smf.gee(out["formula"], groups="code", data=data, family=sm.families.Binomial(), cov_struct=sm.cov_struct.Exchangeable())
            res = model.fit(maxiter=100)
        except (ValueError, np.linalg.LinAlgError) as exc:  # e.g. every answer alike
            return out | {"converged": False, "estimable": False, "problems": [str(exc)], "pairs": []}
    names = list(res.params.index)
    cov = res.cov_params().to_numpy()
    beta = res.params.to_numpy()

    def coef(m):
        v = np.zeros(len(names))
        if m != models[0]:
            v[names.index(f"C(model)[T.{m}]")] = 1.0
        return v

    pairs = []
    for a, b in itertools.combinations(models, 2):
        c = coef(b) - coef(a)
        est, se = float(c @ beta), float(np.sqrt(max(c @ cov @ c, 0.0)))
        z = est / se if se > 0 else float("nan")
        p = float(2 * stats.norm.sf(abs(z))) if np.isfinite(z) else float("nan")
        with np.errstate(over="ignore"):  # separation in small data: huge log-odds, an infinite odds ratio
            pairs.append({"a": a, "b": b, "log_odds_ratio": est, "se": se, "odds_ratio": float(np.exp(est)),
                          "ci_low": float(np.exp(est - 1.959963984540054 * se)), "ci_high": float(np.exp(est + 1.959963984540054 * se)),
                          "p_value": p})
    converged = bool(getattr(res, "converged", True)) and not any("converge" in str(w.message).lower() for w in caught)
    # not estimable: a model whose answers are all yes or all no (separation: the odds ratio is
    # infinite and the Wald test meaningless), a zero or non-finite standard error, |log OR| > 10,
    # or too few participants for a sandwich covariance
    constant = {m for m, g in data.groupby("model", observed=True)["answer"] if g.nunique() < 2}
    problems = []
    if out["n_participants"] < MIN_GEE_PARTICIPANTS:
        problems.append(f"fewer than {MIN_GEE_PARTICIPANTS} participants")
    if constant:
        problems.append("every answer alike for " + ", ".join(sorted(constant)))
    for pair in pairs:
        bad = problems or pair["a"] in constant or pair["b"] in constant or not (pair["se"] > 0 and np.isfinite(pair["se"])) \
            or not abs(pair["log_odds_ratio"]) <= 10.0
        pair["estimable"] = not bad
        if bad:
            pair |= {"ci_low": float("nan"), "ci_high": float("nan"), "p_value": float("nan")}
    if any(not p["estimable"] for p in pairs) and not problems:
        problems.append("separation or a zero standard error")
    return out | {"converged": converged and not problems, "estimable": not problems, "problems": problems,
                  "working_correlation": float(res.cov_struct.dep_params), "pairs": pairs}


def max_cochran_q(yes: list[int], n: int) -> float:
    """The largest Cochran's Q that any pairing of `n` participants' answers can give with
    these yes counts per model (the margins). Q = (k-1)(k sum C_j^2 - T^2) / (k T - sum R_i^2)
    has fixed column totals C_j and total T, so it is largest when sum R_i^2 is: the row
    totals most spread out that the margins allow, the conjugate of the column totals
    (participant i says yes to model j when i <= C_j; Gale-Ryser: every feasible row-sum
    vector is majorised by it, and sum R^2 is Schur-convex)."""
    k, T = len(yes), int(sum(yes))
    rows = [sum(1 for c in yes if c >= i) for i in range(1, n + 1)]
    den = k * T - sum(r * r for r in rows)
    num = (k - 1) * (k * sum(c * c for c in yes) - T * T)
    if den == 0:
        return 0.0 if num == 0 else float("inf")
    return num / den


def min_mcnemar_p(a: int, b: int, n: int) -> float:
    """The smallest exact McNemar p-value any pairing can give two models with `a` and `b`
    yes of `n` (searched over every feasible number of discordant pairs)."""
    best = 1.0
    for n01 in range(0, min(n - a, b) + 1):  # a no, b yes
        n10 = a - b + n01
        if n10 < 0 or n10 > min(a, n - b):
            continue
        m = n01 + n10
        if m:
            best = min(best, float(binomtest(min(n01, n10), m, 0.5).pvalue))
    return best


def margin_bounds(table: dict[str, dict[str, tuple[int, int]]]) -> dict:
    """What the margins (yes/no per question and model) allow, whatever the pairing: the
    smallest possible Cochran's Q p-value per question, and the smallest possible exact
    McNemar p-value per pair, with Holm over the whole family of pairs (Holm is monotone in
    every p-value, so these bound the adjusted p-values from below)."""
    cochran_rows, pairs = [], []
    for item, by_model in table.items():
        ns = {y + no for y, no in by_model.values()}
        if len(by_model) < 2 or len(ns) != 1:
            cochran_rows.append({"item": item, "q_max": float("nan"), "p_min": float("nan"),
                                 "note": "not computable: " + ("one model" if len(by_model) < 2 else "models answered by different numbers")})
            continue
        n = ns.pop()
        yes = [y for y, _ in by_model.values()]
        q = max_cochran_q(yes, n)
        cochran_rows.append({"item": item, "n": n, "q_max": q, "df": len(yes) - 1, "p_min": float(stats.chi2.sf(q, len(yes) - 1)), "note": ""})
        for (ma, (ya, _)), (mb, (yb, _)) in itertools.combinations(by_model.items(), 2):
            pairs.append({"item": item, "a": ma, "b": mb, "yes_a": ya, "yes_b": yb, "n": n, "p_min": min_mcnemar_p(ya, yb, n)})
    for pair, p in zip(pairs, holm([x["p_min"] for x in pairs])):
        pair["p_min_holm"] = p
    return {"cochran": cochran_rows, "mcnemar": pairs,
            "note": "bounds over every pairing of the participants' answers consistent with the printed counts: the smallest "
                    "p-values the paired tests could have given; Holm over all pairwise tests of the table"}


def _percent(text: str) -> float:
    t = text.strip().rstrip("%")
    return float(t) / 100.0


def published(path: str | Path) -> dict:
    """Check a published table (columns item, question, model, yes, no, printed_rate): every
    printed rate recomputed from its counts; what aggregated counts allow, and what not."""
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
        "bounds": margin_bounds(table),
        "not_computable": "the exact Cochran's Q and McNemar p-values and intervals for differences between models need each "
                          "participant's paired answers; the counts bound them (`bounds`): no pairing gives smaller p-values.",
    }


__all__ = ["holm", "holm_family", "named", "wilson", "pairwise_mcnemar", "friedman", "pairwise_wilcoxon", "gee_fit", "margin_bounds", "published"]
