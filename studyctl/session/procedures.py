"""Adaptive procedures for the discrimination task (studyctl/tasks.py): which relative
increment `delta` to try next in a two-interval forced choice, given the answers so far.

Two methods behind one interface (`Procedure`):

- ``quest+``: QUEST+ (Watson 2017) through the `questplus` package: a Weibull on log delta with
  guess rate 0.5, a grid of thresholds, slopes and lapse rates, each next delta the one that
  minimises the expected entropy of the posterior;
- ``staircase``: a transformed up-down staircase (Levitt 1971), 1-up-2-down (converging near
  70.7% correct) or 1-up-3-down (79.4%), in multiplicative steps.

Deterministic: no random numbers inside, so `replay` of the stored trials rebuilds exactly
the procedure an interrupted session had (a resumed session asks for what the uninterrupted one
would have). `state()` is a JSON-able snapshot stored with every trial for audit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from analysis.errors import StudyError

METHODS = ("quest+", "staircase")
RULES = ("1-up-2-down", "1-up-3-down")
DOWN_AFTER = {"1-up-2-down": 2, "1-up-3-down": 3}  # consecutive correct answers that make delta smaller
GUESS = 0.5  # two intervals: the lower asymptote
LOG10_LN2 = math.log10(math.log(2.0))  # Weibull: 75% correct (guess 0.5, no lapses) lies this far from its threshold, / slope
OUTCOMES = ("Correct", "Incorrect")
DIGITS = 12  # significant digits of a delta: readable in the stored state, far finer than any grid


class SpecError(StudyError, ValueError):
    """A procedure's parameters are out of their domain (the message names the field)."""


@dataclass(frozen=True)
class ProcedureSpec:
    """An adaptive procedure and its parameters (defaults measured in tests/test_procedures.py)."""

    method: str  # one of METHODS
    rule: str = "1-up-2-down"  # staircase only: one of RULES
    start: float = 0.4  # staircase only: the first delta (QUEST+ chooses its own)
    low: float = 0.01  # the deltas tried: the stimulus domain is [low, high] (both methods)
    high: float = 1.0
    # staircase: steps multiply delta by `step` until `coarse_reversals` reversals, then by
    # `fine_step`; 2 then 2**(1/4) leaves the start in a few trials and ends within 2 points of
    # Levitt's targets in 80 trials (sqrt(2) ended 4 points under 70.7%, 2**(1/8) had not arrived)
    step: float = 2.0
    fine_step: float = 2.0 ** 0.25
    coarse_reversals: int = 2  # also the reversals left out of the estimate
    # QUEST+: delta on a log grid of this step (log10 units; 0.05 is 1 dB of amplitude, as in
    # Watson's examples), thresholds on the same grid; Weibull slopes from shallow (about 1.1 fits
    # the synthetic observer, whose d' grows with log(1 + delta): a suprathreshold discrimination)
    # to steep (3.5, Watson's contrast detection); lapse rates (upper asymptote 1 - lapse)
    grid_step: float = 0.05
    slopes: tuple[float, ...] = (0.8, 1.2, 1.8, 2.7, 4.0)
    lapses: tuple[float, ...] = (0.0, 0.01, 0.02, 0.04)

    def __post_init__(self):
        if self.method not in METHODS:
            raise SpecError(f"method: {self.method!r} is not a method; allowed: {', '.join(METHODS)}")
        if self.rule not in RULES:
            raise SpecError(f"rule: {self.rule!r} is not a rule; allowed: {', '.join(RULES)}")
        if not (isinstance(self.low, (int, float)) and math.isfinite(self.low) and self.low > 0):
            raise SpecError(f"low: {self.low!r} is out of range; allowed: a finite delta > 0")
        if not (isinstance(self.high, (int, float)) and math.isfinite(self.high) and self.high > self.low):
            raise SpecError(f"high: {self.high!r} is out of range; allowed: a finite delta > low ({self.low:g})")
        if self.method == "staircase":
            if not (isinstance(self.start, (int, float)) and self.low <= self.start <= self.high):
                raise SpecError(f"start: {self.start!r} is out of range; allowed: {self.low:g}..{self.high:g} (low..high)")
            for name in ("step", "fine_step"):
                if not getattr(self, name) > 1.0:
                    raise SpecError(f"{name}: {getattr(self, name)!r} is out of range; allowed: a factor > 1")
            if not (isinstance(self.coarse_reversals, int) and self.coarse_reversals >= 0):
                raise SpecError(f"coarse_reversals: {self.coarse_reversals!r} is out of range; allowed: an integer >= 0")
        else:
            if not self.grid_step > 0:
                raise SpecError(f"grid_step: {self.grid_step!r} is out of range; allowed: > 0 (log10 units)")
            if not self.slopes or not all(s > 0 for s in self.slopes):
                raise SpecError(f"slopes: {self.slopes!r} is out of range; allowed: one or more slopes > 0")
            if not self.lapses or not all(0.0 <= x < GUESS for x in self.lapses):
                raise SpecError(f"lapses: {self.lapses!r} is out of range; allowed: one or more rates in [0, {GUESS:g})")


class Procedure(Protocol):
    """What the task asks of a procedure."""

    def next_stimulus(self) -> float: ...

    def update(self, stimulus: float, correct: bool) -> None: ...

    def state(self) -> dict: ...

    def estimate(self) -> float: ...


def make_procedure(spec: ProcedureSpec) -> Procedure:
    return QuestPlusProcedure(spec) if spec.method == "quest+" else Staircase(spec)


def replay(spec: ProcedureSpec, history) -> Procedure:
    """A new procedure told the trials `history` ((delta, correct) pairs, in order): the same
    next delta and state as the one that ran them."""
    procedure = make_procedure(spec)
    for stimulus, correct in history:
        procedure.update(float(stimulus), bool(correct))
    return procedure


def _round(x: float) -> float:
    return float(f"{x:.{DIGITS - 1}e}")


class QuestPlusProcedure:
    """QUEST+ on a log grid of delta.

    Psychometric function: the package's Weibull on log10 delta,
    P = 1 - lapse - (1 - 0.5 - lapse) * exp(-10 ** (slope * (log10 delta - t))); its threshold t is
    the 81.6% point of the lapse-free function, so the 75% point is t + log10(ln 2) / slope
    (`estimate`: the posterior mean of that, in log10). Prior: uniform over the grid.

    Grid: thresholds on the stimulus grid (35 for the task's 0.02..1), 5 slopes, 4 lapse rates:
    700 parameter sets (a trial's cost, most of it the next delta's expected entropies:
    docs/study.md); the cost grows with the grid. Slopes 2..5 (as
    Watson's) recovered the synthetic observers' Weber fractions worse (35% median error
    against 20%, biased up by 30%); the shallow grid costs steep observers a bias of about -10%.
    """

    def __init__(self, spec: ProcedureSpec):
        import questplus  # lazy: slow to import, only for a QUEST+ procedure (every protocol's check imports this module)

        self.spec = spec
        lo, hi = math.log10(spec.low), math.log10(spec.high)
        n = max(2, round((hi - lo) / spec.grid_step) + 1)
        self.grid = np.linspace(lo, hi, n)  # log10 delta: stimuli and thresholds
        self.deltas = np.array([_round(10.0 ** g) for g in self.grid])
        self.qp = questplus.QuestPlus(
            stim_domain={"intensity": self.grid},
            param_domain={"threshold": self.grid, "slope": np.array(spec.slopes, dtype=float), "lower_asymptote": GUESS,
                          "lapse_rate": np.array(spec.lapses, dtype=float)},
            outcome_domain={"response": list(OUTCOMES)}, func="weibull", stim_scale="log10",
            stim_selection_method="min_entropy", param_estimation_method="mean")
        # log10 of the lapse-free 75% point of every (threshold, slope), axes as `_posterior`'s
        self._log75 = (self.grid[:, None] + LOG10_LN2 / np.array(spec.slopes, dtype=float)[None, :])[:, :, None]
        self.trials = 0
        self._next: float | None = None

    def _index(self, stimulus: float) -> int:
        k = int(np.argmin(np.abs(self.deltas - stimulus)))
        if not math.isclose(self.deltas[k], stimulus, rel_tol=1e-9):
            raise SpecError(f"stimulus: {stimulus!r} is not on this QUEST+ grid ({self.deltas[0]:g}..{self.deltas[-1]:g}, "
                            f"{len(self.deltas)} log-spaced deltas)")
        return k

    def next_stimulus(self) -> float:
        if self._next is None:  # the expected entropies are the costly part: once per trial
            g = self.qp.next_stim["intensity"]
            self._next = float(self.deltas[int(np.argmin(np.abs(self.grid - g)))])
        return self._next

    def update(self, stimulus: float, correct: bool) -> None:
        k = self._index(stimulus)
        self.qp.update(stim={"intensity": self.grid[k]}, outcome={"response": OUTCOMES[0] if correct else OUTCOMES[1]})
        self.trials += 1
        self._next = None

    def _posterior(self) -> np.ndarray:
        """The posterior as (threshold, slope, lapse) in numpy: the package's xarray sums cost a
        millisecond each."""
        return self.qp.posterior.transpose("threshold", "slope", "lower_asymptote", "lapse_rate").values[:, :, 0, :]

    def _log75_moments(self, p: np.ndarray) -> tuple[float, float]:
        mean = float(np.sum(p * self._log75))
        return mean, math.sqrt(max(float(np.sum(p * (self._log75 - mean) ** 2)), 0.0))

    def estimate(self) -> float:
        """The delta at 75% correct of the lapse-free function: 10 ** its posterior mean log10."""
        return 10.0 ** self._log75_moments(self._posterior())[0]

    def state(self) -> dict:
        p = self._posterior()
        mean, sd = self._log75_moments(p)
        return {"method": "quest+", "trials": self.trials, "next": self.next_stimulus(), "estimate": 10.0 ** mean,
                "log10_threshold_mean": mean, "log10_threshold_sd": sd,  # of the 75% point, posterior
                "slope_mean": float(np.sum(p.sum(axis=(0, 2)) * np.array(self.spec.slopes, dtype=float))),
                "lapse_mean": float(np.sum(p.sum(axis=(0, 1)) * np.array(self.spec.lapses, dtype=float)))}


class Staircase:
    """Transformed up-down staircase (Levitt 1971): after N consecutive correct answers (N = 2 or
    3 by the rule) delta goes down one step, after any wrong answer up one step, clipped to
    [low, high]. Steps multiply or divide delta by `spec.step` (2) until `spec.coarse_reversals`
    (2) reversals, then by `spec.fine_step` (2 ** (1/4), 19%), so the start is quickly left and the
    levels then stay near the target.

    A reversal is a trial whose step goes the other way from the previous step; its level is
    that trial's delta. `estimate`: the geometric mean of the reversal levels after the coarse
    ones, an even number of them (the earliest dropped if odd), so peaks and valleys balance;
    NaN until there are two (and `state()` has no "estimate").
    """

    def __init__(self, spec: ProcedureSpec):
        self.spec = spec
        self.down_after = DOWN_AFTER[spec.rule]
        # delta = anchor * step ** coarse * fine_step ** fine, from whole exponents, so that a level
        # revisited is the same float (the task keeps scaled scenes by their delta); a clipped
        # level becomes the new anchor
        self._anchor, self._coarse, self._fine = float(spec.start), 0, 0
        self.delta = _round(spec.start)
        self.run = 0  # consecutive correct answers since the last step
        self.direction = 0  # of the last step: -1 down, +1 up, 0 none yet
        self.reversals: list[float] = []
        self.trials = 0

    def factor(self) -> float:
        return self.spec.step if self._coarse_phase() else self.spec.fine_step

    def _coarse_phase(self) -> bool:
        return len(self.reversals) < self.spec.coarse_reversals

    def next_stimulus(self) -> float:
        return self.delta

    def update(self, stimulus: float, correct: bool) -> None:
        if not math.isclose(stimulus, self.delta, rel_tol=1e-9):  # a staircase's history is its own deltas
            raise SpecError(f"stimulus: {stimulus!r} is not the staircase's delta {self.delta!r}")
        self.trials += 1
        if correct:
            self.run += 1
            if self.run < self.down_after:
                return
        self.run = 0
        direction = -1 if correct else 1
        if self.direction and direction != self.direction:
            self.reversals.append(self.delta)
        self.direction = direction
        if self._coarse_phase():
            self._coarse += direction
        else:
            self._fine += direction
        level = self._anchor * self.spec.step ** self._coarse * self.spec.fine_step ** self._fine
        if not self.spec.low <= level <= self.spec.high:
            self._anchor, self._coarse, self._fine = min(max(level, self.spec.low), self.spec.high), 0, 0
            level = self._anchor
        self.delta = _round(level)

    def estimate(self) -> float:
        levels = self.reversals[self.spec.coarse_reversals:]
        levels = levels[len(levels) % 2:]
        return math.exp(sum(math.log(x) for x in levels) / len(levels)) if levels else math.nan

    def state(self) -> dict:
        out = {"method": "staircase", "rule": self.spec.rule, "trials": self.trials, "next": self.delta, "step": self.factor(),
               "run": self.run, "direction": self.direction, "reversals": list(self.reversals)}
        if math.isfinite(est := self.estimate()):  # none yet: no key (JSON has no NaN)
            out["estimate"] = est
        return out
