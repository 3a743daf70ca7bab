"""Psychometric functions of the two-interval stiffness discrimination task (studyctl/tasks.py):
per participant and condition a maximum-likelihood fit (`fit_psychometric`) and its Weber fraction
with a parametric-bootstrap interval (`bootstrap_interval`, `weber_table`). Degenerate data give a
flagged fit (`FLAGS`), never NaN or an exception. The model, the fit, the flags and how well they
recover known Weber fractions: docs/study.md, "The psychometric fit"; the group test across
conditions: analysis/discrimination/weber_groups.py."""

from __future__ import annotations

import dataclasses
import functools
import math
import zlib
from typing import NamedTuple

import numpy as np
import pandas as pd
from scipy import optimize, special, stats
from threadpoolctl import ThreadpoolController

FUNCTIONS = ("gaussian", "weibull", "thurstone")
# the reports' function: the two-interval observer of signal detection theory on the log stiffness
# ratio, the one that recovers synthetic participants' Weber fractions best (docs/study.md)
DEFAULT_FUNCTION = "thurstone"
GUESS = 0.5  # two intervals
LAPSE_MAX = 0.06
# the steepest function fitted by "gaussian" and "weibull" (scale in ln delta; "thurstone" holds
# its scale at 1): the Weibull slope 5, the steepest the QUEST+ procedure considers
# (studyctl/session/procedures.py); a lower floor let bootstraps from near-steps miss the truth (docs/study.md)
SCALE_MIN = 0.2
# replicates of the parametric bootstrap: its endpoints' Monte Carlo noise against the report's
# time (both in docs/study.md)
N_BOOT = 500
BOOTSTRAP_SEED = 2015  # fixed: a report computed twice prints the same intervals
LEVEL = 0.95
ONE_LEVEL_SPAN = math.log(2.0)  # the ln-stimulus span that sets the bounds when one level was tested
FLAGS = ("all_correct", "at_chance", "one_level", "location_at_bound", "shallow", "optimizer", "steep")
DEGENERATE = ("all_correct", "at_chance", "one_level")
CONVERGED_FLAGS = ("", "steep")  # the flags a fit may carry and still count as converged
WEBER_COLUMNS = ["code", "condition", "n_trials", "weber", "ci_low", "ci_high", "lapse", "slope", "converged", "flag"]
NAN = float("nan")
POLISH_ITERATIONS = 25  # Fisher-scoring steps per refit; `_polish` says why not more
HALVINGS = 12

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
# z where F = 1/2 (the threshold), F's density there, and the width of psignifit (F from 5% to 95%)
_Z75 = float(stats.norm.ppf(0.75))
_Z_HALF = {"gaussian": 0.0, "weibull": math.log(math.log(2.0)), "thurstone": math.log(_Z75)}
_DENSITY_HALF = {"gaussian": 1.0 / math.sqrt(2.0 * math.pi), "weibull": 0.5 * math.log(2.0),
                 "thurstone": math.sqrt(2.0 / math.pi) * math.exp(-0.5 * _Z75 * _Z75) * _Z75}
_Z_WIDTH = {"gaussian": 2.0 * float(stats.norm.ppf(0.95)), "weibull": math.log(-math.log(0.05)) - math.log(-math.log(0.95)),
            "thurstone": math.log(float(stats.norm.ppf(0.975))) - math.log(float(stats.norm.ppf(0.525)))}
# z beyond these changes no probability that matters (1 - F < 1e-260) and keeps 1 / (1 - P) finite
_Z_CLIP = {"gaussian": (-35.0, 35.0), "weibull": (-35.0, 6.5), "thurstone": (-35.0, 3.4)}


def _axis(function: str, delta) -> np.ndarray:
    """The stimulus axis x a function is fitted on: ln delta (gaussian, weibull), or the log of
    the log stiffness ratio, ln ln(1 + delta) (thurstone: the ratio the task varies)."""
    d = np.asarray(delta, dtype=float)
    return np.log(np.log1p(d)) if function == "thurstone" else np.log(d)


def _delta(function: str, x):
    """The increment at axis value x (the inverse of `_axis`)."""
    return np.expm1(np.exp(x)) if function == "thurstone" else np.exp(x)


@dataclasses.dataclass(frozen=True)
class PsychometricFit:
    """A maximum-likelihood psychometric function (docs/study.md). `location`, `scale` and
    `width` are in ln(delta); `slope` is dP(correct)/d ln(delta) at the threshold (per e-fold of
    the increment; divide by `weber` for per unit delta). `width`: psignifit's, the ln-delta
    distance over which F rises from 5% to 95%. `converged` is False whenever `flag` is set but
    to "steep" (docs/study.md: the flags). `ci_low`, `ci_high`: NaN unless fitted with n_boot > 0."""

    function: str
    guess: float
    lapse_max: float
    scale_min: float
    reference: float
    weber: float  # the increment at F = 0.5 (75% correct without lapses), relative to the reference
    jnd: float  # weber * reference
    location: float
    scale: float
    width: float
    slope: float
    lapse: float
    loglik: float
    n_trials: int
    n_levels: int
    converged: bool
    flag: str  # "" or one of FLAGS
    ci_low: float = NAN
    ci_high: float = NAN
    ci_level: float = NAN
    n_boot: int = 0

    def p_correct(self, stimulus) -> np.ndarray:
        """The fitted P(correct) at increments `stimulus`."""
        x = _axis(self.function, stimulus)
        t = _terms(self.function, self.guess, x, self.location, math.log(self.scale), self.lapse)
        return np.exp(t.logP)


# --- the model ----------------------------------------------------------------------------------

class _Terms(NamedTuple):
    z: np.ndarray
    logP: np.ndarray
    log1mP: np.ndarray
    logF: np.ndarray
    logf: np.ndarray
    logA: np.ndarray


def _log_cdf(function: str, z: np.ndarray):
    """ln F, ln(1 - F) and ln F' at z, accurate in both tails."""
    if function == "gaussian":
        # one ndtr for the smaller tail, accurate down to 1e-268 at |z| = 35 (the clip): half
        # the time of two log_ndtr calls, which dominated the bootstrap
        tail = special.ndtr(-np.abs(z))
        log_tail, log_body = np.log(tail), np.log1p(-tail)
        below = z < 0
        return np.where(below, log_tail, log_body), np.where(below, log_body, log_tail), -0.5 * z * z - _LOG_SQRT_2PI
    if function == "thurstone":
        # F = 2 Phi(t) - 1 = erf(t / sqrt 2), t = e^z: the two-interval observer of signal
        # detection theory, P = Phi(t) without lapses; erf directly where F is small, 1 - erfc
        # where it is near 1
        t = np.exp(z)
        u = t / math.sqrt(2.0)
        logQ = math.log(2.0) + special.log_ndtr(-t)
        logF = np.where(t < 1.0, np.log(special.erf(np.minimum(u, 1.0))), np.log1p(-special.erfc(np.maximum(u, 0.5))))
        return logF, logQ, 0.5 * math.log(2.0 / math.pi) - 0.5 * t * t + z
    ez = np.exp(z)
    return np.log(-np.expm1(-ez)), -ez, z - ez


def _terms(function: str, guess: float, x, location, log_scale, lapse) -> _Terms:
    """Everything the likelihood and its derivatives need; broadcasts parameters (B, 1) against
    levels (J,). In logs: 1 - P is lapse + A (1 - F), which underflows where F is near 1."""
    z = np.clip((x - location) / np.exp(log_scale), *_Z_CLIP[function])
    logF, logQ, logf = _log_cdf(function, z)
    logA = np.log1p(-(guess + np.asarray(lapse, dtype=float)))
    with np.errstate(divide="ignore"):
        logP = np.logaddexp(np.log(guess), logA + logF)
        log1mP = np.logaddexp(np.log(lapse), logA + logQ)
    return _Terms(z, logP, log1mP, logF, logf, logA)


def _loglik(t: _Terms, k: np.ndarray, n: np.ndarray) -> np.ndarray:
    return np.sum(k * t.logP + (n - k) * t.log1mP, axis=-1)


def _score(t: _Terms, k, n, log_scale) -> np.ndarray:
    """d loglik / d(location, ln scale, lapse), shape (..., 3)."""
    w = k * np.exp(-t.logP) - (n - k) * np.exp(-t.log1mP)  # d loglik / dP per level
    dz = w * np.exp(t.logA + t.logf)  # dP/dz = A f
    inv_scale = np.exp(-np.asarray(log_scale, dtype=float))  # scalar, or (B, 1) against (B, J)
    return np.stack([-np.sum(dz * inv_scale, axis=-1), -np.sum(dz * t.z, axis=-1), -np.sum(w * np.exp(t.logF), axis=-1)], axis=-1)


def _fisher(t: _Terms, n, log_scale) -> np.ndarray:
    """Expected information sum n dP dP' / (P (1 - P)), shape (B, 3, 3); each factor scaled by
    1 / sqrt(P (1 - P)) first so no term overflows."""
    h = 0.5 * (t.logP + t.log1mP)
    g = np.exp(t.logA + t.logf - h)
    d = np.stack([-g / np.exp(log_scale), -g * t.z, -np.exp(t.logF - h)], axis=-1)  # (B, J, 3)
    return np.einsum("bj,bja,bjc->bac", np.broadcast_to(n, d.shape[:2]), d, d)


def _threshold(function: str, location, scale):
    return location + scale * _Z_HALF[function]


@functools.cache
def _blas():
    return ThreadpoolController()


def _one_blas_thread():
    """numpy's OpenBLAS to one thread while fitting: the products here are small, and its idle
    workers spinning after each threaded call slowed a bootstrap several times (docs/study.md)."""
    return _blas().limit(limits=1, user_api="blas")


# --- data and bounds ----------------------------------------------------------------------------

def _levels(stimulus, correct, trials=None, function: str = "gaussian") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(the function's axis value per level (`_axis`), correct per level, trials per level) from
    trials (0/1 answers) or, with `trials`, from counts per row (floats allowed: expected counts)."""
    s = np.asarray(stimulus, dtype=float).ravel()
    c = np.asarray(correct, dtype=float).ravel()
    n = np.ones_like(s) if trials is None else np.asarray(trials, dtype=float).ravel()
    if not (len(s) == len(c) == len(n)):
        raise ValueError(f"stimulus, correct{', trials' if trials is not None else ''}: lengths {len(s)}, {len(c)}, {len(n)} differ")
    if not len(s):
        raise ValueError("no trials")
    if not (np.isfinite(s).all() and (s > 0).all()):
        raise ValueError("stimulus: every increment must be finite and > 0")
    if trials is None and not np.isin(c, (0.0, 1.0)).all():
        raise ValueError("correct: every answer must be 0 or 1 (or pass trials= with counts)")
    if trials is not None and not (np.isfinite(n).all() and (n > 0).all() and (c >= 0).all() and (c <= n).all()):
        raise ValueError("trials, correct: need trials > 0 and 0 <= correct <= trials")
    x, inv = np.unique(_axis(function, s), return_inverse=True)
    return x, np.bincount(inv, weights=c), np.bincount(inv, weights=n)


class _Bounds(NamedTuple):
    lo: np.ndarray  # (location, ln scale, lapse)
    hi: np.ndarray


def _bounds(x: np.ndarray, lapse_max: float, scale_min: float, function: str = "gaussian") -> _Bounds:
    span = float(x[-1] - x[0]) if len(x) > 1 else ONE_LEVEL_SPAN
    if function == "thurstone":  # the observer's slope follows from its threshold: ln scale held at 0
        return _Bounds(np.array([x[0] - span, 0.0, 0.0]), np.array([x[-1] + span, 0.0, lapse_max]))
    return _Bounds(np.array([x[0] - span, math.log(scale_min), 0.0]),
                   np.array([x[-1] + span, math.log(max(2.0 * span, 10.0 * scale_min)), lapse_max]))


def _grid(b: _Bounds, n_loc: int, n_scale: int, n_lapse: int) -> np.ndarray:
    """Parameter points (G, 3) spanning the bounds."""
    lapses = np.linspace(b.lo[2], b.hi[2], n_lapse) if b.hi[2] > b.lo[2] else np.array([b.lo[2]])
    g = np.meshgrid(np.linspace(b.lo[0], b.hi[0], n_loc), np.linspace(b.lo[1], b.hi[1], n_scale), lapses, indexing="ij")
    return np.stack([a.ravel() for a in g], axis=1)


def _check(function: str, guess: float, lapse_max: float, scale_min: float, reference: float = 1.0) -> None:
    if function not in FUNCTIONS:
        raise ValueError(f"function: {function!r}; allowed: {', '.join(FUNCTIONS)}")
    if not (0.0 <= guess < 1.0 and 0.0 <= lapse_max and guess + lapse_max < 1.0):
        raise ValueError(f"guess {guess!r}, lapse_max {lapse_max!r}: need 0 <= guess < 1, lapse_max >= 0, guess + lapse_max < 1")
    if not (math.isfinite(scale_min) and scale_min > 0):
        raise ValueError(f"scale_min {scale_min!r}: must be > 0")
    if not (math.isfinite(reference) and reference > 0):
        raise ValueError(f"reference {reference!r}: must be > 0")


def _check_level(level: float) -> None:
    if not 0.0 < level < 1.0:
        raise ValueError(f"level {level!r}: must be in (0, 1)")


# --- the fit ------------------------------------------------------------------------------------

def fit_psychometric(stimulus, correct, function: str = DEFAULT_FUNCTION, guess: float = GUESS, lapse_max: float = LAPSE_MAX,
                     scale_min: float = SCALE_MIN, reference: float = 1.0, trials=None, n_boot: int = 0, level: float = LEVEL,
                     seed=BOOTSTRAP_SEED) -> PsychometricFit:
    """The maximum-likelihood psychometric function of one participant in one condition.

    `stimulus`: the increments delta (> 0) of the trials; `correct`: 1 where the comparison was
    chosen. With `trials`, each row is a level instead: `correct` of `trials` answers correct
    (floats allowed). `n_boot` > 0 adds the parametric-bootstrap interval (`bootstrap_interval`,
    seeded by `seed`) as ci_low, ci_high. Degenerate data give a flagged fit (module
    docstring), never an exception or a silent NaN; invalid input raises ValueError."""
    _check(function, guess, lapse_max, scale_min, reference)
    _check_level(level)
    x, k, n = _levels(stimulus, correct, trials, function)
    with _one_blas_thread():
        return _fit(function, guess, lapse_max, scale_min, reference, x, k, n, n_boot, level, seed)


def _fit(function, guess, lapse_max, scale_min, reference, x, k, n, n_boot, level, seed) -> PsychometricFit:
    b = _bounds(x, lapse_max, scale_min, function)
    # the grid: a coarse look at the whole bounded space, so the polish starts near the global
    # maximum whatever the data (psychometric likelihoods with a lapse are not concave)
    pts = _grid(b, 41, 25, 3)
    ll = _loglik(_terms(function, guess, x, pts[:, :1], pts[:, 1:2], pts[:, 2:]), k, n)
    # starts: the best grid points, and the best at each lapse rate and each quarter of the scale
    # range (other basins), each taken uphill by the vectorised `_polish`; L-BFGS-B from the best
    # of them, so the reported optimum is scipy's
    ll = np.where(np.isfinite(ll), ll, -np.inf)
    quarter = np.minimum(((pts[:, 1] - b.lo[1]) / max(b.hi[1] - b.lo[1], 1e-300) * 4).astype(int), 3)
    slices = [np.flatnonzero((pts[:, 2] == lam) & (quarter == q)) for lam in np.unique(pts[:, 2]) for q in range(4)]
    idx = np.unique(np.concatenate([np.argsort(ll)[-8:]] + [[s_[np.argmax(ll[s_])]] for s_ in slices if len(s_)]))
    cand = _polish(function, guess, x, np.broadcast_to(k, (len(idx), len(x))), n, pts[idx], b)
    ll_c = _loglik(_terms(function, guess, x, cand[:, :1], cand[:, 1:2], cand[:, 2:]), k, n)
    start = cand[np.argmax(ll_c)]
    scale_l = lapse_max if lapse_max > 0 else 1.0  # lapse in units of its bound: the three parameters alike in size

    def negll(v):
        theta = np.array([v[0], v[1], v[2] * scale_l])
        t = _terms(function, guess, x, theta[0], theta[1], theta[2])
        return -float(_loglik(t, k, n)), -_score(t, k, n, theta[1]) * np.array([1.0, 1.0, scale_l])

    box = np.array(list(zip(b.lo, b.hi))) / np.array([1.0, 1.0, scale_l])[:, None]
    best = optimize.minimize(negll, start / [1.0, 1.0, scale_l], jac=True, method="L-BFGS-B", bounds=box,
                             options={"ftol": 1e-12, "gtol": 1e-8, "maxiter": 500})
    theta = np.clip(best.x * [1.0, 1.0, scale_l], b.lo, b.hi)
    # L-BFGS-B's line search may stop "abnormally" at the optimum itself: then judge the point by
    # the log-likelihood a Fisher step could still gain, free of the parameters' units
    ok = bool(best.success) or _gain(function, guess, x, k, n, theta, b) < 1e-6
    fit = _make_fit(function, guess, lapse_max, scale_min, reference, theta, -float(best.fun), x, k, n, b, ok)
    if n_boot > 0 and fit.flag not in DEGENERATE:
        low, high = _interval(fit, x, n, n_boot, level, seed)
        fit = dataclasses.replace(fit, ci_low=low, ci_high=high, ci_level=level, n_boot=n_boot)
    return fit


def _gain(function, guess, x, k, n, theta: np.ndarray, b: _Bounds) -> float:
    """Half the squared Newton decrement g' I^-1 g (Fisher information I) over the parameters
    not held on a bound: about the log-likelihood left to gain."""
    t = _terms(function, guess, x, theta[None, :1], theta[None, 1:2], theta[None, 2:])
    g = _score(t, k, n, theta[None, 1:2])[0]
    free = ~(((theta <= b.lo + 1e-12) & (g < 0)) | ((theta >= b.hi - 1e-12) & (g > 0)))
    info = _fisher(t, n, theta[None, 1:2])[0][np.ix_(free, free)]
    return 0.5 * float(g[free] @ np.linalg.pinv(info) @ g[free]) if free.any() else 0.0


def _make_fit(function, guess, lapse_max, scale_min, reference, theta, loglik, x, k, n, b: _Bounds, success: bool) -> PsychometricFit:
    loc, log_s, lapse = (float(v) for v in theta)
    s = math.exp(log_s)
    weber = float(_delta(function, _threshold(function, loc, s)))
    tol = 1e-6 * (b.hi[:2] - b.lo[:2])
    if len(x) == 1:
        flag = "one_level"
    elif np.all(k >= n):
        flag = "all_correct"
    elif np.all(k <= guess * n):
        flag = "at_chance"
    elif loc <= b.lo[0] + tol[0] or loc >= b.hi[0] - tol[0]:
        flag = "location_at_bound"
    elif b.hi[1] > b.lo[1] and log_s >= b.hi[1] - tol[1]:  # (a held scale is on no bound)
        flag = "shallow"
    elif not success:
        flag = "optimizer"
    elif b.hi[1] > b.lo[1] and log_s <= b.lo[1] + tol[1]:
        flag = "steep"
    else:
        flag = ""
    return PsychometricFit(function=function, guess=guess, lapse_max=lapse_max, scale_min=scale_min, reference=reference,
                           weber=weber, jnd=weber * reference, location=loc, scale=s, width=s * _Z_WIDTH[function],
                           slope=(1.0 - guess - lapse) * _DENSITY_HALF[function] / s, lapse=lapse, loglik=loglik,
                           n_trials=int(round(float(n.sum()))), n_levels=len(x), converged=flag in CONVERGED_FLAGS, flag=flag)


# --- the parametric bootstrap -------------------------------------------------------------------

def bootstrap_interval(fit: PsychometricFit, stimulus, trials=None, n_boot: int = N_BOOT, level: float = LEVEL,
                       rng=BOOTSTRAP_SEED) -> tuple[float, float]:
    """The percentile interval (`level`) of the Weber fraction over `n_boot` data sets simulated
    from `fit` at the same stimuli (`stimulus`, and `trials` per row if the fit was made from
    counts) and refitted by maximum likelihood with the fit's bounds. `rng`: a seed or a numpy
    Generator. (NaN, NaN) for a degenerate fit (FLAGS) or n_boot < 1."""
    _check_level(level)
    if n_boot < 1 or fit.flag in DEGENERATE:
        return NAN, NAN
    s = np.asarray(stimulus, dtype=float).ravel()
    x, _, n = _levels(s, np.zeros_like(s), trials, fit.function)
    with _one_blas_thread():
        return _interval(fit, x, n, n_boot, level, rng)


def _interval(fit: PsychometricFit, x, n, n_boot: int, level: float, rng) -> tuple[float, float]:
    webers = _bootstrap_webers(fit, x, n, n_boot, rng)
    low, high = np.quantile(webers, [(1.0 - level) / 2.0, (1.0 + level) / 2.0])
    return float(low), float(high)


def _bootstrap_webers(fit: PsychometricFit, x, n, n_boot: int, rng) -> np.ndarray:
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    p = np.exp(_terms(fit.function, fit.guess, x, fit.location, math.log(fit.scale), fit.lapse).logP)
    if np.allclose(n, np.round(n)):
        k = rng.binomial(np.round(n).astype(np.int64), p, size=(n_boot, len(x))).astype(float)
    else:  # expected counts: simulate each level's proportion from the nearest whole number of trials
        m = np.maximum(np.round(n), 1).astype(np.int64)
        k = rng.binomial(m, p, size=(n_boot, len(x))) * (n / m)
    theta = _fit_many(fit.function, fit.guess, x, k, n, _bounds(x, fit.lapse_max, fit.scale_min, fit.function),
                      np.array([fit.location, math.log(fit.scale), fit.lapse]))
    return _delta(fit.function, _threshold(fit.function, theta[:, 0], np.exp(theta[:, 1])))


def _fit_many(function: str, guess: float, x, k, n, b: _Bounds, warm: np.ndarray) -> np.ndarray:
    """Maximum-likelihood parameters (B, 3) of B data sets `k` (B, J) at the same levels. Starts
    per data set: `warm` (the fitted parameters), the best point of a coarse grid, and the best
    at each other lapse rate of the grid when within 2 log-likelihood units of it (the other
    basin: lapses or a shallower function explaining the same errors). Every start gets a few
    steps of `_polish`, the best of each data set is polished to the end. (`warm` and the grid's
    best alone missed the maximum more often: docs/study.md.)"""
    pts = _grid(b, 21, 11, 3)
    t = _terms(function, guess, x, pts[:, :1], pts[:, 1:2], pts[:, 2:])  # (G, J)
    ll_grid = k @ t.logP.T + (n - k) @ t.log1mP.T  # (B, G): one matrix product for every data set
    B = len(k)
    best = np.argmax(ll_grid, axis=1)
    top = ll_grid[np.arange(B), best]
    rows, starts = [np.arange(B), np.arange(B)], [np.broadcast_to(warm, (B, 3)), pts[best]]
    for lam in np.unique(pts[:, 2]):
        m = np.flatnonzero(pts[:, 2] == lam)
        j = m[np.argmax(ll_grid[:, m], axis=1)]
        extra = (j != best) & (ll_grid[np.arange(B), j] >= top - 2.0)
        rows.append(np.flatnonzero(extra))
        starts.append(pts[j[extra]])
    rows = np.concatenate(rows)
    theta = _polish(function, guess, x, k[rows], n, np.concatenate(starts), b, max_iter=4)
    ll = _loglik(_terms(function, guess, x, theta[:, :1], theta[:, 1:2], theta[:, 2:]), k[rows], n)
    order = np.lexsort((ll, rows))  # by data set, then likelihood: the last of each data set is its best
    last = np.r_[rows[order][1:] != rows[order][:-1], True]
    winners = np.empty((B, 3))
    winners[rows[order][last]] = theta[order][last]
    return _polish(function, guess, x, k, n, winners, b)


def _polish(function: str, guess: float, x, k, n, theta: np.ndarray, b: _Bounds, max_iter: int = POLISH_ITERATIONS) -> np.ndarray:
    """Projected Fisher scoring with step halving, every data set at once: a parameter on a bound
    whose gradient points outward is held there (its row of the information replaced by the
    identity); each step is halved until the likelihood does not fall. A data set stops when
    its log-likelihood gains less than 1e-10, or after `max_iter` steps: the few still moving
    then creep along a ridge where the likelihood is flat to 1e-6 (a threshold anywhere in the
    gap between two levels: more steps did not change the intervals, docs/study.md)."""
    theta = theta.copy()
    n_b = np.broadcast_to(n, k.shape)

    def ll_of(th, kk, nn):
        return _loglik(_terms(function, guess, x, th[:, :1], th[:, 1:2], th[:, 2:]), kk, nn)

    ll = ll_of(theta, k, n_b)
    todo = np.arange(len(theta))
    eye = np.eye(3)
    for _ in range(max_iter):
        if not len(todo):
            break
        th, kk, nn, ll0 = theta[todo], k[todo], n_b[todo], ll[todo]
        t = _terms(function, guess, x, th[:, :1], th[:, 1:2], th[:, 2:])
        g = _score(t, kk, nn, th[:, 1:2])
        held = ((th <= b.lo + 1e-12) & (g < 0)) | ((th >= b.hi - 1e-12) & (g > 0))
        free = (~held).astype(float)
        info = _fisher(t, nn, th[:, 1:2]) * free[:, :, None] * free[:, None, :] + held[:, :, None] * eye
        info += eye * (1e-10 * np.trace(info, axis1=1, axis2=2)[:, None, None] + 1e-12)
        step = np.linalg.solve(info, (g * free)[:, :, None])[:, :, 0]
        new, ll_new = th.copy(), ll0.copy()
        left = np.arange(len(todo))
        frac = 1.0
        for _ in range(HALVINGS):
            cand = np.clip(th[left] + frac * step[left], b.lo, b.hi)
            ll_c = ll_of(cand, kk[left], nn[left])
            ok = ll_c >= ll0[left]
            new[left[ok]], ll_new[left[ok]] = cand[ok], ll_c[ok]
            left = left[~ok]
            if not len(left):
                break
            frac *= 0.5
        theta[todo], ll[todo] = new, ll_new
        todo = todo[ll_new - ll0 > 1e-10]
    return theta


# --- per participant and condition --------------------------------------------------------------

def _row_seed(seed: int, code, condition) -> list[int]:
    """A row's own stream: its interval does not depend on which other rows the table has."""
    return [int(seed), zlib.crc32(str(code).encode()), zlib.crc32(str(condition).encode())]


def weber_table(trials: pd.DataFrame, function: str = DEFAULT_FUNCTION, n_boot: int = N_BOOT, seed: int = BOOTSTRAP_SEED,
                guess: float = GUESS, lapse_max: float = LAPSE_MAX, scale_min: float = SCALE_MIN, level: float = LEVEL,
                reference: float = 1.0) -> pd.DataFrame:
    """One row per participant (code) and condition of `trials` (columns code, condition, stimulus,
    correct; others ignored): the fit's n_trials, weber, ci_low, ci_high (the bootstrap
    interval, NaN with n_boot=0 or a degenerate fit), lapse, slope, converged, flag. Sorted by
    code, then condition."""
    missing = [c for c in ("code", "condition", "stimulus", "correct") if c not in trials.columns]
    if missing:
        raise ValueError(f"trials: missing columns {', '.join(missing)}")
    rows = []
    for (code, condition), g in trials.groupby(["code", "condition"], sort=True):
        fit = fit_psychometric(g["stimulus"], g["correct"], function=function, guess=guess, lapse_max=lapse_max, scale_min=scale_min,
                               reference=reference, n_boot=n_boot, level=level, seed=_row_seed(seed, code, condition))
        rows.append({"code": code, "condition": condition, "n_trials": fit.n_trials, "weber": fit.weber, "ci_low": fit.ci_low,
                     "ci_high": fit.ci_high, "lapse": fit.lapse, "slope": fit.slope, "converged": fit.converged, "flag": fit.flag})
    return pd.DataFrame(rows, columns=WEBER_COLUMNS)


__all__ = ["PsychometricFit", "fit_psychometric", "bootstrap_interval", "weber_table", "FUNCTIONS", "FLAGS",
           "DEGENERATE", "WEBER_COLUMNS", "N_BOOT", "BOOTSTRAP_SEED", "GUESS", "LAPSE_MAX"]
