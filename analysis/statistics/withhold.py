"""When a statistic may be printed: one rule for every report.

A statistic is given only where its prerequisites hold for the data at hand: enough
participants, at least two conditions, variation to rank or scale, a model that converged and
has residual degrees of freedom. Otherwise it is NaN (JSON: null) with a `reason` in words,
which every format prints instead of the number. Intervals of a bounded scale stay inside it.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from sim.text import n_text

NAN = float("nan")
WILCOXON_MIN_N = 6  # the exact two-sided signed-rank test reaches p < 0.05 from 6 untied pairs (2 / 2**6 = 0.031)



def interval_reason(values: np.ndarray) -> str | None:
    """Why the values have no interval of their mean (too few, no variation), or None."""
    n = len(values)
    if n < 2:
        return f"no interval at {n_text(n)}"
    if np.ptp(values) == 0:
        return f"no interval: every value is {float(values[0]):g} (no variation)"
    return None


def mean_ci(values, confidence: float = 0.95, scale: tuple[float, float] | None = None) -> dict:
    """Mean, SD (n - 1) and its 95% interval; missing values left out.

    Unbounded: the t interval (n - 1 df). On a bounded `scale` (lo, hi): the t interval of the
    logit of the mean's place on the scale (delta method), back-transformed, so it lies inside
    the scale and is asymmetric near its ends (a t interval of 86.8 +- 17 on a 0-100 scale would
    end at 103.8). Withheld with a `reason` below 2 values or without variation."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    n = len(v)
    mean = float(v.mean()) if n else NAN
    out = {"n": n, "mean": mean, "sd": float(v.std(ddof=1)) if n >= 2 else NAN, "ci_low": NAN, "ci_high": NAN,
           "ci_method": None, "ci_reason": None}
    reason = interval_reason(v) if n else "no values"
    if reason is not None:
        return out | {"ci_reason": reason}
    t = float(stats.t.ppf(0.5 + confidence / 2, n - 1))
    se = out["sd"] / math.sqrt(n)
    if scale is None:
        return out | {"ci_low": mean - t * se, "ci_high": mean + t * se, "ci_method": "t"}
    lo, hi = scale
    p = (mean - lo) / (hi - lo)
    if not 0.0 < p < 1.0:  # every value at one end (no variation is caught above): nothing to transform
        return out | {"ci_reason": "no interval: the mean is at the end of the scale"}
    half = t * se / (hi - lo) / (p * (1.0 - p))
    logit = math.log(p / (1.0 - p))
    back = [lo + (hi - lo) / (1.0 + math.exp(-x)) for x in (logit - half, logit + half)]
    return out | {"ci_low": back[0], "ci_high": back[1], "ci_method": f"logit t ({lo:g}-{hi:g} scale)"}


def pair_reason(n: int, differences: np.ndarray | None = None) -> str | None:
    """Why a paired rank test (Wilcoxon signed-rank) is not run on `n` pairs, or None."""
    if n < 2:
        return f"not testable at {n_text(n)}"
    if differences is not None and not np.any(differences != 0):
        return "no difference in any pair: nothing to rank"
    return None


def pair_warning(n_untied: int) -> str | None:
    """A warning for a small paired rank test that is run: it cannot reach p < 0.05."""
    if n_untied < WILCOXON_MIN_N:
        return f"at N = {n_untied} untied pairs the exact test cannot reach p < 0.05 (needs {WILCOXON_MIN_N} or more)"
    return None


def across_reason(n: int, k: int, matrix: np.ndarray | None = None) -> str | None:
    """Why a test across k conditions (Friedman, Cochran's Q) is not run, or None."""
    if k < 2:
        return "one condition: nothing to compare"
    if k == 2:
        return "two conditions: the pair is the test"
    if n < 2:
        return f"not testable at {n_text(n)}"
    if matrix is not None and np.ptp(matrix) == 0:
        return "every answer alike: nothing to rank"
    return None


def binary_across_reason(n: int, k: int, matrix: np.ndarray | None = None) -> str | None:
    """Why Cochran's Q across k conditions of yes/no answers is not run, or None (two
    conditions: Q is McNemar's chi-square, and is run)."""
    if k < 2:
        return "one condition: nothing to compare"
    if n < 2:
        return f"not testable at {n_text(n)}"
    if matrix is not None and not np.any(np.ptp(matrix, axis=1) > 0):
        return "every participant answered alike in every condition: nothing to test"
    return None


def model_reason(converged: bool | None, df_den: float | None, n: int) -> str | None:
    """Why a fitted model's test is withheld (not converged, no residual degrees of freedom)."""
    if df_den is not None and not df_den > 0:
        return f"no residual degrees of freedom at {n_text(n)}"
    if converged is False:
        return "the model did not converge"
    return None
