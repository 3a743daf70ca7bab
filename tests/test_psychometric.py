"""analysis/discrimination/psychometric.py against independent references: psignifit 4 (Schuett et al. 2016)
on the same data, with flat priors (its maximum a posteriori is then the maximum likelihood),
with its own priors on large data, and on its demo data set; noise-free data that must give the
generating parameters exactly; simulated participants whose Weber fractions must be recovered
and covered by the bootstrap intervals at about the nominal rate; pingouin for the group tests;
and degenerate data. psignifit and pingouin are test-only dependencies (pyproject's dev group)."""

import itertools
import json
import math
import warnings

import numpy as np
import pandas as pd
import pytest
from scipy import special, stats

from analysis.discrimination.psychometric import (
    DEGENERATE,
    WEBER_COLUMNS,
    _bounds,
    _fit_many,
    _levels,
    bootstrap_interval,
    fit_psychometric,
    weber_table,
)
from analysis.discrimination.weber_groups import group_test

ps = pytest.importorskip("psignifit")
pg = pytest.importorskip("pingouin")

FUNCTIONS = ("gaussian", "weibull")
Z95 = float(stats.norm.ppf(0.95))
LN_LN2 = math.log(math.log(2.0))
GUMBEL_WIDTH = math.log(-math.log(0.05)) - math.log(-math.log(0.95))


# --- an independent psychometric function (psignifit's parametrisation) -------------------------

def p_correct(function, x, threshold, scale, lapse, guess=0.5):
    """P(correct) on x = ln delta with F = 0.5 at `threshold`, written out here from the
    definitions: the cumulative Gaussian, or the Weibull 1 - exp(-(delta / a) ** b) with b =
    1 / scale and a chosen so that F(threshold) = 0.5."""
    x = np.asarray(x, dtype=float)
    if function == "gaussian":
        F = stats.norm.cdf((x - threshold) / scale)
    else:
        b = 1.0 / scale
        a = math.exp(threshold) / math.log(2.0) ** (1.0 / b)
        F = 1.0 - np.exp(-((np.exp(x) / a) ** b))
    return guess + (1.0 - guess - lapse) * F


def loglik(function, x, k, n, threshold, scale, lapse):
    return float(np.sum(stats.binom.logpmf(k, n, p_correct(function, x, threshold, scale, lapse))))


def simulate(function, weber, scale, lapse, stimulus, rng):
    p = p_correct(function, np.log(stimulus), math.log(weber), scale, lapse)
    return (rng.random(len(stimulus)) < p).astype(int)


def width_to_scale(function, width):
    """psignifit's width (F from 5% to 95%) as the scale on ln delta."""
    return width / (2.0 * Z95 if function == "gaussian" else GUMBEL_WIDTH)


# --- the convention, exactly: noise-free data ----------------------------------------------------

@pytest.mark.parametrize("function", FUNCTIONS)
@pytest.mark.parametrize("lapse", [0.0, 0.03])
def test_noise_free_proportions_give_the_generating_function(function, lapse):
    """Expected counts of a huge binomial at 7 levels: the likelihood's maximum is the
    generating function itself, so every parameter comes back to optimiser precision."""
    weber, scale, n = 0.15, 0.5, 1e6
    x = math.log(weber) + np.linspace(-2.0, 2.0, 7) * scale
    k = n * p_correct(function, x, math.log(weber), scale, lapse)
    fit = fit_psychometric(np.exp(x), k, function=function, trials=np.full(7, n), reference=2.0)
    assert fit.converged
    assert fit.flag == ""
    assert fit.weber == pytest.approx(weber, rel=1e-6)
    assert fit.jnd == pytest.approx(2.0 * weber, rel=1e-6)
    assert fit.scale == pytest.approx(scale, rel=1e-5)
    assert fit.lapse == pytest.approx(lapse, abs=1e-6)
    # the threshold is where F = 0.5: 75% correct without lapses, 0.75 - lapse / 2 with them
    assert float(fit.p_correct([fit.weber])[0]) == pytest.approx(0.75 - lapse / 2, abs=1e-7)
    # the Weibull's own parameters: location = ln a, scale = 1 / b
    if function == "weibull":
        assert math.exp(fit.location) == pytest.approx(weber / math.log(2.0) ** scale, rel=1e-6)
    else:
        assert fit.location == pytest.approx(math.log(weber), abs=1e-6)
    # slope: dP / d ln(delta) at the threshold, by a central difference of the fitted function
    h = 1e-5
    slope = (fit.p_correct([fit.weber * math.exp(h)])[0] - fit.p_correct([fit.weber * math.exp(-h)])[0]) / (2 * h)
    assert fit.slope == pytest.approx(slope, rel=1e-6)
    # width: psignifit's, the ln-delta distance from F = 5% to F = 95%
    assert fit.width == pytest.approx(scale * (2 * Z95 if function == "gaussian" else GUMBEL_WIDTH), rel=1e-5)
    assert fit.n_trials == 7_000_000
    assert fit.n_levels == 7


# --- psignifit ----------------------------------------------------------------------------------

def _flat(lo, hi):
    return lambda v: ((np.asarray(v) >= lo) & (np.asarray(v) <= hi)).astype(float)


def _psignifit(function, x, k, n, flat_priors=False, **kw):
    options = {"sigmoid": "norm" if function == "gaussian" else "weibull", "experiment_type": "2AFC", "verbose": False} | kw
    if flat_priors:
        spread = float(x.max() - x.min())
        options["priors"] = {"threshold": _flat(x.min() - spread / 2, x.max() + spread / 2), "width": _flat(0.0, np.inf),
                             "lambda": _flat(0.0, 0.06)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return ps.psignifit(np.column_stack([x, k, n]), **options).parameter_estimate


# (weber, scale, lapse) of the generating functions: lapses at the bound 0, inside and near 0.06
FLAT_CASES = [(0.1, 0.4, 0.0), (0.2, 0.6, 0.04), (0.3, 0.7, 0.01)]


@pytest.mark.parametrize("function", FUNCTIONS)
def test_same_maximum_as_psignifit_with_flat_priors(function):
    """psignifit with flat priors on threshold, width and lapse rate (lapse in [0, 0.06] as
    here), overdispersion fixed at 0 and the same sigmoid on ln delta: its maximum a posteriori
    is the maximum likelihood, found independently (grids and Nelder-Mead). Measured on these
    data: ln thresholds within 2e-5, widths within 6e-5 relative, lapse rates within 4e-6, and
    our likelihood the higher by 1e-9 to 2e-7 (on other data sets its simplex stopped up to
    8e-4 away in ln threshold)."""
    rng = np.random.default_rng(11)
    for weber, scale, lapse in FLAT_CASES:
        x = math.log(weber) + np.linspace(-2.2, 2.5, 9) * scale
        n = np.full(9, 60.0)
        k = rng.binomial(60, p_correct(function, x, math.log(weber), scale, lapse)).astype(float)
        fit = fit_psychometric(np.exp(x), k, function=function, trials=n, scale_min=0.01)
        est = _psignifit(function, x, k, n, flat_priors=True, fixed_parameters={"eta": 0.0}, bounds={"lambda": (0.0, 0.06)})
        assert math.log(fit.weber) == pytest.approx(est["threshold"], abs=2e-4)
        assert fit.width == pytest.approx(est["width"], rel=5e-4)
        assert fit.lapse == pytest.approx(est["lambda"], abs=1e-4)
        ours = loglik(function, x, k, n, math.log(fit.weber), fit.scale, fit.lapse)
        theirs = loglik(function, x, k, n, est["threshold"], width_to_scale(function, est["width"]), est["lambda"])
        log_binomial = float(np.sum(stats.binom.logpmf(k, n, 0.5) - n * math.log(0.5)))  # ln C(n, k): not in fit.loglik
        assert ours == pytest.approx(fit.loglik + log_binomial, abs=1e-6)
        assert ours >= theirs - 1e-9


@pytest.mark.parametrize("function", FUNCTIONS)
def test_psignifit_with_its_own_priors_agrees_on_large_data(function):
    """psignifit as shipped (its priors, overdispersion estimated, maximum a posteriori) on 2400
    trials at 12 levels: the priors barely matter. Measured: ln thresholds 4.4e-4 to 5.8e-4 above
    ours (its lapse prior pulls the lapse rate down, by 2e-4 to 3.8e-4)."""
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        weber, scale, lapse = 0.15, 0.5, 0.02
        x = math.log(weber) + np.linspace(-2.5, 3.0, 12) * scale
        n = np.full(12, 200.0)
        k = rng.binomial(200, p_correct(function, x, math.log(weber), scale, lapse)).astype(float)
        fit = fit_psychometric(np.exp(x), k, function=function, trials=n)
        est = _psignifit(function, x, k, n)
        assert math.log(fit.weber) == pytest.approx(est["threshold"], abs=5e-3)
        assert fit.lapse == pytest.approx(est["lambda"], abs=3e-3)


# psignifit's demo data (its docs' basic usage and tests/data.py: a 2AFC signal-detection run, 90
# trials at each of 13 levels) and the threshold its tests print for it, from the MATLAB
# psignifit ("parm_heiko" in python-psignifit's tests/test_psignifit.py): cumulative Gaussian
# on the linear stimulus, threshold 0.0046448472488663396
DEMO = np.array([[0.0010, 45, 90], [0.0015, 50, 90], [0.0020, 44, 90], [0.0025, 44, 90], [0.0030, 52, 90], [0.0035, 53, 90],
                 [0.0040, 62, 90], [0.0045, 64, 90], [0.0050, 76, 90], [0.0060, 79, 90], [0.0070, 88, 90], [0.0080, 90, 90],
                 [0.0100, 90, 90]], dtype=float)
DEMO_THRESHOLD = 0.0046448472488663396


def test_psignifit_demo_data():
    """Our model is on ln delta; given delta = exp(level), ln delta is the level itself, so the
    fit is psignifit's Gaussian on the linear level (a small scale_min: the levels span 0.009).
    Measured: 0.0046478 against the printed 0.0046448 (MAP with priors; 6.5e-4 relative), and
    2e-5 relative from the installed psignifit with overdispersion fixed at 0. On the ln levels
    themselves, psignifit's 0.0045362 against our 0.0045352 (2e-4 relative)."""
    level, k, n = DEMO.T
    fit = fit_psychometric(np.exp(level), k, trials=n, scale_min=1e-5, function="gaussian")
    assert fit.converged
    assert math.log(fit.weber) == pytest.approx(DEMO_THRESHOLD, rel=2e-3)
    no_overdispersion = _psignifit("gaussian", level, k, n, fixed_parameters={"eta": 0.0})
    assert math.log(fit.weber) == pytest.approx(no_overdispersion["threshold"], rel=2e-4)
    on_logs = fit_psychometric(level, k, trials=n, function="gaussian")
    assert on_logs.weber == pytest.approx(math.exp(_psignifit("gaussian", np.log(level), k, n)["threshold"]), rel=2e-3)


# --- recovery and coverage ----------------------------------------------------------------------

@pytest.mark.parametrize("function", FUNCTIONS)
def test_recovers_a_known_function(function):
    """30 simulated observers, 1600 trials each (16 levels over +-3 scales), true Weber fraction
    0.15. Measured: ln(fitted / true) has mean 0.009 (gaussian), 0.007 (weibull), sd 0.065 and
    0.061, largest 0.16 and 0.17."""
    weber, scale, lapse = 0.15, 0.5, 0.02
    stimulus = np.repeat(weber * np.exp(np.linspace(-1.5, 1.5, 16)), 100)
    errors, scales, lapses = [], [], []
    for seed in range(30):
        correct = simulate(function, weber, scale, lapse, stimulus, np.random.default_rng(seed))
        fit = fit_psychometric(stimulus, correct, function=function)
        assert fit.converged
        errors.append(math.log(fit.weber / weber))
        scales.append(fit.scale)
        lapses.append(fit.lapse)
    errors = np.array(errors)
    assert abs(errors.mean()) < 0.04  # 3 standard errors of the mean
    assert errors.std() < 0.1
    assert np.abs(errors).max() < 0.25
    assert np.median(scales) == pytest.approx(scale, rel=0.15)
    assert np.median(lapses) == pytest.approx(lapse, abs=0.01)


@pytest.mark.parametrize("function", FUNCTIONS)
def test_bootstrap_interval_covers_the_truth(function):
    """200 simulated participants of 60 trials (10 levels, 6 each), 200 replicates each.
    Measured coverage 0.905-0.935 over three seeds, both functions (a percentile interval of a
    maximum-likelihood threshold from 60 trials is a little short of 95%); the band allows about
    2 binomial standard deviations either side."""
    weber, scale, lapse = 0.15, 0.5, 0.02
    stimulus = np.repeat(weber * np.exp(np.linspace(-1.5, 1.5, 10)), 6)
    rng = np.random.default_rng(1)
    hits = 0
    for r in range(200):
        fit = fit_psychometric(stimulus, simulate(function, weber, scale, lapse, stimulus, rng), function=function, n_boot=200, seed=r)
        assert fit.ci_low <= fit.weber <= fit.ci_high
        assert fit.n_boot == 200
        hits += fit.ci_low <= weber <= fit.ci_high
    assert 0.87 <= hits / 200 <= 0.98


@pytest.mark.parametrize("function", FUNCTIONS)
def test_vectorised_refit_finds_the_maximum(function):
    """The bootstrap's refits (all replicates at once) against fit_psychometric (grid, Fisher
    scoring from many starts, L-BFGS-B) on the same 200 simulated data sets: the same maximum to
    1e-6 in all but a few, never a higher one. Measured: 2.5% of these replicates (40 trials at
    10 levels) stop at a lower local maximum; 1.1% over replicates of 40 other designs."""
    rng = np.random.default_rng(3)
    stimulus = np.repeat(0.15 * np.exp(np.linspace(-1.5, 1.5, 10)), 4)
    fit = fit_psychometric(stimulus, simulate(function, 0.15, 0.5, 0.02, stimulus, rng), function=function)
    x, _, n = _levels(stimulus, np.zeros(len(stimulus)))
    k = rng.binomial(n.astype(int), fit.p_correct(np.exp(x)), size=(200, len(x))).astype(float)
    warm = np.array([fit.location, math.log(fit.scale), fit.lapse])
    theta = _fit_many(function, 0.5, x, k, n, _bounds(x, fit.lapse_max, fit.scale_min), warm)
    gaps = []
    for i in range(len(k)):
        ref = fit_psychometric(np.exp(x), k[i], function=function, trials=n)
        if ref.flag in DEGENERATE:
            continue
        t = math.exp(theta[i, 1])
        ours = loglik(function, x, k[i], n, theta[i, 0] + (LN_LN2 * t if function == "weibull" else 0.0), t, theta[i, 2])
        best = loglik(function, x, k[i], n, math.log(ref.weber), ref.scale, ref.lapse)
        gaps.append(best - ours)
    gaps = np.array(gaps)
    assert gaps.min() > -1e-6
    assert np.mean(gaps > 1e-6) < 0.05


def test_bootstrap_is_reproducible_and_per_row():
    rng = np.random.default_rng(5)
    stimulus = np.repeat(0.15 * np.exp(np.linspace(-1.5, 1.5, 8)), 5)
    correct = simulate("gaussian", 0.15, 0.5, 0.02, stimulus, rng)
    fit = fit_psychometric(stimulus, correct)
    assert bootstrap_interval(fit, stimulus, n_boot=300, rng=7) == bootstrap_interval(fit, stimulus, n_boot=300, rng=7)
    assert fit_psychometric(stimulus, correct, n_boot=300, seed=7).ci_low == bootstrap_interval(fit, stimulus, n_boot=300, rng=7)[0]
    # a row's interval does not depend on which other rows the table has
    trials = pd.DataFrame({"code": np.repeat(["P01", "P02"], len(stimulus)), "condition": "fem", "stimulus": np.tile(stimulus, 2),
                           "correct": np.concatenate([correct, simulate("gaussian", 0.2, 0.5, 0.02, stimulus, rng)])})
    both = weber_table(trials, n_boot=200)
    one = weber_table(trials[trials["code"] == "P02"], n_boot=200)
    assert list(both.columns) == WEBER_COLUMNS
    assert one.iloc[0]["ci_low"] == both.iloc[1]["ci_low"]
    assert one.iloc[0]["ci_high"] == both.iloc[1]["ci_high"]


# --- degenerate data ----------------------------------------------------------------------------

@pytest.mark.parametrize("function", FUNCTIONS)
@pytest.mark.parametrize("case, flag", [("all_correct", "all_correct"), ("all_wrong", "at_chance"), ("one_level", "one_level"),
                                        ("one_trial", "one_level"), ("chance", "at_chance")])
def test_degenerate_data_give_a_flagged_finite_fit(function, case, flag):
    stimulus = np.repeat([0.05, 0.1, 0.2, 0.4], 10)
    correct = {"all_correct": np.ones(40), "all_wrong": np.zeros(40), "one_level": np.tile([1, 0, 1, 1], 10),
               "one_trial": np.ones(1), "chance": np.tile([1, 0], 20)}[case]
    if case in ("one_level", "one_trial"):
        stimulus = np.full(len(correct), 0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning (log of 0, 0 * inf) on the way either
        fit = fit_psychometric(stimulus, correct, function=function, n_boot=100)
        assert all(math.isnan(v) for v in bootstrap_interval(fit, stimulus, n_boot=100))
    assert fit.flag == flag
    assert not fit.converged
    for v in (fit.weber, fit.jnd, fit.location, fit.scale, fit.width, fit.slope, fit.lapse, fit.loglik):
        assert math.isfinite(v)
    assert math.isnan(fit.ci_low)  # documented: no interval from a bound
    assert math.isnan(fit.ci_high)
    if flag == "all_correct":
        assert fit.weber < stimulus.min()  # the threshold below anything tested
    if flag == "at_chance":
        assert fit.weber > stimulus.max()


def test_no_trend_is_flagged_shallow():
    """75% correct at every level: any function through 75% everywhere fits, the flattest best."""
    stimulus = np.repeat([0.05, 0.1, 0.2, 0.4], 20)
    fit = fit_psychometric(stimulus, np.tile([1, 1, 1, 0], 20), n_boot=50, function="gaussian")
    assert fit.flag == "shallow"
    assert not fit.converged
    assert fit.scale == pytest.approx(2 * math.log(8.0))  # the upper bound: twice the span of ln delta
    assert all(math.isfinite(v) for v in (fit.weber, fit.ci_low, fit.ci_high))


@pytest.mark.parametrize("kwargs, message", [
    ({"stimulus": [0.1, -0.2], "correct": [1, 0]}, "stimulus"),
    ({"stimulus": [0.1, 0.2], "correct": [1, 2]}, "correct"),
    ({"stimulus": [], "correct": []}, "no trials"),
    ({"stimulus": [0.1, 0.2], "correct": [1]}, "lengths"),
    ({"stimulus": [0.1, 0.2], "correct": [1, 0], "function": "logistic"}, "function"),
    ({"stimulus": [0.1, 0.2], "correct": [3, 0], "trials": [2, 2]}, "trials"),
])
def test_invalid_input_raises(kwargs, message):
    with pytest.raises(ValueError, match=message):
        fit_psychometric(**kwargs)


def test_weber_table_rows_and_degenerate_rows():
    rng = np.random.default_rng(2)
    stimulus = np.repeat(0.15 * np.exp(np.linspace(-1.5, 1.5, 8)), 5)
    rows = []
    for code, cond, weber in [("P02", "mass_spring", 0.2), ("P01", "fem", 0.1), ("P01", "mass_spring", 0.3), ("P02", "fem", 0.15)]:
        correct = simulate("gaussian", weber, 0.5, 0.02, stimulus, rng)
        if (code, cond) == ("P02", "fem"):
            correct = np.ones(len(stimulus), int)  # degenerate: every answer correct
        rows.append(pd.DataFrame({"code": code, "condition": cond, "trial": np.arange(len(stimulus)), "stimulus": stimulus,
                                  "correct": correct}))
    table = weber_table(pd.concat(rows, ignore_index=True), n_boot=100)
    assert list(table.columns) == WEBER_COLUMNS
    assert list(zip(table["code"], table["condition"])) == [("P01", "fem"), ("P01", "mass_spring"), ("P02", "fem"),
                                                             ("P02", "mass_spring")]
    assert (table["n_trials"] == 40).all()
    bad = table.iloc[2]
    assert bad["flag"] == "all_correct"
    assert not bad["converged"]
    assert math.isfinite(bad["weber"])
    assert math.isnan(bad["ci_low"])
    good = table.drop(index=2)
    assert (good["ci_low"] <= good["weber"]).all()
    assert (good["weber"] <= good["ci_high"]).all()
    with pytest.raises(ValueError, match="missing columns"):
        weber_table(pd.DataFrame({"code": ["P01"], "stimulus": [0.1], "correct": [1]}))


# --- group tests --------------------------------------------------------------------------------

CONDITIONS = ["fem", "mass_spring", "plate_spring"]


def _table(n=12, effects=(0.0, 0.15, 0.45), person_sd=0.4, noise_sd=0.3, seed=0, conditions=CONDITIONS) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    person = rng.normal(0, person_sd, n)
    return pd.DataFrame([{"code": f"P{i:02d}", "condition": c, "weber": 0.15 * math.exp(person[i] + e + rng.normal(0, noise_sd)),
                          "converged": True} for i in range(n) for c, e in zip(conditions, effects)])


def _holm_by_hand(p):
    order = np.argsort(p)
    m, out, running = len(p), np.empty(len(p)), 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[i]))
        out[i] = running
    return out


def test_group_test_matches_pingouin(monkeypatch):
    monkeypatch.setitem(pg.options, "round.column.CI95", None)  # pingouin prints its interval to 2 decimals
    table = _table()
    g = group_test(table, CONDITIONS)
    json.dumps(g, allow_nan=False)  # JSON as it stands
    assert g["estimable"]
    assert g["n_participants"] == 12
    assert g["excluded"] == []
    assert g["conditions"] == CONDITIONS
    wide = np.log(table.pivot(index="code", columns="condition", values="weber")[CONDITIONS])
    long = table.assign(lw=np.log(table["weber"]))
    fr = pg.friedman(long, dv="lw", within="condition", subject="code").iloc[0]
    assert g["friedman"]["test"] == "Friedman"
    assert g["friedman"]["df"] == 2
    assert g["friedman"]["statistic"] == pytest.approx(float(fr["Q"]), rel=1e-9)
    assert g["friedman"]["p"] == pytest.approx(float(fr["p_unc"]), rel=1e-9)
    assert [(p["a"], p["b"]) for p in g["pairs"]] == list(itertools.combinations(CONDITIONS, 2))
    for pair in g["pairs"]:
        b, a = wide[pair["b"]].to_numpy(), wide[pair["a"]].to_numpy()
        t = pg.ttest(b, a, paired=True).iloc[0]
        assert pair["p"] == pytest.approx(float(t["p_val"]), rel=1e-9)
        assert pair["t"] == pytest.approx(float(t["T"]), rel=1e-9)
        assert pair["df"] == 11
        lo, hi = t["CI95"]
        assert pair["ratio"] == pytest.approx(math.exp(np.mean(b - a)), rel=1e-12)
        assert pair["ratio_low"] == pytest.approx(math.exp(lo), rel=1e-9)
        assert pair["ratio_high"] == pytest.approx(math.exp(hi), rel=1e-9)
        w = pg.wilcoxon(b, a).iloc[0]
        assert pair["p_wilcoxon"] == pytest.approx(float(w["p_val"]), rel=1e-9)
        assert pair["wilcoxon"] == pytest.approx(float(w["W_val"]))
    for key, holm_key in (("p", "p_holm"), ("p_wilcoxon", "p_wilcoxon_holm")):
        by_hand = _holm_by_hand(np.array([p[key] for p in g["pairs"]]))
        assert [p[holm_key] for p in g["pairs"]] == pytest.approx(list(by_hand), rel=1e-12)


@pytest.mark.filterwarnings("ignore:The inplace keyword")  # inside pingouin.rm_anova, with pandas 3
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_mixed_model_likelihood_ratio_against_the_anova(seed):
    """Balanced, complete, one value per participant and condition: the ML random-intercept
    model's likelihood splits into participants' means and within-participant contrasts, and
    only the latter depend on condition, so (with a positive participant variance) the LR
    statistic is n (k - 1) ln(1 + F / (n - 1)) with F the repeated-measures ANOVA's (pingouin).
    Measured: equal to 1e-9 relative. Its chi-square p is smaller than the F test's (the LR
    test is liberal with 12 participants): measured ratios 0.52-0.96 on these tables."""
    table = _table(seed=seed, effects=(0.0, 0.1, 0.25))
    g = group_test(table)
    mm = g["mixed_model"]
    assert mm["converged"]
    assert mm["variance_participant"] > 0
    assert mm["df"] == 2
    assert mm["n_observations"] == 36
    aov = pg.rm_anova(table.assign(lw=np.log(table["weber"])), dv="lw", within="condition", subject="code", correction=False).iloc[0]
    n, k = 12, 3
    assert mm["chi2"] == pytest.approx(n * (k - 1) * math.log(1 + float(aov["F"]) / (n - 1)), rel=1e-5)
    assert mm["p"] == pytest.approx(float(stats.chi2.sf(mm["chi2"], 2)), rel=1e-12)
    assert 0.4 < mm["p"] / float(aov["p_unc"]) <= 1.0


def test_group_test_two_conditions_incomplete_and_too_few():
    table = _table(conditions=["fem", "plate_spring"], effects=(0.0, 0.4))
    g = group_test(table)
    wide = np.log(table.pivot(index="code", columns="condition", values="weber"))
    w = pg.wilcoxon(wide["plate_spring"].to_numpy(), wide["fem"].to_numpy()).iloc[0]
    assert g["friedman"]["test"] == "Wilcoxon signed-rank"
    assert g["friedman"]["df"] is None
    assert g["friedman"]["p"] == pytest.approx(float(w["p_val"]), rel=1e-9)
    assert g["pairs"][0]["p_holm"] == pytest.approx(g["pairs"][0]["p"], rel=1e-12)  # one pair: Holm changes nothing
    # a participant without one condition, one whose fit gave no Weber fraction: left out, said so
    t3 = _table()
    t3 = t3[~((t3["code"] == "P03") & (t3["condition"] == "fem"))].copy()
    t3.loc[(t3["code"] == "P05") & (t3["condition"] == "fem"), "weber"] = math.nan
    t3.loc[(t3["code"] == "P06") & (t3["condition"] == "fem"), "converged"] = False
    g3 = group_test(t3)
    assert g3["n_participants"] == 10
    assert g3["excluded"] == ["P03", "P05"]
    assert g3["n_not_converged"] == 1
    # one condition, or too few complete participants: no tests, no exception, JSON all the same
    for bad, problem in ((_table()[lambda d: d["condition"] == "fem"], "fewer than 2 conditions"),
                         (_table(n=2), "fewer than 3 participants")):
        g = group_test(bad)
        json.dumps(g, allow_nan=False)
        assert not g["estimable"]
        assert g["mixed_model"] is None
        assert g["friedman"] is None
        assert any(problem in p for p in g["problems"])
    with pytest.raises(ValueError, match="two rows"):
        group_test(pd.concat([_table(), _table().iloc[:1]]))


# --- the reports' function: the two-interval observer on the log stiffness ratio ----------------

def sdt_observer(delta, weber, lapse):
    """P(correct) of the two-interval observer of signal detection theory with Weber-law noise,
    written out from its definition (docs/study.md, studyctl/synthetic/observer.py): it picks the stiffer
    interval when ln(1 + delta) plus Gaussian noise of sd ln(1 + weber) / z75 is positive, and
    guesses with probability `lapse`."""
    z75 = stats.norm.ppf(0.75)
    return lapse / 2 + (1 - lapse) * stats.norm.cdf(np.log1p(np.asarray(delta, dtype=float)) * z75 / math.log1p(weber))


def test_thurstone_terms_are_the_closed_form():
    from analysis.discrimination.psychometric import _log_cdf

    z = np.linspace(-30.0, 3.4, 400)
    logF, logQ, logf = _log_cdf("thurstone", z)
    t = np.exp(z)  # F = 2 Phi(t) - 1 = erf(t / sqrt 2), 1 - F = 2 Phi(-t)
    assert np.allclose(np.exp(logF), special.erf(t / math.sqrt(2)), rtol=1e-12, atol=0)
    assert np.allclose(np.exp(logQ), 2 * stats.norm.sf(t), rtol=1e-12, atol=0)
    assert np.allclose(np.exp(logf), 2 * stats.norm.pdf(np.exp(z)) * np.exp(z), rtol=1e-12)  # dF/dz


@pytest.mark.parametrize("lapse", [0.0, 0.04])
def test_thurstone_noise_free_gives_the_observer(lapse):
    """Expected counts of the SDT observer (written out above, independent of the fit's code) at
    8 increments: the fit returns its Weber fraction, and its lapse as the observer's half (a
    lapsed trial is a guess, right half the time)."""
    weber, n = 0.18, 1e6
    delta = weber * np.exp(np.linspace(-2.0, 1.5, 8))
    fit = fit_psychometric(delta, n * sdt_observer(delta, weber, lapse), trials=np.full(8, n), function="thurstone")
    assert fit.converged
    assert fit.flag == ""
    assert fit.scale == 1.0
    assert fit.weber == pytest.approx(weber, rel=1e-6)
    assert fit.lapse == pytest.approx(lapse / 2, abs=1e-6)
    assert float(fit.p_correct([weber])[0]) == pytest.approx(0.75 - lapse / 4, abs=1e-7)
    h = 1e-5  # the slope per unit of the fit's axis, ln ln(1 + delta)
    up, down = math.expm1(math.log1p(weber) * math.exp(h)), math.expm1(math.log1p(weber) * math.exp(-h))
    assert fit.slope == pytest.approx((fit.p_correct([up])[0] - fit.p_correct([down])[0]) / (2 * h), rel=1e-6)


def test_thurstone_recovers_and_covers_the_observer():
    """150 simulated observers (Weber fractions 7-27%, lapses 0-4%: the synthetic participants'
    ranges), 40 trials at increments log-uniform in the task's range 0.02-1: the reports' fit.
    Measured: median absolute error 29.5%, the bootstrap interval covering 85-90% (Gaussian on
    ln delta: 36%, 87%); the band allows about 2 binomial standard deviations either side."""
    rng = np.random.default_rng(1)
    errors, hits = [], 0
    for r in range(150):
        weber, lapse = rng.uniform(0.07, 0.27), rng.uniform(0.0, 0.04)
        delta = np.exp(rng.uniform(math.log(0.02), 0.0, 40))
        correct = (rng.random(40) < sdt_observer(delta, weber, lapse)).astype(int)
        fit = fit_psychometric(delta, correct, n_boot=200, seed=r)
        assert fit.function == "thurstone"
        assert math.isfinite(fit.weber)
        errors.append(abs(fit.weber - weber) / weber)
        hits += fit.ci_low <= weber <= fit.ci_high
    assert np.median(errors) < 0.33
    assert 0.80 <= hits / 150 <= 0.96


def test_pooling_over_participants_recovers_them_better_than_their_own_fits():
    """60 simulated observers of one condition (Weber fractions log-normal around 12%, lapses
    0-4%), 40 trials each at increments log-uniform in 0.02-1: each participant's pooled estimate
    (hierarchical over the 60) against the generating value, beside their own fits. Measured:
    median error 19.7% pooled against 22.1% own; the credible intervals cover 95% (the band allows
    about 2 binomial standard deviations of 60 fits)."""
    from analysis.discrimination.pooled import POOLED_MIN, pooled_webers

    rng = np.random.default_rng(4)
    rows, truth = [], {}
    for i in range(60):
        weber, lapse = float(np.exp(rng.normal(math.log(0.12), 0.35))), rng.uniform(0.0, 0.04)
        delta = np.exp(rng.uniform(math.log(0.02), 0.0, 40))
        correct = (rng.random(40) < sdt_observer(delta, weber, lapse)).astype(int)
        truth[f"P{i:02d}"] = weber
        rows.append(pd.DataFrame({"code": f"P{i:02d}", "condition": "c", "stimulus": delta, "correct": correct}))
    trials = pd.concat(rows, ignore_index=True)
    pooled = pooled_webers(trials)
    own = weber_table(trials, n_boot=0)
    g = np.array([truth[c] for c in pooled["code"]])
    pooled_error = np.median(np.abs(pooled["weber_pooled"] - g) / g)
    own_error = np.median(np.abs(own["weber"].to_numpy() - np.array([truth[c] for c in own["code"]])) / g)
    covered = np.mean((pooled["pooled_low"] <= g) & (g <= pooled["pooled_high"]))
    assert pooled_error < 0.9 * own_error, (pooled_error, own_error, covered)
    assert 0.80 <= covered <= 0.99, (pooled_error, own_error, covered)
    few = pooled_webers(trials[trials["code"].isin(list(truth)[:POOLED_MIN - 1])])
    assert few["weber_pooled"].isna().all()  # too few participants to pool over
