"""Statistics for rating-scale (Likert), continuous and choice answers of a within-subject study:
a proportional-odds GEE (the primary analysis of Likert items), a linear mixed model, bootstrap
intervals for the rank effect sizes, the analysis of a "which condition felt most X" question,
and small helpers for report tables. Tidy outputs with stable keys, as in analysis/statistics/stats.py.

Input answers: a DataFrame with columns code (participant), model (condition), item (question
id), answer (numeric) and, optionally, period (0-based position of that condition in the
participant's session). `models`: the condition names in protocol order; every pair is
(a, b) in `itertools.combinations(models, 2)` order and its effect is b against a.
"""

from __future__ import annotations

import inspect
import itertools
import math
import warnings

import numpy as np
import pandas as pd
import statsmodels.api as sm
from scipy import stats
from scipy.special import gammaln
from statsmodels.genmod import cov_struct
from statsmodels.genmod.generalized_estimating_equations import OrdinalGEE
from statsmodels.stats.proportion import proportion_confint
from statsmodels.tools.sm_exceptions import ConvergenceWarning, IterationLimitWarning

from analysis.statistics.stats import MIN_GEE_PARTICIPANTS, friedman, pairwise_wilcoxon
from analysis.statistics.withhold import mean_ci, model_reason

Z95 = 1.959963984540054
MAX_LOG_OR = 10.0  # beyond this a log odds ratio is separation, not an estimate (as in gee_fit)
BOOTSTRAP_RESAMPLES = 9999
BOOTSTRAP_SEED = 2015  # fixed: a report computed twice prints the same intervals
MAX_MULTINOMIAL_OUTCOMES = 200_000  # enumerate the exact multinomial test up to this many tables
DEPENDENCE = {"global_odds_ratio": "global odds ratio (ordinal)", "independence": "independence"}
NAN = float("nan")


# --- design matrices shared by the GEE and the mixed model --------------------------------------

def _answers(df: pd.DataFrame, models: list[str], with_period: bool) -> tuple[pd.DataFrame, list[str]]:
    """Rows with an answer for one of `models`, sorted by participant (clusters contiguous);
    notes on what was left out."""
    notes = []
    data = df[df["model"].isin(models)].copy()
    missing = int(data["answer"].isna().sum())
    if missing:
        notes.append(f"{missing} missing answers left out")
    data = data[data["answer"].notna()]
    if with_period and "period" not in data.columns:
        raise ValueError("with_period needs a `period` column (analysis.statistics.stats.periods)")
    if with_period and data["period"].isna().any():
        notes.append(f"{int(data['period'].isna().sum())} answers without a period left out")
        data = data[data["period"].notna()]
    data["answer"] = data["answer"].astype(float)
    sort = ["code", "model"] + (["period"] if with_period else []) + (["item"] if "item" in data.columns else [])
    return data.sort_values(sort, kind="stable").reset_index(drop=True), notes


def _dummies(values: pd.Series, name: str, levels: list) -> pd.DataFrame:
    """Treatment coding with the first of `levels` as reference, named like patsy's C(name)[T.level]."""
    return pd.DataFrame({f"C({name})[T.{lv}]": (values == lv).to_numpy(float) for lv in levels[1:]}, index=values.index)


def _design(data: pd.DataFrame, present: list[str], with_period: bool, with_item: bool, intercept: bool) -> pd.DataFrame:
    parts = [pd.DataFrame({"Intercept": np.ones(len(data))}, index=data.index)] if intercept else []
    parts.append(_dummies(data["model"], "model", present))
    if with_period:
        parts.append(_dummies(data["period"].astype(int), "period", sorted(data["period"].astype(int).unique())))
    if with_item:
        parts.append(_dummies(data["item"], "item", list(pd.unique(data["item"]))))
    return pd.concat(parts, axis=1)


SINGULAR = "the design is singular: model confounded with period or item (e.g. every participant in one order)"


def _singular(X: pd.DataFrame) -> bool:
    """Whether the fixed effects (with an intercept, the thresholds' role in the ordinal model) are not identifiable."""
    A = np.column_stack([np.ones(len(X)), X.drop(columns="Intercept", errors="ignore").to_numpy()])
    return bool(np.linalg.matrix_rank(A) < A.shape[1])


def _model_vector(names: list[str], present: list[str], m: str) -> np.ndarray:
    """The coefficient vector picking model m's effect against the reference (the first present model)."""
    v = np.zeros(len(names))
    if m != present[0]:
        v[names.index(f"C(model)[T.{m}]")] = 1.0
    return v


def _formula(terms_from: str, with_period: bool, with_item: bool) -> str:
    return f"{terms_from} ~ " + " + ".join(["C(model)"] + (["C(period)"] if with_period else []) + (["C(item)"] if with_item else []))


def _nan_pairs(models: list[str], keys: tuple[str, ...]) -> list[dict]:
    return [{"a": a, "b": b} | dict.fromkeys(keys, NAN) | {"estimable": False} for a, b in itertools.combinations(models, 2)]


def _is_convergence_warning(w: warnings.WarningMessage) -> bool:
    return issubclass(w.category, (ConvergenceWarning, IterationLimitWarning)) and "boundary" not in str(w.message).lower()


# --- 1. proportional-odds GEE --------------------------------------------------------------------

ORDINAL_PAIR_KEYS = ("log_odds_ratio", "se", "odds_ratio", "ci_low", "ci_high", "p_value")


def ordinal_gee(df: pd.DataFrame, models: list[str], with_period: bool = True, with_item: bool = True,
                dependence: str = "global_odds_ratio") -> dict:
    """The primary analysis of Likert items: a cumulative-logit (proportional odds) marginal
    model fitted by GEE (statsmodels OrdinalGEE), answer ~ C(model) [+ C(period)] [+ C(item)],
    participants as clusters, robust (sandwich) covariance. Ordinal, so it needs no interval
    scale and no normal residuals; marginal, so its odds ratios are population-averaged; the
    sandwich keeps the inference valid whatever the within-participant dependence.

    Sign convention (checked against statsmodels' source): OrdinalGEE expands each answer y into
    the indicators 1{y > c} for every observed category c but the highest, and models
    logit P(y > c) = alpha_c + x'beta. A positive coefficient therefore means HIGHER ratings;
    each pair's odds_ratio = exp(beta_b - beta_a) is the cumulative odds of a higher rating
    (above any cut) with b over those with a, the same for every cut (proportional odds). The
    same sign as R's MASS::polr and ordinal::clm; the opposite of SAS PROC LOGISTIC's default.

    Working dependence: `dependence="global_odds_ratio"` (default; Heagerty and Zeger 1996:
    one odds ratio between the indicators of two answers of a participant) or "independence"
    (statsmodels' OrdinalIndependence: answers independent, one answer's indicators with their
    multinomial covariance; its estimates are the proportional-odds maximum-likelihood ones,
    whereas plain Independence, which treats one answer's indicators as independent, is not).
    When the global odds ratio fit fails (an error, non-finite estimates, or no convergence), the
    fit falls back to independence and `fallback` says why. Not estimable (pairs with NaN
    interval and p): fewer than MIN_GEE_PARTICIPANTS participants, every answer alike, a model
    whose answers are all one category (separation), |log OR| > 10 or a non-finite or zero
    standard error. Never raises on degenerate data."""
    if dependence not in DEPENDENCE:
        raise ValueError(f"dependence: {dependence!r}; allowed: {', '.join(DEPENDENCE)}")
    data, notes = _answers(df, models, with_period)
    with_item = with_item and "item" in data.columns
    out = {"formula": _formula("answer", with_period, with_item), "n_participants": int(data["code"].nunique()),
           "n_answers": int(len(data)), "working_dependence": DEPENDENCE[dependence], "fallback": None,
           "covariance": "bias-reduced sandwich (Mancl and DeRouen 2001), t with participants - 1 df", "global_odds_ratio": NAN,
           "notes": notes}
    present = [m for m in models if (data["model"] == m).any()]
    constant = {m for m, g in data.groupby("model")["answer"] if g.nunique() < 2}
    problems = _ordinal_problems(data, models, present, constant, out["n_participants"])
    if data["answer"].nunique() < 2 or len(present) < 2:
        return _not_estimable(out, problems, models)
    X = _design(data, present, with_period, with_item, intercept=False)
    if _singular(X):
        return _not_estimable(out, problems + [SINGULAR], models)
    res, caught, error = _fit_ordinal_or_independence(data, X, dependence, out)
    if res is None:
        return _not_estimable(out, problems + [f"fit failed: {error}"], models)
    if out["working_dependence"] == DEPENDENCE["global_odds_ratio"]:
        out["global_odds_ratio"] = float(np.squeeze(res.cov_struct.dep_params))
    pairs = _ordinal_pairs(res, models, present, out["n_participants"])
    _mark_estimable(pairs, problems, constant)
    if any(not p["estimable"] for p in pairs) and not problems:
        problems.append("separation or a zero standard error")
    converged = not any(_is_convergence_warning(w) for w in caught)
    return out | {"converged": converged and not problems, "estimable": not problems, "problems": problems, "pairs": pairs}


def _ordinal_problems(data: pd.DataFrame, models: list[str], present: list[str], constant: set[str], n_participants: int) -> list[str]:
    """Why the answers cannot give estimable odds ratios (empty: they can)."""
    problems = []
    if n_participants < MIN_GEE_PARTICIPANTS:
        problems.append(f"fewer than {MIN_GEE_PARTICIPANTS} participants")
    if data["answer"].nunique() < 2:
        problems.append("every answer alike" if len(data) else "no answers")
    if absent := [m for m in models if m not in present]:
        problems.append("no answers for " + ", ".join(absent))
    if constant and data["answer"].nunique() > 1:
        problems.append("every answer one category for " + ", ".join(m for m in models if m in constant))
    return problems


def _not_estimable(out: dict, problems: list[str], models: list[str]) -> dict:
    return out | {"converged": False, "estimable": False, "problems": problems, "pairs": _nan_pairs(models, ORDINAL_PAIR_KEYS)}


def _fit_ordinal_or_independence(data: pd.DataFrame, X: pd.DataFrame, dependence: str, out: dict):
    """`_fit_ordinal`; a failed global odds ratio fit is fitted again with independence, and
    `out` (working_dependence, fallback) says so."""
    res, caught, error = _fit_ordinal(data, X, dependence)
    if dependence == "global_odds_ratio" and (res is None or not _fit_ok(res, caught)):
        why = error or ("no convergence" if res is not None and caught else "non-finite estimates")
        out |= {"working_dependence": DEPENDENCE["independence"], "fallback": f"global odds ratio failed ({why}); fitted with independence"}
        res, caught, error = _fit_ordinal(data, X, "independence")
    return res, caught, error


def _ordinal_pairs(res, models: list[str], present: list[str], n_participants: int) -> list[dict]:
    """Each pair's log odds ratio b against a, with its t interval and p (NaN for an absent model)."""
    names, beta, cov = list(res.params.index), res.params.to_numpy(), res.cov_params().to_numpy()
    # t with participants - 1 df, not z: with the bias-reduced sandwich it holds the null's
    # false-positive rate at 12-24 participants (plan --null; z and the plain sandwich gave 0.105)
    dof = max(n_participants - 1, 1)
    t95 = float(stats.t.ppf(0.975, dof))
    pairs = []
    for a, b in itertools.combinations(models, 2):
        if a not in present or b not in present:
            pairs.append(_nan_pairs([a, b], ORDINAL_PAIR_KEYS)[0])
            continue
        c = _model_vector(names, present, b) - _model_vector(names, present, a)
        est, var = float(c @ beta), float(c @ cov @ c)
        se = math.sqrt(var) if np.isfinite(var) and var > 0 else NAN
        with np.errstate(over="ignore"):  # separation in small data: a huge log odds ratio
            pairs.append({"a": a, "b": b, "log_odds_ratio": est, "se": se, "odds_ratio": float(np.exp(est)),
                          "ci_low": float(np.exp(est - t95 * se)), "ci_high": float(np.exp(est + t95 * se)),
                          "p_value": float(2 * stats.t.sf(abs(est / se), dof)) if se > 0 else NAN})
    return pairs


def _mark_estimable(pairs: list[dict], problems: list[str], constant: set[str]) -> None:
    """A pair is estimable with no problems, neither model's answers all one category, a positive
    standard error and |log OR| <= MAX_LOG_OR; the others' interval and p become NaN."""
    for pair in pairs:
        if problems or pair["a"] in constant or pair["b"] in constant or not (pair["se"] > 0) or not abs(pair["log_odds_ratio"]) <= MAX_LOG_OR:
            pair |= {"ci_low": NAN, "ci_high": NAN, "p_value": NAN, "estimable": False}
        else:
            pair["estimable"] = True


def _fit_ordinal(data: pd.DataFrame, X: pd.DataFrame, dependence: str):
    """(results or None, convergence warnings caught, error text or None)."""
    dep = cov_struct.GlobalOddsRatio("ordinal") if dependence == "global_odds_ratio" else cov_struct.OrdinalIndependence()
    with warnings.catch_warnings(record=True) as caught, np.errstate(all="ignore"):
        warnings.simplefilter("always")
        try:
            # Mancl and DeRouen's (2001) bias-reduced sandwich: the plain one is too small with few clusters
            res = OrdinalGEE(data["answer"], X, groups=data["code"].to_numpy(), cov_struct=dep).fit(maxiter=200, cov_type="bias_reduced")
        except Exception as exc:  # statsmodels raises many kinds on degenerate data
            return None, [], f"{type(exc).__name__}: {exc}"
    return res, [w for w in caught if _is_convergence_warning(w)], None


def _fit_ok(res, caught) -> bool:
    return not caught and bool(np.all(np.isfinite(res.params))) and bool(np.all(np.isfinite(res.cov_params().to_numpy())))


# --- 2. linear mixed model -----------------------------------------------------------------------

MIXED_PAIR_KEYS = ("difference", "se", "ci_low", "ci_high", "p_value")


MIXED_TEST = "Wald test of the condition in the linear mixed model (F with between-within df)"


def mixed_model(df: pd.DataFrame, models: list[str], with_period: bool = True) -> dict:
    """Linear mixed model (statsmodels MixedLM, REML): answer ~ C(model) [+ C(period)] with a
    random intercept per participant; for continuous answers, or as the parametric companion
    of the ordinal GEE on a scale score. Several answers of a participant for one model (items)
    count as replicates; pass one item, or each participant's score, for a per-item analysis.

    Small-sample inference: statsmodels gives z statistics; here the model test is the Wald
    chi-square (chi2, df, p_value) and its F form (f = chi2 / df) against the between-within
    denominator df (n_answers - n_participants - (fixed effects - 1)), which in a balanced
    design with one answer per participant and model, and a positive participant variance, is
    exactly the repeated-measures ANOVA F test. Pair differences (b - a) use the t distribution
    with the same df (in that balanced case: the classical pooled-error contrast).
    `means`: estimated marginal means per model, averaged over the period levels with equal
    weights (the emmeans convention, so a period imbalance does not leak into a model's mean),
    with a t interval on n_participants - 1 df (a mean's variance is mostly between
    participants). NaN where not computable; never raises on degenerate data."""
    data, notes = _answers(df, models, with_period)
    out = {"formula": _formula("answer", with_period, False) + " + (1 | code)", "n_participants": int(data["code"].nunique()),
           "n_answers": int(len(data)), "method": "REML", "notes": notes}
    present = [m for m in models if (data["model"] == m).any()]
    problems = []
    if out["n_participants"] < 2:
        problems.append("fewer than 2 participants")
    if len(data) and data["answer"].nunique() < 2:
        problems.append("every answer alike")
    if absent := [m for m in models if m not in present]:
        problems.append("no answers for " + ", ".join(absent))
    empty = {"converged": False, "estimable": False, "problems": problems, "variance_participant": NAN, "variance_residual": NAN,
             "model_test": dict.fromkeys(("chi2", "df", "p_value", "f", "df_denominator", "p_value_f"), NAN)
             | {"test": MIXED_TEST, "reason": "; ".join(problems) or "not estimable"},
             "means": {m: {"mean": NAN, "se": NAN, "ci_low": NAN, "ci_high": NAN} for m in models},
             "pairs": _nan_pairs(models, MIXED_PAIR_KEYS)}
    if out["n_participants"] < 2 or len(present) < 2 or data["answer"].nunique() < 2:
        return out | empty
    X = _design(data, present, with_period, False, intercept=True)
    if _singular(X):
        return out | empty | {"problems": problems + [SINGULAR], "model_test": empty["model_test"] | {"reason": SINGULAR}}
    res, caught, error = _fit_mixed(data, X)
    if res is None:
        return out | empty | {"problems": problems + [f"fit failed: {error}"], "model_test": empty["model_test"] | {"reason": f"fit failed: {error}"}}
    names, k = list(X.columns), X.shape[1]
    beta = np.asarray(res.fe_params, dtype=float)
    cov = np.asarray(res.cov_params(), dtype=float)[:k, :k]
    df_den = out["n_answers"] - out["n_participants"] - (k - 1)
    if any("boundary" in str(w.message).lower() for w in caught):
        notes.append("participant variance on the boundary (0): the fit is an ordinary regression")
    # statsmodels warns as it retries other optimisers; res.converged is the final fit's word
    converged = bool(res.converged) and bool(np.isfinite(cov).all()) and not problems
    test = _wald([_model_vector(names, present, m) for m in present[1:]], beta, cov, df_den)
    reason = model_reason(converged, df_den, out["n_participants"])
    if reason is not None:  # no F or p from a fit that did not converge or has no residual df
        test |= {"chi2": NAN, "p_value": NAN, "f": NAN, "p_value_f": NAN}
    out |= {"converged": converged, "variance_participant": float(np.asarray(res.cov_re).squeeze()), "variance_residual": float(res.scale),
            "model_test": test | {"test": MIXED_TEST, "reason": reason}}
    period_mix = np.zeros(k)  # equal weights over the period levels: each period dummy's mean
    if with_period:
        levels = data["period"].astype(int).nunique()
        period_mix[[i for i, nm in enumerate(names) if nm.startswith("C(period)")]] = 1.0 / levels
    t_mean = stats.t.ppf(0.975, out["n_participants"] - 1)
    means = {}
    for m in models:
        if m not in present:
            means[m] = {"mean": NAN, "se": NAN, "ci_low": NAN, "ci_high": NAN}
            continue
        x = period_mix + _model_vector(names, present, m)
        x[0] = 1.0
        est, se = float(x @ beta), _se(x, cov)
        means[m] = {"mean": est, "se": se, "ci_low": est - t_mean * se, "ci_high": est + t_mean * se}
    pairs = []
    t_pair = stats.t.ppf(0.975, df_den) if df_den > 0 else NAN
    for a, b in itertools.combinations(models, 2):
        if a not in present or b not in present:
            pairs.append(_nan_pairs([a, b], MIXED_PAIR_KEYS)[0])
            continue
        c = _model_vector(names, present, b) - _model_vector(names, present, a)
        est, se = float(c @ beta), _se(c, cov)
        ok = se > 0 and df_den > 0 and not problems
        pairs.append({"a": a, "b": b, "difference": est, "se": se,
                      "ci_low": est - t_pair * se if ok else NAN, "ci_high": est + t_pair * se if ok else NAN,
                      "p_value": float(2 * stats.t.sf(abs(est / se), df_den)) if ok else NAN, "estimable": bool(ok)})
    return out | {"estimable": not problems, "problems": problems, "means": means, "pairs": pairs}


def _fit_mixed(data: pd.DataFrame, X: pd.DataFrame):
    with warnings.catch_warnings(record=True) as caught, np.errstate(all="ignore"):
        warnings.simplefilter("always")
        try:
            res = sm.MixedLM(data["answer"], X, groups=data["code"].to_numpy()).fit(reml=True)
        except Exception as exc:  # singular designs and flat likelihoods raise many kinds
            return None, [], f"{type(exc).__name__}: {exc}"
    return res, list(caught), None


def _se(c: np.ndarray, cov: np.ndarray) -> float:
    var = float(c @ cov @ c)
    return math.sqrt(var) if np.isfinite(var) and var > 0 else NAN


def _wald(rows: list[np.ndarray], beta: np.ndarray, cov: np.ndarray, df_den: int) -> dict:
    """Joint Wald test of L beta = 0, as chi-square and as F on (rank, df_den)."""
    L = np.array(rows)
    try:
        Lb, V = L @ beta, L @ cov @ L.T
        chi2 = float(Lb @ np.linalg.solve(V, Lb))
    except np.linalg.LinAlgError:
        chi2 = NAN
    q = len(rows)
    ok = np.isfinite(chi2) and chi2 >= 0
    f = chi2 / q if ok else NAN
    return {"chi2": chi2 if ok else NAN, "df": q, "p_value": float(stats.chi2.sf(chi2, q)) if ok else NAN,
            "f": f, "df_denominator": df_den, "p_value_f": float(stats.f.sf(f, q, df_den)) if ok and df_den > 0 else NAN}


# --- 3. intervals for the rank effect sizes ------------------------------------------------------

PERCENTILE_METHOD = f"percentile bootstrap over participants ({BOOTSTRAP_RESAMPLES} resamples, seed {BOOTSTRAP_SEED})"
BOOTSTRAP_METHOD = f"BCa bootstrap over participants ({BOOTSTRAP_RESAMPLES} resamples, seed {BOOTSTRAP_SEED})"


def _rank_biserial(d: np.ndarray, axis: int = -1) -> np.ndarray:
    """Matched-pairs rank-biserial correlation of differences d along `axis`, vectorised, the
    same definition as analysis.statistics.stats.pairwise_wilcoxon: zero differences dropped, then
    (sum of ranks of |d| with d > 0 - those with d < 0) / all ranks; 0 when every d is 0."""
    d = np.moveaxis(np.asarray(d, dtype=float), axis, -1)
    rk = stats.rankdata(np.where(d == 0, np.nan, np.abs(d)), axis=-1, nan_policy="omit")
    pos = np.where(d > 0, rk, 0.0).sum(axis=-1)
    neg = np.where(d < 0, rk, 0.0).sum(axis=-1)
    total = pos + neg
    return np.where(total > 0, (pos - neg) / np.where(total > 0, total, 1.0), 0.0)


_RNG = "rng" if "rng" in inspect.signature(stats.bootstrap).parameters else "random_state"  # scipy < 1.15: random_state


def _bootstrap(data: tuple, statistic, n_resamples: int, seed: int, method: str = "BCa") -> tuple[float, float]:
    """A bootstrap interval (scipy.stats.bootstrap, BCa unless `method` says otherwise); NaN
    when the resampled statistic is degenerate (every resample the same value, e.g. every
    difference positive)."""
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        try:
            ci = stats.bootstrap(data, statistic, vectorized=True, n_resamples=n_resamples, method=method,
                                 confidence_level=0.95, **{_RNG: np.random.default_rng(seed)}).confidence_interval
        except ValueError:
            return NAN, NAN
    lo, hi = float(ci.low), float(ci.high)
    return (lo, hi) if np.isfinite(lo) and np.isfinite(hi) else (NAN, NAN)


def rank_biserial_ci(x, y, n_resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED) -> dict:
    """Matched-pairs rank-biserial correlation of x - y (positive: x higher, as in
    analysis.statistics.stats.pairwise_wilcoxon) with a 95% BCa bootstrap interval over participants.
    Why the bootstrap: r is a U-statistic-like rank measure whose standard error has no simple
    closed form away from r = 0 (the Wilcoxon statistic's variance is known under no effect
    only, so a Fisher-z interval built on it is centred on the wrong spread); resampling
    participants, the independent units, needs no such assumption, handles ties and zero
    differences as the estimate does, and stays inside [-1, 1]. Why BCa rather than the
    percentile interval: it corrects the bias and skew of a bounded statistic near +-1. The seed is fixed so the interval
    is reproducible. Pairs with a missing value are dropped. NaN interval: fewer than 3 pairs or
    a degenerate bootstrap distribution (all differences of one sign: r = +-1 in every resample)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    keep = np.isfinite(x) & np.isfinite(y)
    d = x[keep] - y[keep]
    r = float(_rank_biserial(d)) if len(d) else NAN
    lo, hi = _bootstrap((d,), _rank_biserial, n_resamples, seed) if len(d) >= 3 else (NAN, NAN)
    return {"rank_biserial": r, "ci_low": lo, "ci_high": hi, "n": int(len(d)), "method": BOOTSTRAP_METHOD}


def kendall_w_ci(matrix, n_resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED) -> dict:
    """Kendall's W (tie-corrected, W = Friedman chi2 / (n (k - 1)), as analysis.statistics.stats.friedman)
    for rows (participants) by columns (models), with a 95% percentile bootstrap interval over
    rows. Not BCa: W is bounded below by 0 and biased upwards (its expectation with no effect
    at all is about 1/n), so near 0 nearly every resample exceeds the estimate, BCa's bias
    correction runs off to the lower tail and its interval collapses onto [0, W] (seen: W =
    0.008 with a BCa interval [0, 0.008] while 99% of the resamples were larger). The interval
    describes W; it is no test. Rows with a missing value are dropped. NaN interval: fewer than
    3 rows, every row all ties, or a degenerate bootstrap distribution."""
    m = np.asarray(matrix, dtype=float)
    m = m[np.isfinite(m).all(axis=1)]
    n, k = m.shape
    if n == 0 or k < 2:
        return {"kendall_w": NAN, "ci_low": NAN, "ci_high": NAN, "n": int(n), "method": PERCENTILE_METHOD}
    ranks = stats.rankdata(m, axis=1)
    ties = np.array([float(np.sum(c**3 - c)) for c in (np.unique(row, return_counts=True)[1] for row in m)])

    def w(idx, axis=-1):
        idx = np.asarray(idx, dtype=int)
        nn = idx.shape[-1]
        r = ranks[idx].sum(axis=-2)  # (..., k) column rank sums of the resampled rows
        chi2 = 12.0 / (nn * k * (k + 1)) * (r**2).sum(axis=-1) - 3.0 * nn * (k + 1)
        c = 1.0 - ties[idx].sum(axis=-1) / (nn * k * (k * k - 1))
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(c > 0, chi2 / np.where(c > 0, c, 1.0) / (nn * (k - 1)), np.nan)

    value = float(w(np.arange(n)))
    lo, hi = _bootstrap((np.arange(n),), w, n_resamples, seed, "percentile") if n >= 3 and np.isfinite(value) else (NAN, NAN)
    return {"kendall_w": value, "ci_low": lo, "ci_high": hi, "n": int(n), "method": PERCENTILE_METHOD}


def friedman_with_ci(matrix) -> dict:
    """analysis.statistics.stats.friedman plus kendall_w_ci's interval (kendall_w_low, kendall_w_high)."""
    ci = kendall_w_ci(matrix)
    return friedman(matrix) | {"kendall_w_low": ci["ci_low"], "kendall_w_high": ci["ci_high"], "interval": ci["method"]}


def wilcoxon_with_ci(wide: pd.DataFrame) -> pd.DataFrame:
    """analysis.statistics.stats.pairwise_wilcoxon (rank_biserial: a - b) plus each pair's bootstrap
    interval (rb_ci_low, rb_ci_high; rank_biserial_ci)."""
    df = pairwise_wilcoxon(wide)
    cis = [rank_biserial_ci(wide[a], wide[b]) for a, b in zip(df["a"], df["b"])]
    df["rb_ci_low"] = [c["ci_low"] for c in cis]
    df["rb_ci_high"] = [c["ci_high"] for c in cis]
    return df


# --- 4. one choice among the conditions ----------------------------------------------------------

def choice_analysis(choices: pd.Series, models: list[str]) -> dict:
    """A "which condition felt most X" question: each participant picks one of the k models.
    Returns each model's count and share with its Wilson 95% interval; `overall`, the test that
    every model is equally likely to be chosen: the exact multinomial goodness-of-fit test
    (p = the probability, under equal chances, of every table no more probable than the one
    observed) when there are at most MAX_MULTINOMIAL_OUTCOMES tables to enumerate, else
    Pearson's chi-square (`test` says which; `statistic` is Pearson's chi-square either way);
    and the exact binomial (sign) test of every pair among the participants who chose either
    (n_a, n_b, share_b with its Wilson interval), to Holm-adjust with the other pairwise tests.

    Why not Bradley-Terry or Plackett-Luce (e.g. `choix`): one top choice per participant is a
    top-1 ranking, whose Plackett-Luce likelihood prod_i s_(c_i) / sum_j s_j is a multinomial
    likelihood in p_j = s_j / sum s; its maximum is p_j = n_j / n, strengths proportional to
    the counts (and a model never chosen has strength 0, which a fit can only approach). A fit
    would add nothing to the shares and the multinomial test (tests/test_scales.py checks it).

    Missing answers (NaN) are left out; a name not in `models` is an error (ValueError)."""
    given = choices.dropna()
    unknown = sorted(set(given) - set(models))
    if unknown:
        raise ValueError(f"choices name unknown models: {', '.join(map(str, unknown))}; allowed: {', '.join(models)}")
    counts = np.array([int((given == m).sum()) for m in models])
    n, k = int(counts.sum()), len(models)

    def wilson(x: int, m: int) -> tuple[float, float]:
        if m == 0:
            return NAN, NAN
        lo, hi = proportion_confint(x, m, alpha=0.05, method="wilson")
        return float(lo), float(hi)

    shares = {}
    for m, c in zip(models, counts):
        lo, hi = wilson(int(c), n)
        shares[m] = {"count": int(c), "share": int(c) / n if n else NAN, "wilson_low": lo, "wilson_high": hi}
    pairs = []
    for (a, na), (b, nb) in itertools.combinations(zip(models, counts.tolist()), 2):
        m = na + nb
        lo, hi = wilson(nb, m)
        pairs.append({"a": a, "b": b, "n_a": na, "n_b": nb, "p_value": float(stats.binomtest(nb, m, 0.5).pvalue) if m else NAN,
                      "share_b": nb / m if m else NAN, "share_b_low": lo, "share_b_high": hi})
    return {"n": n, "k": k, "n_missing": int(len(choices) - len(given)), "shares": shares,
            "overall": multinomial_test(counts), "pairs": pairs}


def _outcomes(n: int, k: int) -> int:
    return math.comb(n + k - 1, k - 1)


def multinomial_test(counts) -> dict:
    """Goodness of fit of `counts` to equal chances: exact (enumerating every table of n into k
    cells, stars and bars) when cheap, else Pearson's chi-square with k - 1 df."""
    counts = np.asarray(counts, dtype=int)
    n, k = int(counts.sum()), len(counts)
    if n == 0 or k < 2:
        return {"test": "none", "statistic": NAN, "df": max(k - 1, 0), "p_value": NAN, "n": n}
    expected = n / k
    chi2 = float(((counts - expected) ** 2).sum() / expected)
    p_chi2 = float(stats.chi2.sf(chi2, k - 1))
    if _outcomes(n, k) > MAX_MULTINOMIAL_OUTCOMES:
        return {"test": "chi-square goodness of fit", "statistic": chi2, "df": k - 1, "p_value": p_chi2, "n": n,
                "p_value_chi2": p_chi2}
    bars = np.array(list(itertools.combinations(range(n + k - 1), k - 1)), dtype=int).reshape(-1, k - 1)
    edges = np.hstack([np.full((len(bars), 1), -1), bars, np.full((len(bars), 1), n + k - 1)])
    tables = np.diff(edges, axis=1) - 1  # cells between consecutive bars
    logp = gammaln(n + 1) - gammaln(tables + 1).sum(axis=1) - n * math.log(k)
    observed = gammaln(n + 1) - gammaln(counts + 1).sum() - n * math.log(k)
    p = float(np.exp(logp[logp <= observed + 1e-7]).sum())  # tables as probable as the observed one count too
    return {"test": "exact multinomial (probability ordering)", "statistic": chi2, "df": k - 1, "p_value": min(p, 1.0),
            "n": n, "p_value_chi2": p_chi2}


# --- 5. report-table helpers ---------------------------------------------------------------------

def median_iqr(values) -> dict:
    """Median and quartiles (linear interpolation: numpy's default, R's type 7); missing values left out."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if not len(v):
        return {"n": 0, "median": NAN, "q1": NAN, "q3": NAN, "iqr": NAN}
    q1, med, q3 = (float(x) for x in np.percentile(v, [25, 50, 75]))
    return {"n": int(len(v)), "median": med, "q1": q1, "q3": q3, "iqr": q3 - q1}


__all__ = ["ordinal_gee", "mixed_model", "rank_biserial_ci", "kendall_w_ci", "friedman_with_ci", "wilcoxon_with_ci",
           "choice_analysis", "multinomial_test", "mean_ci", "median_iqr"]
