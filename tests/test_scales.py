"""analysis/statistics/scales.py (and the rank tests of analysis/statistics/stats.py) against independent references:
published examples, pingouin, likelihoods and bootstrap intervals written out by hand here, and
exact enumerations. pingouin is a test-only dependency (pyproject's dev group)."""

import itertools
import math
from fractions import Fraction

import numpy as np
import pandas as pd
import pytest
from scipy import optimize, stats
from scipy.special import expit

from analysis.statistics.scales import (
    choice_analysis,
    friedman_with_ci,
    kendall_w_ci,
    mean_ci,
    median_iqr,
    mixed_model,
    ordinal_gee,
    rank_biserial_ci,
    wilcoxon_with_ci,
)
from analysis.statistics.stats import friedman, pairwise_wilcoxon

pg = pytest.importorskip("pingouin")
MODELS = ["fem", "mass_spring", "plate_spring"]


def _pg(frame: pd.DataFrame) -> pd.Series:
    """pingouin's one-row result with its column names as of 0.6 (0.5 spelt p-unc, p-val)."""
    return frame.rename(columns=lambda c: c.replace("-", "_")).iloc[0]


def _likert(n: int, shift=(0.0, 1.0, -0.5), items: int = 1, seed: int = 0) -> pd.DataFrame:
    """Answers 1..5 from a latent logistic with a participant effect; periods in a cyclic Latin square."""
    rng = np.random.default_rng(seed)
    person = rng.normal(0, 1, n)
    rows = []
    for i in range(n):
        for j, m in enumerate(MODELS):
            for q in range(items):
                latent = shift[j] + person[i] + rng.logistic()
                rows.append({"code": f"P{i:02d}", "model": m, "item": f"q{q}", "period": (i + j) % 3,
                             "answer": int(np.clip(np.round(latent + 3), 1, 5))})
    return pd.DataFrame(rows)


# --- Friedman and Kendall's W (analysis.statistics.stats.friedman) -----------------------------------------

# R's ?friedman.test example: Hollander and Wolfe (1973), Nonparametric Statistical Methods,
# p. 140 ff.: times of 22 baseball players rounding first base three ways. R prints
# "Friedman chi-squared = 11.143, df = 2, p-value = 0.003805" (with the tie correction).
ROUNDING_TIMES = [
    [5.40, 5.50, 5.55], [5.85, 5.70, 5.75], [5.20, 5.60, 5.50], [5.55, 5.50, 5.40], [5.90, 5.85, 5.70],
    [5.45, 5.55, 5.60], [5.40, 5.40, 5.35], [5.45, 5.50, 5.35], [5.25, 5.15, 5.00], [5.85, 5.80, 5.70],
    [5.25, 5.20, 5.10], [5.65, 5.55, 5.45], [5.60, 5.35, 5.45], [5.05, 5.00, 4.95], [5.50, 5.50, 5.40],
    [5.45, 5.55, 5.50], [5.55, 5.55, 5.35], [5.45, 5.50, 5.55], [5.50, 5.45, 5.25], [5.65, 5.60, 5.40],
    [5.70, 5.65, 5.55], [6.30, 6.30, 6.25],
]


def test_friedman_matches_r_rounding_times_example():
    f = friedman(np.array(ROUNDING_TIMES))
    assert round(f["statistic"], 3) == 11.143
    assert f["df"] == 2
    assert round(f["p_value"], 6) == 0.003805
    # Kendall's W = chi2 / (n (k - 1)) (Kendall and Babington Smith) from R's printed statistic
    assert f["kendall_w"] == pytest.approx(11.143 / (22 * 2), abs=2e-5)


@pytest.mark.parametrize("data", ["rounding", "likert"])
def test_friedman_and_kendall_w_match_pingouin(data):
    m = np.array(ROUNDING_TIMES) if data == "rounding" else \
        _likert(25, seed=1).pivot(index="code", columns="model", values="answer").to_numpy()
    ref = _pg(pg.friedman(pd.DataFrame(m, columns=["a", "b", "c"])))  # its own tie-corrected W, then Q = n (k - 1) W
    f = friedman(m)
    assert f["statistic"] == pytest.approx(ref["Q"], rel=1e-10)
    assert f["p_value"] == pytest.approx(ref["p_unc"], rel=1e-9)
    assert f["kendall_w"] == pytest.approx(ref["W"], rel=1e-10)


# --- Wilcoxon pairs (analysis.statistics.stats.pairwise_wilcoxon) -------------------------------------------

def test_pairwise_wilcoxon_matches_pingouin():
    wide = _likert(30, seed=2).pivot(index="code", columns="model", values="answer")[MODELS]
    ours = pairwise_wilcoxon(wide)
    for row in ours.itertuples():
        # pingouin: RBC = (R+ - R-) / (R+ + R-) of x - y, two-sided, the same sign as ours (a - b);
        # it applies a continuity correction by default, pairwise_wilcoxon (scipy's default) does not
        ref = _pg(pg.wilcoxon(wide[row.a].to_numpy(float), wide[row.b].to_numpy(float), correction=False))
        assert row.p_value == pytest.approx(ref["p_val"], rel=1e-9)
        assert row.rank_biserial == pytest.approx(ref["RBC"], abs=1e-12)
    by = {(r.a, r.b): r.rank_biserial for r in ours.itertuples()}
    assert by[("fem", "mass_spring")] < -0.3  # a - b: mass_spring rated higher
    assert by[("mass_spring", "plate_spring")] > 0.3


# --- bootstrap intervals against a BCa written out by hand (Efron and Tibshirani 1993, ch. 14) ---

def _hand_bca(samples: np.ndarray, statistic, resamples: int = 4000, seed: int = 11) -> tuple[float, float]:
    """BCa over rows of `samples`, one statistic call per resample: bias from the share of
    resamples below the estimate (ties counted half), acceleration from the jackknife."""
    rng = np.random.default_rng(seed)
    n = len(samples)
    est = statistic(samples)
    boot = np.array([statistic(samples[rng.integers(0, n, n)]) for _ in range(resamples)])
    z0 = stats.norm.ppf((np.sum(boot < est) + 0.5 * np.sum(boot == est)) / resamples)
    jack = np.array([statistic(np.delete(samples, i, axis=0)) for i in range(n)])
    dev = jack.mean() - jack
    acc = np.sum(dev**3) / (6.0 * np.sum(dev**2) ** 1.5)
    out = []
    for q in (0.025, 0.975):
        z = stats.norm.ppf(q)
        out.append(np.quantile(boot, stats.norm.cdf(z0 + (z0 + z) / (1 - acc * (z0 + z)))))
    return float(out[0]), float(out[1])


def _rb_reference(d: np.ndarray) -> float:
    d = d[d != 0]
    if not len(d):
        return 0.0
    r = stats.rankdata(np.abs(d))
    return (r[d > 0].sum() - r[d < 0].sum()) / r.sum()


def test_rank_biserial_interval_matches_a_hand_bca_bootstrap():
    wide = _likert(30, seed=3).pivot(index="code", columns="model", values="answer")
    x, y = wide["plate_spring"].to_numpy(float), wide["fem"].to_numpy(float)
    out = rank_biserial_ci(x, y)
    ref = _pg(pg.wilcoxon(x, y))
    assert out["rank_biserial"] == pytest.approx(ref["RBC"], abs=1e-12)
    assert out["n"] == 30
    lo, hi = _hand_bca(x - y, _rb_reference)  # Monte Carlo error about 0.01; the percentile interval is 0.05 off here
    assert out["ci_low"] == pytest.approx(lo, abs=0.03)
    assert out["ci_high"] == pytest.approx(hi, abs=0.03)
    assert -1 <= out["ci_low"] < out["rank_biserial"] < out["ci_high"] <= 1
    assert out["ci_high"] - out["ci_low"] > 0.2
    assert rank_biserial_ci(x, y) == out  # a fixed seed: the same interval every time


def test_kendall_w_interval_matches_a_hand_percentile_bootstrap():
    m = _likert(30, seed=4).pivot(index="code", columns="model", values="answer").to_numpy(float)

    def w(rows):  # scipy's tie-corrected Friedman statistic, resampled rows as blocks
        return stats.friedmanchisquare(*rows.T).statistic / (len(rows) * 2)

    out = kendall_w_ci(m)
    assert out["kendall_w"] == pytest.approx(_pg(pg.friedman(pd.DataFrame(m)))["W"], rel=1e-10)
    rng = np.random.default_rng(11)
    boot = [w(m[rng.integers(0, len(m), len(m))]) for _ in range(3000)]
    lo, hi = np.quantile(boot, [0.025, 0.975])  # Monte Carlo error about 0.01
    assert out["ci_low"] == pytest.approx(lo, abs=0.03)
    assert out["ci_high"] == pytest.approx(hi, abs=0.03)
    assert 0 <= out["ci_low"] < out["kendall_w"] < out["ci_high"] <= 1


def test_kendall_w_interval_does_not_collapse_near_zero():
    # no effect: W near 0 and biased upwards, so most resamples exceed it; a BCa interval
    # collapsed onto [0, W] here, the percentile interval covers where the resamples are
    # (this data: W = 0.0019; BCa gave [0, 0.0051], the percentile interval [0.0005, 0.084])
    rng = np.random.default_rng(0)
    m = rng.integers(1, 8, size=(48, 3)).astype(float)
    out = kendall_w_ci(m)
    assert out["kendall_w"] < 0.005
    assert out["ci_high"] > 0.05
    assert out["ci_low"] <= out["kendall_w"]


def test_wrappers_add_the_intervals_to_the_existing_tests():
    wide = _likert(20, seed=5).pivot(index="code", columns="model", values="answer")[MODELS]
    w = wilcoxon_with_ci(wide)
    assert list(w.columns) == ["a", "b", "test", "statistic", "p_value", "p_holm", "rank_biserial", "reason", "warning", "rb_ci_low", "rb_ci_high"]
    for row in w.itertuples():
        single = rank_biserial_ci(wide[row.a], wide[row.b])
        assert (row.rb_ci_low, row.rb_ci_high) == (single["ci_low"], single["ci_high"])
    f = friedman_with_ci(wide.to_numpy())
    assert f["kendall_w_low"] < f["kendall_w"] < f["kendall_w_high"]
    assert f["statistic"] == friedman(wide.to_numpy())["statistic"]


def test_degenerate_rank_intervals_are_nan_not_errors():
    same = rank_biserial_ci([3, 4, 5, 2], [1, 2, 3, 1])  # every difference positive: r = 1 in every resample
    assert same["rank_biserial"] == 1.0
    assert math.isnan(same["ci_low"])
    assert math.isnan(same["ci_high"])
    assert math.isnan(rank_biserial_ci([1, 2], [2, 1])["ci_low"])  # two pairs
    tied = kendall_w_ci(np.ones((6, 3)))
    assert math.isnan(tied["kendall_w"])
    assert math.isnan(tied["ci_low"])


# --- the linear mixed model against the repeated-measures ANOVA ----------------------------------

def _continuous(n: int, seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    person = rng.normal(0, 2.0, n)  # a clear participant effect: the variance component is positive
    effect = {"fem": 0.0, "mass_spring": 0.6, "plate_spring": -0.4}
    return pd.DataFrame([{"code": f"P{i:02d}", "model": m, "item": "q0", "period": (i + j) % 3,
                          "answer": 5 + person[i] + effect[m] + rng.normal(0, 1.0)}
                         for i in range(n) for j, m in enumerate(MODELS)])


@pytest.mark.filterwarnings("ignore:The inplace keyword")  # inside pingouin.rm_anova, with pandas 3
def test_mixed_model_wald_test_is_the_rm_anova_f_on_balanced_data():
    df = _continuous(18, seed=6)
    out = mixed_model(df, MODELS, with_period=False)
    ref = _pg(pg.rm_anova(df, dv="answer", within="model", subject="code", correction=False))
    assert out["converged"]
    assert out["variance_participant"] > 1.0
    t = out["model_test"]
    assert t["df"] == 2
    assert t["df_denominator"] == (18 - 1) * (3 - 1)
    # REML is optimised numerically (statsmodels' default tolerances: about 1e-5 relative on the
    # variances); ML instead of REML, or another denominator, would be off by percents
    assert t["chi2"] / t["df"] == pytest.approx(ref["F"], rel=2e-4)
    assert t["f"] == pytest.approx(ref["F"], rel=2e-4)
    assert t["p_value_f"] == pytest.approx(ref["p_unc"], rel=1e-3)
    # balanced: differences of cell means, with the classical pooled-error standard error sqrt(2 MSE / n)
    y = df.pivot(index="code", columns="model", values="answer")[MODELS].to_numpy()
    resid = y - y.mean(axis=1, keepdims=True) - y.mean(axis=0, keepdims=True) + y.mean()
    mse = float((resid**2).sum()) / ((18 - 1) * (3 - 1))
    for pair in out["pairs"]:
        i, j = MODELS.index(pair["a"]), MODELS.index(pair["b"])
        diff = y[:, j].mean() - y[:, i].mean()
        assert pair["difference"] == pytest.approx(diff, abs=1e-8)
        assert pair["estimable"]
        assert pair["se"] == pytest.approx(math.sqrt(2 * mse / 18), rel=2e-4)
        assert pair["p_value"] == pytest.approx(2 * stats.t.sf(abs(diff) / math.sqrt(2 * mse / 18), 34), rel=1e-3)
    for m in MODELS:
        assert out["means"][m]["mean"] == pytest.approx(y[:, MODELS.index(m)].mean(), abs=1e-8)


def test_mixed_model_with_period_in_a_latin_square_keeps_the_cell_means():
    """Each model in each period equally often: model and period are orthogonal, so the estimated
    marginal means (equal weights over periods) are the cell means."""
    df = _continuous(18, seed=7)
    df["answer"] += 0.8 * df["period"]  # a learning effect
    out = mixed_model(df, MODELS)
    assert out["formula"] == "answer ~ C(model) + C(period) + (1 | code)"
    assert out["model_test"]["df_denominator"] == 32
    cell = df.groupby("model")["answer"].mean()
    for m in MODELS:
        assert out["means"][m]["mean"] == pytest.approx(cell[m], abs=1e-8)
        assert out["means"][m]["ci_low"] < cell[m] < out["means"][m]["ci_high"]


def test_mixed_model_degenerate_data_gives_nan_not_errors():
    flat = _continuous(6, seed=8).assign(answer=3.0)
    out = mixed_model(flat, MODELS)
    assert not out["estimable"]
    assert "every answer alike" in out["problems"]
    assert all(not p["estimable"] and math.isnan(p["p_value"]) for p in out["pairs"])
    assert math.isnan(out["model_test"]["chi2"])
    one_order = _continuous(8, seed=8).assign(period=lambda d: d["model"].map({m: k for k, m in enumerate(MODELS)}))
    assert not mixed_model(one_order, MODELS)["estimable"]  # period confounded with model


# --- the proportional-odds GEE -------------------------------------------------------------------

def _proportional_odds_mle(y: np.ndarray, X: np.ndarray) -> np.ndarray:
    """The cumulative-logit maximum-likelihood coefficients, by hand: P(y > c_j) = expit(a_j + X b),
    thresholds kept decreasing by a_(j+1) = a_j - exp(g_j); minus the multinomial log-likelihood
    minimised by BFGS."""
    cats = np.unique(y)
    k, n = len(cats), len(y)
    idx = np.searchsorted(cats, y)

    def nll(theta):
        a = theta[0] - np.concatenate([[0.0], np.cumsum(np.exp(theta[1:k - 1]))])
        up = expit(a[None, :] + (X @ theta[k - 1:])[:, None])
        ext = np.hstack([np.ones((n, 1)), up, np.zeros((n, 1))])  # P(y > below the lowest) = 1, P(y > top) = 0
        return -np.sum(np.log(ext[np.arange(n), idx] - ext[np.arange(n), idx + 1]))

    res = optimize.minimize(nll, np.zeros(k - 1 + X.shape[1]), method="BFGS", options={"gtol": 1e-9})
    return res.x[k - 1:]


def test_ordinal_gee_with_independence_is_the_proportional_odds_mle():
    df = _likert(40, items=2, seed=9)
    out = ordinal_gee(df, MODELS, dependence="independence")
    X = pd.get_dummies(df[["model", "period", "item"]].astype(str), drop_first=True).astype(float)
    names = list(X.columns)  # model_mass_spring, model_plate_spring, period_1, period_2, item_q1
    b = dict(zip(names, _proportional_odds_mle(df["answer"].to_numpy(), X.to_numpy())))
    beta = {"fem": 0.0, "mass_spring": b["model_mass_spring"], "plate_spring": b["model_plate_spring"]}
    assert out["working_dependence"] == "independence"
    assert out["fallback"] is None
    assert out["estimable"]
    assert out["converged"]
    assert out["formula"] == "answer ~ C(model) + C(period) + C(item)"
    assert out["n_answers"] == 240
    assert out["n_participants"] == 40
    for pair in out["pairs"]:
        ref = beta[pair["b"]] - beta[pair["a"]]
        assert pair["log_odds_ratio"] == pytest.approx(ref, abs=1e-4)
        assert pair["odds_ratio"] == pytest.approx(math.exp(ref), rel=1e-4)
    assert abs(beta["mass_spring"]) > 0.5  # the reference is not a trivial zero


def test_ordinal_gee_odds_ratio_above_one_means_higher_ratings_with_b():
    df = _likert(24, shift=(0.0, 2.0, 0.0), items=3, seed=10)  # mass_spring rated about 2 latent units higher
    out = ordinal_gee(df, MODELS)
    assert out["estimable"]
    assert out["working_dependence"] == "global odds ratio (ordinal)"
    by = {(p["a"], p["b"]): p for p in out["pairs"]}
    up, down = by[("fem", "mass_spring")], by[("mass_spring", "plate_spring")]
    assert up["odds_ratio"] > 3
    assert up["ci_low"] > 1
    assert up["p_value"] < 1e-3
    assert down["odds_ratio"] < 1 / 3
    assert down["ci_high"] < 1
    assert down["p_value"] < 1e-3
    assert 1 / 3 < by[("fem", "plate_spring")]["odds_ratio"] < 3
    # the same direction as the raw data: mass_spring's answers are higher
    means = df.groupby("model")["answer"].mean()
    assert means["mass_spring"] > means["fem"] + 0.5


def test_ordinal_gee_degenerate_data_is_not_estimable_and_does_not_raise():
    flat = _likert(10, seed=11).assign(answer=4)
    out = ordinal_gee(flat, MODELS)
    assert out["estimable"] is False
    assert out["problems"] == ["every answer alike"]
    assert len(out["pairs"]) == 3
    assert all(not p["estimable"] and math.isnan(p["p_value"]) for p in out["pairs"])
    few = _likert(3, items=3, seed=12)
    out = ordinal_gee(few, MODELS)
    assert out["estimable"] is False
    assert "fewer than 5 participants" in out["problems"]
    assert all(not p["estimable"] and math.isnan(p["ci_low"]) for p in out["pairs"])
    top = _likert(12, seed=13)
    top.loc[top["model"] == "plate_spring", "answer"] = 5
    out = ordinal_gee(top, MODELS)
    assert not out["estimable"]
    assert any("plate_spring" in p for p in out["problems"])


# --- one choice among the conditions -------------------------------------------------------------

def _exact_multinomial_by_sequences(counts: list[int]) -> Fraction:
    """Every sequence of n equally likely choices: p = P(a table no more probable than the observed one)."""
    n, k = sum(counts), len(counts)
    seqs = list(itertools.product(range(k), repeat=n))

    def table(s):
        return tuple(s.count(j) for j in range(k))

    prob = {}  # a table's probability = (its number of sequences) / k^n
    for s in seqs:
        prob[table(s)] = prob.get(table(s), 0) + 1
    observed = prob[tuple(counts)]
    return Fraction(sum(c for c in prob.values() if c <= observed), k**n)


def _choices(counts: list[int]) -> pd.Series:
    names = [m for m, c in zip(MODELS, counts) for _ in range(c)]
    return pd.Series(names, index=[f"P{i:02d}" for i in range(len(names))])


def test_exact_multinomial_matches_enumeration_by_hand():
    # n = 4, k = 3, counts (3, 1, 0): tables of the kind (4,0,0) have probability 1/81 (3 of them),
    # (3,1,0) 4/81 (6), (2,2,0) 6/81 (3), (2,1,1) 12/81 (3): p = (3 + 24) / 81 = 1/3
    assert _exact_multinomial_by_sequences([3, 1, 0]) == Fraction(1, 3)
    out = choice_analysis(_choices([3, 1, 0]), MODELS)
    assert out["overall"]["test"].startswith("exact multinomial")
    assert out["overall"]["p_value"] == pytest.approx(1 / 3, abs=1e-12)
    for counts in ([5, 1, 1], [3, 3, 1], [4, 2, 2]):
        ref = float(_exact_multinomial_by_sequences(counts))
        assert choice_analysis(_choices(counts), MODELS)["overall"]["p_value"] == pytest.approx(ref, abs=1e-12)


def test_large_choice_counts_use_chi_square():
    out = choice_analysis(_choices([260, 230, 210]), MODELS)["overall"]
    ref = stats.chisquare([260, 230, 210])
    assert out["test"] == "chi-square goodness of fit"
    assert out["df"] == 2
    assert out["statistic"] == pytest.approx(ref.statistic, rel=1e-12)
    assert out["p_value"] == pytest.approx(ref.pvalue, rel=1e-12)


def test_choice_pairs_are_exact_sign_tests_and_shares_have_wilson_intervals():
    out = choice_analysis(_choices([11, 4, 1]), MODELS)
    for pair in out["pairs"]:
        na, nb = pair["n_a"], pair["n_b"]
        m = na + nb
        # two-sided sign test by hand: twice the smaller tail of Binomial(m, 1/2), at most 1
        hand = min(1.0, 2 * sum(math.comb(m, i) for i in range(min(na, nb) + 1)) / 2**m)
        assert pair["p_value"] == pytest.approx(hand, rel=1e-12)
        assert pair["p_value"] == pytest.approx(stats.binomtest(nb, m, 0.5).pvalue, rel=1e-12)
        assert pair["share_b"] == pytest.approx(nb / m)
    assert [(p["a"], p["b"], p["n_a"], p["n_b"]) for p in out["pairs"]] == [
        ("fem", "mass_spring", 11, 4), ("fem", "plate_spring", 11, 1), ("mass_spring", "plate_spring", 4, 1)]
    # Wilson by hand: (p + z^2/2n +- z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n)
    z, n, x = stats.norm.ppf(0.975), 16, 11
    p = x / n
    centre, half = p + z * z / (2 * n), z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    s = out["shares"]["fem"]
    assert s["count"] == 11
    assert s["share"] == pytest.approx(11 / 16)
    assert s["wilson_low"] == pytest.approx((centre - half) / (1 + z * z / n), rel=1e-12)
    assert s["wilson_high"] == pytest.approx((centre + half) / (1 + z * z / n), rel=1e-12)


def test_wilson_interval_matches_newcombe_1998():
    # Newcombe (1998), Stat Med 17:857, Table I, example (a): 81/263 -> 0.2553 to 0.3662
    out = choice_analysis(_choices([81, 182, 0]), MODELS)
    s = out["shares"]["fem"]
    assert (round(s["wilson_low"], 4), round(s["wilson_high"], 4)) == (0.2553, 0.3662)
    assert out["shares"]["plate_spring"]["count"] == 0
    assert out["shares"]["plate_spring"]["wilson_low"] == pytest.approx(0.0, abs=1e-12)


def test_plackett_luce_strengths_of_top_choices_are_the_shares():
    """The docstring's claim for not fitting Bradley-Terry/Plackett-Luce: with one top choice per
    participant, the maximum-likelihood strengths (normalised) are the choice shares."""
    choices = _choices([9, 5, 2])
    out = choice_analysis(choices, MODELS)
    picked = [MODELS.index(c) for c in choices]

    def nll(theta):  # each participant: P(c chosen first among all k) = exp(theta_c) / sum exp(theta)
        return -sum(theta[c] - np.log(np.exp(theta).sum()) for c in picked)

    theta = optimize.minimize(lambda t: nll(np.append(t, 0.0)), np.zeros(2), method="BFGS", options={"gtol": 1e-10}).x
    strength = np.exp(np.append(theta, 0.0))
    strength /= strength.sum()
    for m, s in zip(MODELS, strength):
        assert s == pytest.approx(out["shares"][m]["share"], abs=1e-5)


def test_choice_analysis_edge_cases():
    out = choice_analysis(pd.Series([None, None], dtype=object), MODELS)
    assert out["n"] == 0
    assert out["n_missing"] == 2
    assert math.isnan(out["overall"]["p_value"])
    assert all(math.isnan(p["p_value"]) for p in out["pairs"])
    with pytest.raises(ValueError, match="unknown"):
        choice_analysis(pd.Series(["fem", "voxels"]), MODELS)


# --- report-table helpers ------------------------------------------------------------------------

def test_mean_ci_and_median_iqr():
    # 1..10: mean 5.5, SD 3.0277; t(0.975, 9) = 2.262 (any t table) -> 5.5 +- 2.262 * 3.0277 / sqrt(10)
    out = mean_ci(list(range(1, 11)) + [float("nan")])
    half = 2.262 * math.sqrt(sum((v - 5.5) ** 2 for v in range(1, 11)) / 9) / math.sqrt(10)
    assert out["n"] == 10
    assert out["mean"] == 5.5
    assert out["sd"] == pytest.approx(3.0277, abs=1e-4)
    assert out["ci_low"] == pytest.approx(5.5 - half, abs=1e-3)
    assert out["ci_high"] == pytest.approx(5.5 + half, abs=1e-3)
    # R: quantile(1:10) -> 1.00 3.25 5.50 7.75 10.00 (type 7)
    assert median_iqr(range(1, 11)) == {"n": 10, "median": 5.5, "q1": 3.25, "q3": 7.75, "iqr": 4.5}
    assert math.isnan(mean_ci([4.0])["ci_low"])
    assert median_iqr([])["n"] == 0
