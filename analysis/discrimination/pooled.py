"""Weber fractions pooled over the participants of a condition: a hierarchical model of the
two-interval observer (analysis/discrimination/psychometric.py's "thurstone") on a grid. `report jnd` prints
each participant's pooled estimate beside their own fit (docs/study.md)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import special, stats

from analysis.discrimination.psychometric import _Z75, LAPSE_MAX, LEVEL, NAN, _check_level

POOLED_MIN = 5  # participants of a condition: fewer give no population to pool over
POOLED_COLUMNS = ["code", "condition", "weber_pooled", "pooled_low", "pooled_high"]
_POOL_GRID = np.linspace(math.log(0.001), math.log(3.0), 350)  # ln Weber fraction: 0.1% to 300%
_POOL_MU = np.linspace(_POOL_GRID[0], _POOL_GRID[-1], 71)  # the population's mean of ln weber
_POOL_TAU = np.linspace(0.05, 2.0, 40)  # and its spread


def _observer_loglik(stimulus, correct, lapse_max: float) -> np.ndarray:
    """ln P(answers | ln weber) on `_POOL_GRID` for the two-interval observer ("thurstone"),
    the lapse (the fit's, 0..lapse_max) integrated out under a flat prior."""
    r = np.log1p(np.asarray(stimulus, dtype=float))
    c = np.asarray(correct, dtype=float)
    sigma = np.log1p(np.exp(_POOL_GRID)) / _Z75  # ln(1 + weber) / z75
    lapses = np.linspace(0.0, lapse_max, 7) if lapse_max > 0 else np.zeros(1)
    phi = special.ndtr(r[None, :] / sigma[:, None])  # (W, T)
    p = 0.5 + (0.5 - lapses[:, None, None]) * (2.0 * phi[None] - 1.0)  # (L, W, T)
    p = np.clip(p, 1e-12, 1.0 - 1e-12)
    ll = (c * np.log(p) + (1.0 - c) * np.log1p(-p)).sum(axis=-1)  # (L, W)
    return np.logaddexp.reduce(ll, axis=0) - math.log(len(lapses))


def pooled_webers(trials: pd.DataFrame, lapse_max: float = LAPSE_MAX, level: float = LEVEL) -> pd.DataFrame:
    """Each participant's Weber fraction pooled with the other participants of the same condition
    (a hierarchical model on a grid): ln weber ~ Normal(mu, tau) over the condition's
    participants, flat priors on mu (over the grid, 0.1% to 300%) and tau (0.05 to 2), the
    two-interval observer's likelihood ("thurstone", the lapse integrated out); each
    participant's posterior median and equal-tailed `level` credible interval, the population's
    mean and spread integrated out (so their uncertainty widens the interval when there are few
    participants). Forty trials pin a Weber fraction down to about a quarter of itself; the
    group's spread says how far to trust that and pulls the noisiest fits toward the group
    (its recovery of synthetic participants against unpooled fits: docs/study.md). Conditions with fewer than POOLED_MIN participants get no pooled
    value (NaN). Columns POOLED_COLUMNS."""
    _check_level(level)
    rows = []
    prior = stats.norm.logpdf(_POOL_GRID[None, None, :], _POOL_MU[:, None, None], _POOL_TAU[None, :, None]) \
        + math.log(float(_POOL_GRID[1] - _POOL_GRID[0]))  # (M, T, W): p(ln weber | mu, tau) on the grid
    for condition, cg in trials.groupby("condition", sort=True):
        codes = sorted(cg["code"].unique())
        if len(codes) < POOLED_MIN:
            rows += [{"code": c, "condition": condition, "weber_pooled": NAN, "pooled_low": NAN, "pooled_high": NAN} for c in codes]
            continue
        L = [_observer_loglik(g["stimulus"], g["correct"], lapse_max) for _, g in cg.groupby("code", sort=True)]
        evidence = np.array([np.logaddexp.reduce(ll[None, None, :] + prior, axis=-1) for ll in L])  # (N, M, T)
        hyper = evidence.sum(axis=0)
        hyper = np.exp(hyper - hyper.max())
        hyper /= hyper.sum()  # p(mu, tau | every participant's answers)
        for code, ll, ev in zip(codes, L, evidence):
            # p(ln weber | answers) = sum over (mu, tau) of p(ln weber | own answers, mu, tau) p(mu, tau | all answers)
            post = np.einsum("mt,mtw->w", hyper, np.exp(ll[None, None, :] + prior - ev[..., None]))
            cdf = np.cumsum(post) / post.sum()
            lo, med, hi = np.exp(np.interp([(1 - level) / 2, 0.5, (1 + level) / 2], cdf, _POOL_GRID))
            rows.append({"code": code, "condition": condition, "weber_pooled": float(med), "pooled_low": float(lo), "pooled_high": float(hi)})
    return pd.DataFrame(rows, columns=POOLED_COLUMNS)
