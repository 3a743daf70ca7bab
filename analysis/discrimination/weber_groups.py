"""The group test of Weber fractions across conditions (`weber_table`'s rows,
analysis/discrimination/psychometric.py): a likelihood-ratio test of a linear mixed model of ln weber with a
random intercept per participant, a rank check (Friedman, or Wilcoxon with two conditions),
and every pair of conditions (geometric-mean ratio with its interval, paired t and Wilcoxon on
ln weber, each family Holm-adjusted). Keys: docs/study.md, "The psychometric fit"."""

from __future__ import annotations

import itertools
import math
import warnings

import numpy as np
import pandas as pd
import statsmodels.api as sm
from scipy import stats

from analysis.statistics.stats import holm
from sim.jsonable import jsonable

MIN_PARTICIPANTS = 3
NAN = float("nan")


def group_test(table: pd.DataFrame, conditions: list[str] | None = None) -> dict:
    """Across conditions (keys: docs/study.md): the likelihood-ratio test of a linear
    mixed model of ln(weber) on condition with a random intercept per participant, Friedman (or
    Wilcoxon with two conditions) as the rank check, and every pair: the geometric-mean ratio
    with its interval, the paired t and the Wilcoxon signed-rank test on ln weber, each family
    Holm-adjusted. `table`: `weber_table`'s columns code, condition, weber (and converged);
    `conditions`: their order (default: sorted). Never raises on too few data: `estimable`
    False with `problems`."""
    if table.duplicated(["code", "condition"]).any():
        raise ValueError("table: a participant has two rows for one condition")
    conds = list(conditions) if conditions is not None else sorted(pd.unique(table["condition"]))
    usable = table[table["condition"].isin(conds) & np.isfinite(table["weber"].astype(float)) & (table["weber"].astype(float) > 0)]
    wide = usable.pivot(index="code", columns="condition", values="weber").reindex(columns=conds)
    complete = wide.dropna()
    out = {"conditions": conds, "n_participants": len(complete),
           "excluded": sorted(str(c) for c in set(table["code"]) - set(complete.index)), "n_not_converged": 0,
           "estimable": False, "problems": [], "mixed_model": None, "friedman": None, "pairs": []}
    if "converged" in table.columns:
        used = table[table["code"].isin(complete.index) & table["condition"].isin(conds)]
        out["n_not_converged"] = int((~used["converged"].astype(bool)).sum())
    if len(conds) < 2:
        out["problems"].append("fewer than 2 conditions")
    if len(complete) < MIN_PARTICIPANTS:
        out["problems"].append(f"fewer than {MIN_PARTICIPANTS} participants with a Weber fraction in every condition")
    if out["problems"]:
        out["pairs"] = [{"a": a, "b": b, "n": len(complete)} for a, b in itertools.combinations(conds, 2)]
        return jsonable(out)
    logw = np.log(complete.to_numpy(dtype=float))  # (participants, conditions)
    out |= {"estimable": True, "mixed_model": _mixed_lr(logw), "friedman": _rank_check(logw), "pairs": _pairs(logw, conds)}
    return jsonable(out)


def _mixed_lr(logw: np.ndarray) -> dict:
    """ML fits of ln weber ~ condition + (1 | participant) and ~ 1 + (1 | participant); the
    likelihood-ratio chi-square on k - 1 df. ML, not REML: REML likelihoods of models with
    different fixed effects are not comparable."""
    n, k = logw.shape
    y = logw.ravel()
    groups = np.repeat(np.arange(n), k)
    cond = np.tile(np.arange(k), n)
    X = np.column_stack([np.ones(n * k)] + [(cond == j).astype(float) for j in range(1, k)])
    fits = []
    for exog in (X, X[:, :1]):
        res, error = None, None
        # statsmodels' default (bfgs, then lbfgs, then cg); its lbfgs alone hits a singular
        # Hessian on some data, where Nelder-Mead still finds the maximum
        for method in (None, "nm"):
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")  # convergence and boundary notes: `converged` says what matters
                try:
                    res = sm.MixedLM(y, exog, groups=groups).fit(reml=False, **({} if method is None else {"method": method}))
                    break
                except Exception as exc:  # a flat likelihood (e.g. every value alike) raises many kinds
                    error = f"{type(exc).__name__}: {exc}"
        if res is None:
            return {"chi2": NAN, "df": k - 1, "p": NAN, "loglik": NAN, "loglik_null": NAN, "variance_participant": NAN,
                    "variance_residual": NAN, "converged": False, "n_observations": n * k, "problem": error}
        fits.append(res)
    full, null = fits
    chi2 = max(2.0 * (float(full.llf) - float(null.llf)), 0.0)  # >= 0: the models are nested
    return {"chi2": chi2, "df": k - 1, "p": float(stats.chi2.sf(chi2, k - 1)), "loglik": float(full.llf),
            "loglik_null": float(null.llf),
            "variance_participant": float(np.asarray(full.cov_re).squeeze()), "variance_residual": float(full.scale),
            "converged": bool(full.converged and null.converged), "n_observations": n * k, "problem": None}


def _rank_check(logw: np.ndarray) -> dict:
    k = logw.shape[1]
    if k >= 3:
        res = stats.friedmanchisquare(*logw.T)
        return {"test": "Friedman", "statistic": float(res.statistic), "df": k - 1, "p": float(res.pvalue)}
    stat, p = _wilcoxon(logw[:, 1], logw[:, 0])
    return {"test": "Wilcoxon signed-rank", "statistic": stat, "df": None, "p": p}


def _wilcoxon(b: np.ndarray, a: np.ndarray) -> tuple[float, float]:
    if np.all(b == a):  # no nonzero difference: nothing to rank (scipy would divide by zero)
        return 0.0, 1.0
    res = stats.wilcoxon(b, a)
    return float(res.statistic), float(res.pvalue)


def _pairs(logw: np.ndarray, conds: list[str]) -> list[dict]:
    n = logw.shape[0]
    t975 = float(stats.t.ppf(0.975, n - 1))
    pairs = []
    for (i, a), (j, b) in itertools.combinations(enumerate(conds), 2):
        d = logw[:, j] - logw[:, i]
        mean, se = float(d.mean()), float(d.std(ddof=1) / math.sqrt(n))
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # zero variance: t and p NaN, reported as None
            t = stats.ttest_rel(logw[:, j], logw[:, i])
        w, pw = _wilcoxon(logw[:, j], logw[:, i])
        pairs.append({"a": a, "b": b, "n": n, "ratio": math.exp(mean), "ratio_low": math.exp(mean - t975 * se),
                      "ratio_high": math.exp(mean + t975 * se), "t": float(t.statistic), "df": n - 1, "p": float(t.pvalue),
                      "wilcoxon": w, "p_wilcoxon": pw})
    for pair, p in zip(pairs, holm([p["p"] for p in pairs])):
        pair["p_holm"] = p
    for pair, p in zip(pairs, holm([p["p_wilcoxon"] for p in pairs])):
        pair["p_wilcoxon_holm"] = p
    return pairs
