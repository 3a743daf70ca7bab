"""Construct validity from the performance metrics: do the groups differ, do
they learn, where do the novices stand against the experts, and can a participant's group be told
from their metrics. Tidy inputs and outputs, stable column names (pingouin style).

Inputs: `metrics`, the tidy table of analysis.validity.metrics.metrics_table (code, synthetic, condition,
trial, hand, metric, value, unit: `trial` the stored 0-based index); `groups`, a Series code ->
group label; `order`, the group labels in order, the expert group last.

- `participant_scores`: one value per participant, condition and metric (mean over trials and hands).
- `group_tests`: Kruskal-Wallis per metric and condition, pairwise two-sided Mann-Whitney U with Holm
  over the whole family (and, with `n_perm`, the Westfall-Young step-down min-p permutation
  adjustment), Cliff's delta with a bootstrap percentile interval, group medians and IQR.
- `mixed_model`: value ~ group + condition + trial, participant random intercept (statsmodels MixedLM).
- `learning_curves`: y = plateau + (y0 - plateau) exp(-rate (trial - 1)) per metric and group,
  bootstrap intervals over participants.
- `proficiency`: the expert group's benchmark band per metric and every other participant's scorecard.
- `classify`: standardised features + logistic regression, leave-one-participant-out accuracy with
  a permutation p-value.
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
import statsmodels.formula.api as smf
from scipy import optimize, stats
from sklearn.impute import SimpleImputer
from sklearn.linear_model import LogisticRegression
from sklearn.metrics import balanced_accuracy_score, confusion_matrix
from sklearn.model_selection import LeaveOneOut, cross_val_predict, permutation_test_score
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from statsmodels.tools.sm_exceptions import ConvergenceWarning
from threadpoolctl import threadpool_limits

from analysis.statistics.stats import holm

BOTH = "both"  # analysis.validity.metrics' hand of the bimanual metrics
SCORE_COLUMNS = ["code", "condition", "metric", "value", "n_values"]
KRUSKAL_COLUMNS = ["metric", "condition", "test", "k", "n", "H", "df", "p", "p_holm", "reason"]
PAIR_COLUMNS = ["metric", "condition", "test", "a", "b", "n_a", "n_b", "median_a", "median_b", "U", "p", "p_holm",
                "cliffs_delta", "delta_low", "delta_high", "reason"]
KRUSKAL = "Kruskal-Wallis H (tie-corrected)"
MANN_WHITNEY = "Mann-Whitney U, two-sided (U: of the first group)"
DESCRIPTIVE_COLUMNS = ["metric", "condition", "group", "n", "median", "q1", "q3", "iqr"]
FIXED_COLUMNS = ["metric", "term", "coef", "se", "z", "p", "converged"]
CURVE_COLUMNS = ["metric", "condition", "group", "n_participants", "n_trials", "y0", "plateau", "rate",
                 "plateau_low", "plateau_high", "rate_low", "rate_high", "n_boot", "n_boot_ok"]
BENCHMARK_COLUMNS = ["metric", "condition", "n_expert", "median", "low", "high", "better"]
SCORECARD_COLUMNS = ["code", "group", "condition", "metric", "value", "median", "low", "high", "better",
                     "position", "proficient"]
SUMMARY_COLUMNS = ["code", "group", "condition", "n_metrics", "n_proficient", "fraction_proficient"]


def _with_groups(df: pd.DataFrame, groups: pd.Series, order: Sequence[str] | None) -> tuple[pd.DataFrame, list[str]]:
    """`df` with a `group` column (participants without a group dropped) and the group order."""
    order = list(order) if order is not None else sorted(pd.unique(groups.dropna()).tolist())
    out = df.assign(group=df["code"].map(groups))
    return out[out["group"].isin(order)].copy(), order


# ---------------------------------------------------------------- scores

def participant_scores(metrics: pd.DataFrame, how: str = "mean") -> pd.DataFrame:
    """One value per participant, condition and metric: the mean (or `how="median"`) over trials
    and hands. Hand "both" rows (the bimanual metrics) are their own metric; should a metric come
    both per hand and as "both", the latter is named ``METRIC:both``. Columns `SCORE_COLUMNS`."""
    if how not in ("mean", "median"):
        raise ValueError(f"how must be 'mean' or 'median', not {how!r}")
    out = _both_named(metrics).groupby(["code", "condition", "metric"], sort=True)["value"].agg([how, "count"]).reset_index()
    return out.rename(columns={how: "value", "count": "n_values"})[SCORE_COLUMNS]


def _both_named(metrics: pd.DataFrame) -> pd.DataFrame:
    """The rows with a value; a metric that comes both per hand and as hand "both" renamed
    ``METRIC:both`` in its "both" rows."""
    m = metrics.dropna(subset=["value"])
    per_hand = set(m.loc[m["hand"] != BOTH, "metric"])
    is_both = (m["hand"] == BOTH) & m["metric"].isin(per_hand)
    return m.assign(metric=m["metric"].where(~is_both, m["metric"] + ":" + BOTH))


def _trial_means(metrics: pd.DataFrame) -> pd.DataFrame:
    """Per participant, condition, trial and metric: the mean over hands (hand "both" as in
    `participant_scores`)."""
    return _both_named(metrics).groupby(["code", "condition", "trial", "metric"], sort=True)["value"].mean().reset_index()


# ---------------------------------------------------------------- group comparisons

def cliffs_delta(a, b) -> float:
    """Cliff's delta P(a > b) - P(a < b), = the rank-biserial correlation of Mann-Whitney's U of `a`."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.mean(np.sign(a[:, None] - b[None, :])))


def cliffs_delta_interval(a, b, n_boot: int = 2000, level: float = 0.95, seed: int = 0) -> tuple[float, float]:
    """Bootstrap percentile interval of Cliff's delta, resampling participants within each group
    (stratified). With complete separation every replicate is +-1 and so is the interval."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) < 2 or len(b) < 2:
        return float("nan"), float("nan")
    dom = np.sign(a[:, None] - b[None, :])
    rng = np.random.default_rng(seed)
    ia = rng.integers(0, len(a), (n_boot, len(a)))
    ib = rng.integers(0, len(b), (n_boot, len(b)))
    d = dom[ia[:, :, None], ib[:, None, :]].mean(axis=(1, 2))
    tail = 50 * (1 - level)
    lo, hi = np.percentile(d, [tail, 100 - tail])
    return float(lo), float(hi)


@dataclass(frozen=True)
class GroupTests:
    """`kruskal` (KRUSKAL_COLUMNS), `pairs` (PAIR_COLUMNS), `descriptives` (DESCRIPTIVE_COLUMNS).
    p_holm: Holm over the whole family, all metrics and conditions (x pairs for `pairs`); with
    `n_perm` > 0, `kruskal` and `pairs` also carry `p_wy` (after `p_holm`): the Westfall-Young
    step-down min-p adjustment over the same family."""
    kruskal: pd.DataFrame
    pairs: pd.DataFrame
    descriptives: pd.DataFrame


WY_TOLERANCE = 1e-10  # relative: a permutation's p this close to the observed one counts as a tie (<=)


def permutation_indices(n: int, n_perm: int, seed: int = 0) -> np.ndarray:
    """The (n_perm, n) permutations of `group_tests`' Westfall-Young adjustment: row b, column i
    is the participant whose group participant i takes in permutation b (participants in sorted
    code order). numpy default_rng(seed).permuted, row by row."""
    return np.random.default_rng(seed).permuted(np.tile(np.arange(n), (n_perm, 1)), axis=1)


def westfall_young(p_obs, p_perm) -> np.ndarray:
    """Westfall-Young step-down min-p adjusted p-values (Westfall & Young 1993, algorithm 2.8).
    `p_obs`: (m,) the observed raw p of the family; `p_perm`: (B, m) the raw p of every test under
    each of B permutations (the same permutation across a row, so the tests' dependence is kept).
    With the observed p in increasing order p(1) <= ... <= p(m), the adjusted p(j) is
    (1 + #{b: min over k >= j of p*_b(k) <= p(j)}) / (B + 1), the observed labelling counted as
    one of the permutations (so >= 1 / (B + 1)), then made monotone (running maximum). A test
    whose observed p is NaN is not in the family (NaN out); a NaN permutation p counts as 1.
    A permutation p within a relative WY_TOLERANCE of p(j) counts as <= (ties of the statistic
    computed in a different floating-point order)."""
    p_obs = np.asarray(p_obs, float)
    p_perm = np.asarray(p_perm, float).reshape(-1, len(p_obs))
    out = np.full(len(p_obs), np.nan)
    keep = np.flatnonzero(np.isfinite(p_obs))
    if not len(keep):
        return out
    order = keep[np.argsort(p_obs[keep], kind="stable")]
    q = np.nan_to_num(p_perm[:, order], nan=1.0)
    q = np.minimum.accumulate(q[:, ::-1], axis=1)[:, ::-1]  # successive minima from the least significant
    hits = (q <= p_obs[order] * (1 + WY_TOLERANCE)).sum(axis=0)
    out[order] = np.maximum.accumulate((1 + hits) / (len(p_perm) + 1))
    return out


def _kruskal_p(x: np.ndarray, labels: np.ndarray, k: int) -> np.ndarray:
    """Kruskal-Wallis p (scipy.stats.kruskal's H, tie-corrected, chi-square with one df fewer than
    the non-empty groups) of values `x` (n,) under each row of `labels` (P, n; group indices
    0..k-1); NaN where fewer than two groups are non-empty or every value is the same."""
    n = len(x)
    if n < 2 or np.ptp(x) == 0:
        return np.full(len(labels), np.nan)
    r = stats.rankdata(x)
    _, t = np.unique(x, return_counts=True)
    ties = 1.0 - (t ** 3 - t).sum() / float(n ** 3 - n)
    onehot = (labels[:, :, None] == np.arange(k)).astype(float)
    rsum = np.einsum("pnk,n->pk", onehot, r)
    ng = onehot.sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ssbn = np.where(ng > 0, rsum * rsum / ng, 0.0).sum(axis=1)
    h = (12.0 / (n * (n + 1)) * ssbn - 3 * (n + 1)) / ties
    df = (ng > 0).sum(axis=1) - 1
    p = stats.chi2.sf(h, np.maximum(df, 1))
    return np.where(df >= 1, p, np.nan)


def _mannwhitney_p(x: np.ndarray, labels: np.ndarray, a: int, b: int) -> np.ndarray:
    """Two-sided Mann-Whitney p of group `a` against `b` under each row of `labels` (P, n), as
    scipy.stats.mannwhitneyu(method="asymptotic") computes it (normal approximation, tie and
    continuity corrections): the average ranks within each row's pooled sample of the two groups.
    NaN where either group is empty."""
    in_a, in_b = labels == a, labels == b
    pooled = (in_a | in_b).astype(float)
    less = pooled @ (x[None, :] < x[:, None]).T.astype(float)  # [p, i]: pooled j with x_j < x_i
    equal = pooled @ (x[None, :] == x[:, None]).T.astype(float)  # [p, i]: pooled j with x_j == x_i (i itself too)
    rank = less + (equal + 1) / 2
    n1, n2 = in_a.sum(axis=1).astype(float), in_b.sum(axis=1).astype(float)
    u1 = (rank * in_a).sum(axis=1) - n1 * (n1 + 1) / 2
    u = np.maximum(u1, n1 * n2 - u1)
    n = n1 + n2
    tie_term = ((equal * equal - 1) * pooled).sum(axis=1)  # sum of t^3 - t over the tie groups
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.sqrt(n1 * n2 / 12 * ((n + 1) - tie_term / (n * (n - 1))))
        z = (u - n1 * n2 / 2 - 0.5) / s
    p = np.clip(2 * stats.norm.sf(z), 0.0, 1.0)
    return np.where((n1 > 0) & (n2 > 0), p, np.nan)


def _rank_reason(present: list[np.ndarray]) -> str | None:
    """Why a rank test across these groups' values is not run, or None: two groups or more, each
    with 2 participants or more (one value a group has no spread to rank against: the
    approximate p of Kruskal-Wallis is meaningless there, and Mann-Whitney's is always 1)."""
    if len(present) < 2:
        return "fewer than two groups with values"
    if min(map(len, present)) < 2:
        return "a group has fewer than 2 participants with values"
    values = np.concatenate(present)
    if np.ptp(values) == 0:
        return f"every value is {float(values[0]):g}: no variation to rank"
    return None


def group_tests(scores: pd.DataFrame, groups: pd.Series, order: Sequence[str] | None = None,
                n_boot: int = 2000, seed: int = 0, n_perm: int = 0) -> GroupTests:
    """Kruskal-Wallis across the groups per metric and condition, then two-sided Mann-Whitney U
    for every pair of groups (in `order`; effect size Cliff's delta of a over b with its
    bootstrap percentile 95% interval). `scores`: as from `participant_scores`.

    `n_perm` > 0 adds the column `p_wy` to `kruskal` (family: every metric x condition) and to
    `pairs` (family: every metric x condition x pair): the Westfall-Young step-down min-p
    adjustment (`westfall_young`) over `n_perm` random permutations of the group labels across
    the participants (`permutation_indices(n, n_perm, seed)`, participants in sorted code order).
    One permutation relabels a participant alike in every metric and condition, so the
    correlation between the metrics is kept and the family-wise error rate is controlled exactly
    under the complete null whatever the dependence. A test uses the participants with a value
    (their permuted labels). The raw p it adjusts: Kruskal-Wallis as in `p`; Mann-Whitney from the
    normal approximation (scipy's method="asymptotic"), which is `p` unless a group has at most 8
    participants and there are no ties (scipy's exact p). With `n_perm` = 0 (the default) there
    is no `p_wy` column."""
    s, order = _with_groups(scores.dropna(subset=["value"]), groups, order)
    kw, pairs, desc = [], [], []
    codes = np.sort(s["code"].unique())
    if n_perm > 0:
        lab = pd.Series(codes).map(groups).map({g: i for i, g in enumerate(order)}).to_numpy(int)
        labels = np.vstack([lab, lab[permutation_indices(len(codes), int(n_perm), seed)]])  # row 0: observed
        kw_perm, pair_perm = [], []
    for (metric, condition), d in s.groupby(["metric", "condition"], sort=True):
        vals = {g: d.loc[d["group"] == g, "value"].to_numpy(float) for g in order}
        for g, v in vals.items():
            q1, med, q3 = np.percentile(v, [25, 50, 75]) if len(v) else (np.nan,) * 3
            desc.append({"metric": metric, "condition": condition, "group": g, "n": len(v), "median": med,
                         "q1": q1, "q3": q3, "iqr": q3 - q1})
        present = [v for v in vals.values() if len(v)]
        H = p = np.nan
        reason = _rank_reason(present)
        if reason is None:
            res = stats.kruskal(*present)
            H, p = float(res.statistic), float(res.pvalue)
        kw.append({"metric": metric, "condition": condition, "test": KRUSKAL, "k": len(present), "n": sum(map(len, present)),
                   "H": H, "df": len(present) - 1, "p": p, "reason": reason})
        if n_perm > 0:
            x = d["value"].to_numpy(float)
            lt = labels[:, np.searchsorted(codes, d["code"].to_numpy())]
            kw_perm.append(_kruskal_p(x, lt, len(order)) if np.isfinite(p) else np.full(len(lt), np.nan))
        for ia, ib in itertools.combinations(range(len(order)), 2):
            ga, gb = order[ia], order[ib]
            a, b = vals[ga], vals[gb]
            reason = _rank_reason([v for v in (a, b) if len(v)])
            row = {"metric": metric, "condition": condition, "test": MANN_WHITNEY, "a": ga, "b": gb, "n_a": len(a), "n_b": len(b),
                   "median_a": np.median(a) if len(a) else np.nan, "median_b": np.median(b) if len(b) else np.nan,
                   "U": np.nan, "p": np.nan, "cliffs_delta": np.nan, "delta_low": np.nan, "delta_high": np.nan, "reason": reason}
            if reason is None:
                res = stats.mannwhitneyu(a, b, alternative="two-sided")
                lo, hi = cliffs_delta_interval(a, b, n_boot=n_boot, seed=seed)
                row |= {"U": float(res.statistic), "p": float(res.pvalue), "cliffs_delta": cliffs_delta(a, b),
                        "delta_low": lo, "delta_high": hi}
            pairs.append(row)
            if n_perm > 0:
                pair_perm.append(_mannwhitney_p(x, lt, ia, ib) if reason is None else np.full(len(lt), np.nan))
    kw_df = pd.DataFrame(kw, columns=[c for c in KRUSKAL_COLUMNS if c != "p_holm"])
    kw_df.insert(len(kw_df.columns), "p_holm", holm(kw_df["p"]))
    pair_df = pd.DataFrame(pairs, columns=[c for c in PAIR_COLUMNS if c != "p_holm"])
    pair_df.insert(PAIR_COLUMNS.index("p_holm"), "p_holm", holm(pair_df["p"]))
    kw_cols, pair_cols = list(KRUSKAL_COLUMNS), list(PAIR_COLUMNS)
    if n_perm > 0:
        for df, perm, cols in ((kw_df, kw_perm, kw_cols), (pair_df, pair_perm, pair_cols)):
            pp = np.column_stack(perm) if perm else np.empty((len(labels), 0))
            df["p_wy"] = westfall_young(pp[0], pp[1:])
            cols.insert(cols.index("p_holm") + 1, "p_wy")
    return GroupTests(kw_df[kw_cols], pair_df[pair_cols], pd.DataFrame(desc, columns=DESCRIPTIVE_COLUMNS))


# ---------------------------------------------------------------- mixed model

@dataclass(frozen=True)
class MixedModels:
    """`fixed`: FIXED_COLUMNS, the fixed effects of every metric fitted; `skipped`: metric, reason."""
    fixed: pd.DataFrame
    skipped: pd.DataFrame


def _term(name: str) -> str:
    """statsmodels' "C(group, Treatment(reference='x'))[T.y]" as "group[y]"."""
    if name.startswith("C(") and ")[T." in name:
        var = name[2:].split(",")[0].split(")")[0]
        return f"{var}[{name.rsplit('[T.', 1)[1][:-1]}]"
    return name


def mixed_model(metrics: pd.DataFrame, groups: pd.Series, order: Sequence[str] | None = None) -> MixedModels:
    """Per metric, statsmodels MixedLM of value ~ group + condition + trial (treatment coding, the
    first group of `order` and the first condition alphabetically as references; `trial` the
    stored index) with a random intercept per participant, on the per-trial values (mean over
    hands). Skipped, with the reason, where the study has one condition or one group."""
    t, order = _with_groups(_trial_means(metrics), groups, order)
    fixed, skipped = [], []
    for metric, d in t.groupby("metric", sort=True):
        conditions = sorted(d["condition"].unique())
        present = [g for g in order if (d["group"] == g).any()]
        if len(conditions) < 2:
            skipped.append({"metric": metric, "reason": f"one condition ({conditions[0]}): no condition effect to model"})
            continue
        if len(present) < 2:
            skipped.append({"metric": metric, "reason": "fewer than two groups with data"})
            continue
        formula = (f"value ~ C(group, Treatment(reference={present[0]!r})) "
                   f"+ C(condition, Treatment(reference={conditions[0]!r})) + trial")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                res = smf.mixedlm(formula, d, groups=d["code"]).fit(reml=True)
            except (np.linalg.LinAlgError, ValueError) as e:
                skipped.append({"metric": metric, "reason": f"fit failed: {e}"})
                continue
        converged = bool(res.converged) and not any(issubclass(w.category, ConvergenceWarning) for w in caught)
        names = [n for n in res.fe_params.index]
        for n in names:
            fixed.append({"metric": metric, "term": _term(n), "coef": float(res.fe_params[n]), "se": float(res.bse_fe[n]),
                          "z": float(res.tvalues[n]), "p": float(res.pvalues[n]), "converged": converged})
    return MixedModels(pd.DataFrame(fixed, columns=FIXED_COLUMNS), pd.DataFrame(skipped, columns=["metric", "reason"]))


# ---------------------------------------------------------------- learning curves

def exp_plateau(trial, y0, plateau, rate):
    """y = plateau + (y0 - plateau) exp(-rate (trial - 1)), trial 1-based."""
    return plateau + (y0 - plateau) * np.exp(-rate * (np.asarray(trial, float) - 1.0))


_RATES = np.geomspace(1e-3, 20.0, 160)


def _start(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Starting values: the rate on a grid minimising the residual of the (then linear) least
    squares fit of y0 and plateau, every rate at once."""
    e = np.exp(-_RATES[:, None] * (x[None, :] - 1.0))
    X = np.stack([e, 1.0 - e], axis=2)  # rates, trials, 2
    coef = np.linalg.pinv(X) @ y  # rates, 2
    ss = np.sum((np.einsum("rtk,rk->rt", X, coef) - y[None, :]) ** 2, axis=1)
    i = int(np.nanargmin(ss))
    return float(coef[i, 0]), float(coef[i, 1]), float(_RATES[i])


# half the approach within a quarter of a trial: a step between the first two trials, which whole
# trials cannot resolve into a rate (the fit then rests wherever its start put it, e.g. at the
# start grid's top)
MAX_RATE = float(np.log(2.0) / 0.25)


def fit_learning_curve(trial, y, max_rate: float = MAX_RATE) -> tuple[float, float, float] | None:
    """(y0, plateau, rate) of `exp_plateau` by scipy.optimize.curve_fit from a grid start, or None
    where the fit fails: fewer than 3 trials, no convergence, non-finite parameters, a rate above
    `max_rate` (a step, no curve: `MAX_RATE`), or a rate too slow for half the approach to the plateau to lie
    within the trials observed (rate < ln 2 / (last - first trial)): a plateau then is an
    extrapolation, and a growing or straight series fits as one far away."""
    x, y = np.asarray(trial, float), np.asarray(y, float)
    ok = np.isfinite(y)
    x, y = x[ok], y[ok]
    if len(np.unique(x)) < 3:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optimize.OptimizeWarning)
            p, _ = optimize.curve_fit(exp_plateau, x, y, p0=_start(x, y), maxfev=2000)
    except (RuntimeError, ValueError):
        return None
    if not np.all(np.isfinite(p)) or not np.log(2.0) / (x.max() - x.min()) <= p[2] <= max_rate:
        return None
    return float(p[0]), float(p[1]), float(p[2])


def learning_curves(metrics: pd.DataFrame, groups: pd.Series, order: Sequence[str] | None = None,
                    n_boot: int = 500, level: float = 0.95, seed: int = 0) -> pd.DataFrame:
    """Per metric, condition and group: the group's per-trial mean (of the participants' means over
    hands) against the trial number (the stored 0-based index + 1), fitted with `exp_plateau`;
    percentile intervals of plateau and rate from `n_boot` bootstrap replicates resampling the
    group's participants (seeded); a replicate whose fit fails is dropped (n_boot_ok counts the
    rest). Columns `CURVE_COLUMNS`."""
    t, order = _with_groups(_trial_means(metrics), groups, order)
    rng = np.random.default_rng(seed)
    tail = 50 * (1 - level)
    rows = []
    for (metric, condition), d in t.groupby(["metric", "condition"], sort=True):
        for g in order:
            w = d[d["group"] == g].pivot_table(index="code", columns="trial", values="value", aggfunc="mean")
            if w.empty:
                continue
            x = w.columns.to_numpy(float) + 1.0
            P = w.to_numpy(float)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a trial nobody in a replicate did
                fit = fit_learning_curve(x, np.nanmean(P, axis=0))
                boots = []
                for _ in range(n_boot):
                    f = fit_learning_curve(x, np.nanmean(P[rng.integers(0, len(P), len(P))], axis=0))
                    if f is not None:
                        boots.append(f)
            row = {"metric": metric, "condition": condition, "group": g, "n_participants": len(P), "n_trials": len(x),
                   "y0": np.nan, "plateau": np.nan, "rate": np.nan, "plateau_low": np.nan, "plateau_high": np.nan,
                   "rate_low": np.nan, "rate_high": np.nan, "n_boot": n_boot, "n_boot_ok": len(boots)}
            if fit is not None:
                row |= dict(zip(["y0", "plateau", "rate"], fit))
            if boots:
                b = np.array(boots)
                row |= dict(zip(["plateau_low", "plateau_high"], np.percentile(b[:, 1], [tail, 100 - tail])))
                row |= dict(zip(["rate_low", "rate_high"], np.percentile(b[:, 2], [tail, 100 - tail])))
            rows.append(row)
    return pd.DataFrame(rows, columns=CURVE_COLUMNS)


# ---------------------------------------------------------------- proficiency

@dataclass(frozen=True)
class Proficiency:
    """`benchmark` (BENCHMARK_COLUMNS): the expert group's median and band per metric and
    condition; `scorecard` (SCORECARD_COLUMNS): every other participant's value against it,
    position "inside" the band, "better" or "worse" beyond it (a metric without a direction:
    "above"/"below"), proficient where inside or better; `summary` (SUMMARY_COLUMNS): the
    fraction of a participant's metrics at proficiency."""
    benchmark: pd.DataFrame
    scorecard: pd.DataFrame
    summary: pd.DataFrame


def proficiency(scores: pd.DataFrame, groups: pd.Series, expert: str, better: Mapping[str, str] | None = None,
                band: tuple[float, float] = (5.0, 95.0)) -> Proficiency:
    """The expert group's benchmark per metric and condition: its median and the `band`
    percentiles (5th-95th by default; (25, 75) for the IQR). `better`: metric -> "lower" or
    "higher", where better performance lies."""
    better = dict(better or {})
    bad = {k: v for k, v in better.items() if v not in ("lower", "higher")}
    if bad:
        raise ValueError(f"better must be 'lower' or 'higher': {bad}")
    s, _ = _with_groups(scores.dropna(subset=["value"]), groups, None)
    ex = s[s["group"] == expert]
    if ex.empty:
        raise ValueError(f"no participant of the expert group {expert!r}")
    bench = []
    for (metric, condition), d in ex.groupby(["metric", "condition"], sort=True):
        lo, med, hi = np.percentile(d["value"].to_numpy(float), [band[0], 50, band[1]])
        bench.append({"metric": metric, "condition": condition, "n_expert": len(d), "median": med, "low": lo,
                      "high": hi, "better": better.get(metric)})
    bench_df = pd.DataFrame(bench, columns=BENCHMARK_COLUMNS)
    card = s[s["group"] != expert].merge(bench_df.drop(columns="n_expert"), on=["metric", "condition"], how="inner")

    def position(r) -> str:
        if r["low"] <= r["value"] <= r["high"]:
            return "inside"
        above = r["value"] > r["high"]
        if r["better"] is None or pd.isna(r["better"]):
            return "above" if above else "below"
        return "better" if above == (r["better"] == "higher") else "worse"

    card["position"] = card.apply(position, axis=1) if len(card) else pd.Series(dtype=str)
    card["proficient"] = card["position"].isin(["inside", "better"])
    card = card.sort_values(["code", "condition", "metric"]).reset_index(drop=True)[SCORECARD_COLUMNS]
    summary = (card.groupby(["code", "group", "condition"], sort=True)["proficient"]
               .agg(n_metrics="count", n_proficient="sum").reset_index())
    summary["n_proficient"] = summary["n_proficient"].astype(int)
    summary["fraction_proficient"] = summary["n_proficient"] / summary["n_metrics"]
    return Proficiency(bench_df, card, summary[SUMMARY_COLUMNS])


# ---------------------------------------------------------------- classification

@dataclass(frozen=True)
class Classification:
    """Leave-one-participant-out classification of group from the metric vector."""
    features: tuple[str, ...]
    n: int
    accuracy: float
    balanced_accuracy: float
    chance: float  # the largest group's share: what always guessing it scores
    p_value: float  # permutation test of the accuracy
    n_permutations: int
    confusion: pd.DataFrame  # rows: true group, columns: predicted, in the group order
    predictions: pd.DataFrame  # code, group, predicted

    def table(self) -> pd.DataFrame:
        return pd.DataFrame([{"n": self.n, "n_features": len(self.features), "accuracy": self.accuracy,
                              "balanced_accuracy": self.balanced_accuracy, "chance": self.chance,
                              "p_value": self.p_value, "n_permutations": self.n_permutations}])


def classify(scores: pd.DataFrame, groups: pd.Series, order: Sequence[str] | None = None,
             n_permutations: int = 500, seed: int = 0, C: float = 1.0) -> Classification:
    """Group from a participant's metric vector (one feature per condition x metric; a missing
    value imputed with the training median): median imputation, standardisation and an
    L2-regularised multinomial logistic regression (class weights balanced), refitted inside
    every fold. Accuracy and balanced accuracy leave-one-participant-out (the table has one row per
    participant, so leave-one-out); p-value from sklearn's permutation_test_score with the same
    folds and `n_permutations` permutations of the labels (seeded). Logistic regression rather
    than a random forest: with ~30 participants and a dozen features a regularised linear model
    is stable across folds, fits in milliseconds (the permutation test refits n x
    n_permutations times) and its standardised coefficients read as which metrics separate."""
    s, order = _with_groups(scores.dropna(subset=["value"]), groups, order)
    s = s.assign(feature=s["condition"].astype(str) + "/" + s["metric"].astype(str))
    wide = s.pivot_table(index="code", columns="feature", values="value", aggfunc="mean").sort_index()
    wide = wide.loc[:, wide.notna().any()]
    y = wide.index.map(groups).to_numpy()
    order = [g for g in order if g in set(y)]
    if len(order) < 2:
        raise ValueError("classification needs participants of at least two groups")
    smallest = pd.Series(y).value_counts().min()
    if smallest < 2:  # leaving its one participant out leaves the model without that group
        raise ValueError(f"classification needs 2 or more participants in every group (leave-one-out leaves a group of {smallest} empty)")
    X = wide.to_numpy(float)
    model = make_pipeline(SimpleImputer(strategy="median"), StandardScaler(),
                          LogisticRegression(C=C, class_weight="balanced", max_iter=2000))
    cv = LeaveOneOut()
    with threadpool_limits(1):  # thousands of tiny fits: BLAS threads only contend (docs/synthetic.md)
        pred = cross_val_predict(model, X, y, cv=cv)
        score, _, p = permutation_test_score(model, X, y, cv=cv, n_permutations=n_permutations,
                                             random_state=seed, scoring="accuracy")
    cm = confusion_matrix(y, pred, labels=order)
    return Classification(
        features=tuple(wide.columns), n=len(y), accuracy=float(score),
        balanced_accuracy=float(balanced_accuracy_score(y, pred)),
        chance=float(pd.Series(y).value_counts(normalize=True).max()), p_value=float(p),
        n_permutations=n_permutations,
        confusion=pd.DataFrame(cm, index=pd.Index(order, name="true"), columns=pd.Index(order, name="predicted")),
        predictions=pd.DataFrame({"code": wide.index, "group": y, "predicted": pred}))
