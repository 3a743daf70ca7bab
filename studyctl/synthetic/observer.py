"""The synthetic participant's observer: what a person would perceive of a condition, and the
probability of each yes.

Symmetric by construction: every condition is judged by the same functions of what the
simulator did (the trials' traces) against a truth that is none of the compared models (the
converged P2 reference, analysis/verification/truth.py). Nothing depends on a model's name. Parameters and
their sources: `ObserverParams` and docs/synthetic.md.

Two stages, so that planning can reuse simulator runs:

- `summarise(trace, truth, mesh)`: what a trial offers any observer (participant-independent):
  the rendered and the true force at the judged samples, the force ripple on the vibration
  threshold scale, safety events, and the frame's counted work;
- `features(summaries, traits, params)`: what this participant perceives of a condition
  (their Weber fraction, expectation, latency and vibration thresholds), and `logit`, whose
  logistic function is a yes/no question's P(yes).

Determinism: every input is a function of the lockstep traces. Latency enters as the
deformation time the model's counted work takes on the reference machine (`frame_ms`), not the
wall-clock time measured on a possibly busy machine, so the same seed gives the same answers
with any number of jobs and any load.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

import numpy as np
from scipy.signal import detrend
from scipy.special import ndtr

from analysis.study import instruments
from analysis.study.questions import Kind, Question
from sim.perception import FORCE_WEBER, FORCE_WEBER_LOW

# question -> weights on (accuracy, latency, vibration, safety); the base logit 1.0 is about
# 73% yes, near the paper's overall rate
WEIGHTS = {
    "natural": (1.2, 0.3, 0.5, 0.3),
    "behaviour": (1.0, 0.3, 0.5, 0.3),
    "texture": (1.5, 0.0, 0.3, 0.0),
    "comfortable": (0.3, 0.3, 1.0, 0.5),
    "guidance": (1.0, 0.3, 0.3, 0.3),
    "realtime": (0.0, 1.5, 0.3, 0.3),
    "feedback": (1.5, 0.0, 0.5, 0.3),
    "deformation": (1.0, 0.5, 0.3, 0.0),
    "stable": (0.0, 0.3, 1.0, 1.5),
}
DEFAULT_WEIGHTS = (0.8, 0.5, 0.5, 0.5)
# the standard questionnaires (analysis/study/instruments.py): SUS's items from one latent ease
# (agreeing with its odd items, disagreeing with its even ones); each NASA-TLX subscale a
# workload that rises as the condition falls short (assumed weights, docs/synthetic.md)
EASE_WEIGHTS = (0.8, 0.8, 0.8, 1.0)
TLX_WEIGHTS = {
    "tlx_mental": (1.0, 0.5, 0.3, 0.3),
    "tlx_physical": (0.3, 0.3, 1.0, 0.5),
    "tlx_temporal": (0.0, 1.5, 0.3, 0.3),
    "tlx_performance": (1.5, 0.3, 0.3, 0.5),
    "tlx_effort": (0.8, 0.5, 0.8, 0.3),
    "tlx_frustration": (0.5, 0.8, 0.8, 1.0),
}
SAFETY_EVENTS = ("force_clamped", "nan_force", "model_unstable", "model_fault", "force_chatter", "deadline_streak", "device_fault",
                 "position_jump", "nan_position")
P_WITHIN_PERFECT = float(ndtr(1.0) - ndtr(-1.0))  # a rendered force equal to the expected one: 0.683


@dataclass(frozen=True)
class ObserverParams:
    """Population values (medians) and spreads (log-sd across people); sources in docs/synthetic.md."""

    weber: float = FORCE_WEBER  # force JND at or above 0.5 N (sim.perception)
    weber_sd: float = 0.25  # 7-15% for the hand-arm system (Pang, Tan and Durlach 1991: 7%) as +-1.5 sd
    weber_low: float = FORCE_WEBER_LOW  # below 0.5 N (sim.perception)
    low_force_n: tuple[float, float] = (0.3, 0.7)  # the paper's step at 0.5 N, made continuous over this band
    judged_force_n: float = 0.02  # truth below this: nothing to judge (below the Omni's force resolution)
    prior_sd: float = 0.20  # how stiff a brain should feel, across people (assumption: about one stiffness JND, 15-22%)
    latency_ms: float = 40.0  # deformation latency noticed by half of people (25 ms task performance, 30-50 ms asynchrony)
    latency_slope: float = 0.25  # log-units per sd of the psychometric function
    latency_sd: float = 0.20  # thresholds across people
    frame_overhead_ms: float = 0.2  # the reference machine: fixed cost of a frame (the plate-spring's frame here) ...
    flops_per_ms: float = 1.1e6  # ... and its rate on the counted work (the mass-spring's here; `python -m bench observer`)
    fingertip_stiffness: float = 1000.0  # N/m: finger pad, turns displacement thresholds into force (Serina et al. 1997)
    vibration_sd: float = 0.35  # vibrotactile thresholds across people (about +-3 dB)
    vibration_slope: float = 0.35  # log-units per sd of the detection function
    bias_sd: float = 0.6  # some people say yes more (logit)
    # stiffness discrimination (the discrimination task): the Weber fraction for stiffness is
    # 15-23% with force and position cues (Jones and Hunter 1990: 23%; Tan et al. 1995: 17%
    # with work cues removed), about twice the force's; people differ by about +-1.5 sd
    stiffness_weber: float = 0.15
    stiffness_weber_sd: float = 0.30
    lapse_max: float = 0.04  # a trial answered at random (attention lapses, mistyped keys): 0-4% of trials
    base_logit: float = 1.0
    sample_every: int = 10  # judge the force at 100 Hz (ticks are 1 kHz)
    # True: the former rule, a sample where the truth is not decided judged against its band
    # (kept so that scripts/decided_share.py can show what judging only decided evidence changes)
    judge_undecided: bool = False


DEFAULT = ObserverParams()

# vibrotactile detection threshold at the fingertip, displacement amplitude (m) by frequency:
# the U-shaped Pacinian curve, lowest near 250 Hz (read from Verrillo 1963 and Gescheider et al.
# 2002, rounded); interpolated log-log, flat outside
VIBRATION_THRESHOLD = ((10.0, 50e-6), (30.0, 20e-6), (100.0, 3e-6), (250.0, 0.6e-6), (500.0, 3e-6))
RIPPLE_BAND_HZ = (20.0, 500.0)  # below: the pull and the hand's tremor (8-12 Hz), not vibration


@dataclass(frozen=True)
class ObserverTraits:
    """One participant's perception."""

    weber: float  # force JND at or above 0.5 N
    prior: float  # expected force / true force
    latency_ms: float  # deformation latency they notice half of the time
    vibration: float  # their threshold / the population's
    bias: float

    @classmethod
    def draw(cls, code: str, seed: int, params: ObserverParams = DEFAULT) -> ObserverTraits:
        rng = random.Random(f"observer:{seed}:{code}")
        return cls.from_normals([rng.gauss(0.0, 1.0) for _ in range(5)], params)

    @classmethod
    def from_normals(cls, z, params: ObserverParams = DEFAULT) -> ObserverTraits:
        """The traits for five standard normal draws (the population's log-normal spreads)."""
        a, b, c, d, e = (float(x) for x in z)
        return cls(weber=params.weber * math.exp(params.weber_sd * a), prior=math.exp(params.prior_sd * b),
                   latency_ms=params.latency_ms * math.exp(params.latency_sd * c), vibration=math.exp(params.vibration_sd * d),
                   bias=params.bias_sd * e)


@dataclass(frozen=True)
class DiscriminationTraits:
    """How finely one participant tells stiffness apart."""

    weber: float  # the relative increment in stiffness they pick out 75% of the time when attending
    lapse: float  # the share of trials they answer at random (their function's upper asymptote is 1 - lapse / 2)

    @classmethod
    def draw(cls, code: str, seed: int, params: ObserverParams = DEFAULT) -> DiscriminationTraits:
        rng = random.Random(f"discrimination:{seed}:{code}")  # its own stream: the other traits keep their draws
        return cls(weber=params.stiffness_weber * math.exp(params.stiffness_weber_sd * rng.gauss(0.0, 1.0)),
                   lapse=rng.uniform(0.0, params.lapse_max))


@dataclass(frozen=True)
class TrialSummary:
    """What one trial offers any observer."""

    rendered: np.ndarray  # (k,) N, force magnitude sent to the device at the judged samples
    truth: np.ndarray  # (k,) N, the reference's force for the same hand motion and grasp
    ripple: float  # force ripple on the population's vibration threshold scale (1: at threshold)
    events: int  # safety events
    frame_flops: float  # mean counted work per deformation frame (NaN: not recorded)
    frame_ms: float = math.nan  # the rig's measured time per frame for this configuration (studyctl/synthetic/rig.py); NaN: none
    band: np.ndarray | None = None  # (k,) the truth's relative half-band where it is not decided (0 where it is); None: 0
    decided: np.ndarray | None = None  # (k,) whether the truth is decided at each sample (only those are judged); None: all


def frame_ms(flops: float, params: ObserverParams = DEFAULT) -> float:
    """Deformation time of a frame of `flops` counted work on the reference machine."""
    return params.frame_overhead_ms + flops / params.flops_per_ms


def vibration_threshold_n(freq: np.ndarray, params: ObserverParams = DEFAULT) -> np.ndarray:
    f, d = np.log(np.array(VIBRATION_THRESHOLD)).T
    return params.fingertip_stiffness * np.exp(np.interp(np.log(np.maximum(freq, 1e-3)), f, d))


def ripple_level(force: np.ndarray, rate_hz: float, params: ObserverParams = DEFAULT) -> float:
    """Force ripple in units of the vibration threshold: the amplitude spectrum (Hann window)
    of the force magnitude in the ripple band, each component over its threshold, summed in
    energy (Parseval: independent of the record's length)."""
    x = np.asarray(force, dtype=np.float64)
    if len(x) < 64:
        return 0.0
    w = np.hanning(len(x))
    spec = np.fft.rfft(detrend(x) * w)
    amp = 2.0 * np.abs(spec) / w.sum()
    freq = np.fft.rfftfreq(len(x), 1.0 / rate_hz)
    band = (freq >= RIPPLE_BAND_HZ[0]) & (freq <= RIPPLE_BAND_HZ[1])
    # the Hann window spreads a line over bins; its noise bandwidth (1.5 bins) undoes that in energy
    return float(np.sqrt(np.sum((amp[band] / vibration_threshold_n(freq[band], params)) ** 2) / 1.5))


def truth_forces(trace, truth, mesh, with_band: bool = False):
    """The truth's force magnitude for the trace's hand motion and grasps, per tick and hand
    (and, `with_band`, its relative half-band where it is not decided)."""
    out, band, _ = truth_along(trace, truth, mesh)
    return (out, band) if with_band else out


def truth_along(trace, truth, mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per tick and hand: the truth's force magnitude (0 where the hand holds nothing), its
    relative half-band where it is not decided, and whether it is decided there."""
    out = np.zeros(trace.positions.shape[:2])
    band = np.zeros(trace.positions.shape[:2])
    decided = np.zeros(trace.positions.shape[:2], dtype=bool)
    grasps: dict[int, list] = {}
    for e in trace.events:
        if e.kind == "grasp":
            grasps.setdefault(e.hand, []).append((e.t, int(e.detail.split()[1])))
    for hand, items in grasps.items():
        for k, (t0, vertex) in enumerate(items):
            t1 = items[k + 1][0] if k + 1 < len(items) else math.inf
            sel = (trace.times >= t0) & (trace.times < t1) & trace.buttons[:, hand]
            if not sel.any():
                continue
            d = trace.positions[sel, hand] - mesh.vertices[vertex]
            out[sel, hand] = np.linalg.norm(truth.force(vertex, d), axis=1)
            band[sel, hand] = truth.band(vertex, d)
            decided[sel, hand] = truth.decided(vertex, d)
    return out, band, decided


def _judged(ref: np.ndarray, params: ObserverParams) -> np.ndarray:
    """The samples (100 Hz) where the truth reaches a force to judge."""
    judged = ref >= params.judged_force_n
    judged[np.arange(len(judged)) % params.sample_every != 0] = False
    return judged


def judged_time(trace, truth, mesh, params: ObserverParams = DEFAULT) -> np.ndarray:
    """(hands, 2) per hand: the samples where the truth reaches a force to judge, and how many
    of them are on decided truth (the only ones whose accuracy is judged)."""
    ref, _, decided = truth_along(trace, truth, mesh)
    judged = _judged(ref, params)
    return np.stack([judged.sum(axis=0), (judged & decided).sum(axis=0)], axis=1)


def summarise(trace, truth, mesh, params: ObserverParams = DEFAULT) -> TrialSummary:
    f = np.linalg.norm(trace.forces, axis=2)
    ref, band, decided = truth_along(trace, truth, mesh)
    rate = 1.0 / float(np.median(np.diff(trace.times))) if len(trace.times) > 1 else 1000.0
    judged = _judged(ref, params)
    ripple = 0.0
    for i in range(f.shape[1]):
        held = np.flatnonzero(ref[:, i] > 0)
        if len(held):
            ripple = max(ripple, ripple_level(f[held[0]:held[-1] + 1, i], rate, params))
    flops = np.asarray(getattr(trace, "frame_flops", np.zeros(0)), dtype=np.float64)
    return TrialSummary(rendered=f[judged], truth=ref[judged], band=band[judged], decided=decided[judged], ripple=ripple,
                        events=sum(1 for e in trace.events if e.kind in SAFETY_EVENTS),
                        frame_flops=float(np.nanmean(flops)) if len(flops) and np.isfinite(flops).any() else math.nan)


def weber_at(force: np.ndarray, traits: ObserverTraits, params: ObserverParams = DEFAULT) -> np.ndarray:
    """The participant's JND (relative) at each force: theirs above 0.5 N, the paper's ratio
    25/10 times theirs below, continuous over `low_force_n`."""
    lo, hi = params.low_force_n
    t = np.clip((np.asarray(force) - lo) / (hi - lo), 0.0, 1.0)
    return traits.weber * (params.weber_low / params.weber * (1.0 - t) + t)


def within_jnd(rendered: np.ndarray, truth: np.ndarray, traits: ObserverTraits, params: ObserverParams = DEFAULT,
               band: np.ndarray | None = None) -> float:
    """Mean probability that a force sample feels as expected: the log ratio of the rendered
    force to the expected one (truth x the participant's prior), perceived with Gaussian noise
    of one JND, falls within one JND. A perfect model scores 0.683, not 1. Where the truth
    carries a band (`band`: its relative half-band b; off a path's own vertex, the transfer's
    error), a force inside the band is as good as the centre: the log ratio is measured from the
    band's nearer edge, taken symmetric in log force (truth (1 + b) above, truth / (1 + b) below:
    below, a little narrower than truth (1 - b))."""
    if len(truth) == 0:
        return math.nan
    w = weber_at(traits.prior * truth, traits, params)
    r = np.log(np.maximum(rendered, 1e-3) / (traits.prior * truth))
    if band is not None:
        r = np.sign(r) * np.maximum(np.abs(r) - np.log1p(np.asarray(band, dtype=np.float64)), 0.0)
    return float(np.mean(ndtr(1.0 - r / w) - ndtr(-1.0 - r / w)))


Z75 = 0.6744897501960817  # the standard normal's 75% point


def loading_curve(trace, hand: int, mesh=None) -> tuple[np.ndarray, np.ndarray] | None:
    """(stretch, force) of one hand while it first held the tissue, up to its largest stretch:
    the hand's distance from the point it grasped (the grasped vertex of `mesh`; without a mesh,
    where the hand was at the grasp) in m, and the force magnitude it felt (N)."""
    first = next((e for e in trace.events if e.kind == "grasp" and e.hand == hand), None)
    if first is None:
        return None
    anchor = mesh.vertices[int(first.detail.split()[1])] if mesh is not None else None
    held = (trace.times >= first.t) & trace.buttons[:, hand]
    idx = np.flatnonzero(held)
    if len(idx) < 2:
        return None
    idx = idx[: np.argmax(np.diff(idx) > 1) + 1] if np.any(np.diff(idx) > 1) else idx  # the first hold only
    stretch = np.linalg.norm(trace.positions[idx, hand] - (trace.positions[idx[0], hand] if anchor is None else anchor), axis=1)
    force = np.linalg.norm(trace.forces[idx, hand], axis=1)
    top = int(np.argmax(stretch))
    return stretch[: top + 1], force[: top + 1]


def stiffness_log_ratio(a, b, mesh=None, points: int = 16, low: float = 0.3) -> float:
    """ln of how much stiffer interval `b` was than `a`: per hand, b's force over a's at the same
    stretches (`points` from `low` times the smaller of the two largest stretches up to it, where
    the pull dominates tremor and the device's resolution), the median over them, then the mean
    over the hands that held the tissue in both; NaN when none did. A person compares the
    resistance at the same stretch, so a longer pull in one interval does not feel stiffer."""
    out = []
    for hand in range(a.positions.shape[1]):
        ca, cb = loading_curve(a, hand, mesh), loading_curve(b, hand, mesh)
        if ca is None or cb is None:
            continue
        top = min(ca[0][-1], cb[0][-1])
        if not top > 0:
            continue
        grid = np.linspace(low * top, top, points)
        fa, fb = (np.interp(grid, x[order], f[order]) for x, f in (ca, cb) for order in [np.argsort(x, kind="stable")])
        ok = (fa > 0) & (fb > 0)
        if ok.any():
            out.append(float(np.median(np.log(fb[ok] / fa[ok]))))
    return _round(float(np.mean(out))) if out else math.nan


def stiffer_answer(intervals, traits: DiscriminationTraits, uniform, normal, mesh=None) -> int:
    """The interval (1 or 2) that felt stiffer: the traces' log stiffness ratio seen through
    Weber-law noise in each interval, so that an increment of `traits.weber` is picked out 75% of
    the time (P = Phi(ln ratio * Z75 / ln(1 + weber))); with probability `traits.lapse`, or when
    nothing was held, a guess. Draws exactly three numbers. `mesh`: the scene's surface, whose
    grasped vertex each stretch is measured from (`loading_curve`)."""
    ratio = stiffness_log_ratio(intervals[0], intervals[1], mesh)
    lapsed, z, guess = uniform(), normal(), uniform()
    if lapsed < traits.lapse or not math.isfinite(ratio):
        return 1 if guess < 0.5 else 2
    return 2 if ratio + z * math.log1p(traits.weber) / Z75 > 0 else 1


def _round(x: float, digits: int = 9) -> float:
    """`x` to `digits` significant digits: the FEM's grasp solves run on a threaded OpenBLAS
    (CHOLMOD) whose sums can differ in the last bit between processes (seen once in the suite:
    a ripple of 0.4448188315920225 against ...227); rounded, such noise reaches an answer only
    if a value sits within a last-bit of a rounding boundary (about 1e-7 per feature)."""
    if not math.isfinite(x) or x == 0.0:
        return x
    return round(x, digits - 1 - int(math.floor(math.log10(abs(x)))))


def features(summaries: list[TrialSummary], traits: ObserverTraits, params: ObserverParams = DEFAULT) -> dict:
    """What the participant perceived of one condition (its trials' summaries), to 9
    significant digits."""
    return {k: _round(float(v)) if isinstance(v, float) else v for k, v in _features(summaries, traits, params).items()}


def _features(summaries: list[TrialSummary], traits: ObserverTraits, params: ObserverParams = DEFAULT) -> dict:
    rendered = np.concatenate([s.rendered for s in summaries]) if summaries else np.zeros(0)
    truth = np.concatenate([s.truth for s in summaries]) if summaries else np.zeros(0)
    band = np.concatenate([s.band if s.band is not None else np.zeros(len(s.truth)) for s in summaries]) if summaries else np.zeros(0)
    decided = np.concatenate([s.decided if s.decided is not None else np.ones(len(s.truth), dtype=bool) for s in summaries]) \
        if summaries else np.zeros(0, dtype=bool)
    # where the truth is not decided it is the law's extrapolation, not evidence: no accuracy
    # judgement there (judged on the decided samples alone; none: the neutral term)
    undecided = int(np.sum(~decided))
    if not params.judge_undecided:
        rendered, truth, band = rendered[decided], truth[decided], band[decided]
    flops = [s.frame_flops for s in summaries if math.isfinite(s.frame_flops)]
    rig = [s.frame_ms for s in summaries if math.isfinite(s.frame_ms)]
    # the rig's measured frame time when the study has a profile, else the counted work on the reference machine
    latency = float(np.mean(rig)) if rig else frame_ms(float(np.mean(flops)), params) if flops else math.nan
    within = within_jnd(rendered, truth, traits, params, band)
    p_vib = [float(ndtr(math.log(s.ripple / traits.vibration) / params.vibration_slope)) if s.ripple > 0 else 0.0 for s in summaries]
    return {
        "within_jnd": within,  # NaN: the truth never reached a judged force (nothing to judge)
        "force_log_ratio": float(np.median(np.log(np.maximum(rendered, 1e-3) / truth))) if len(truth) else math.nan,
        "latency_ms": latency,
        "p_latency": float(ndtr(math.log(latency / traits.latency_ms) / params.latency_slope)) if math.isfinite(latency) else 0.0,
        "ripple": float(np.mean([s.ripple for s in summaries])) if summaries else 0.0,
        "p_vibration": float(np.mean(p_vib)) if p_vib else 0.0,
        "events": sum(s.events for s in summaries) / max(len(summaries), 1),
        "samples": int(len(truth)),
        "undecided_samples": undecided,  # above the judged force on truth that is not decided (not judged)
    }


# the logit's reach per unit weight (assumptions, docs/synthetic.md "P(yes)"): accuracy from a useless to a
# perfect model moves it by ACCURACY_SPAN, latency and vibration from never to always noticed by LATENCY_SPAN and
# VIBRATION_SPAN; each safety event costs one, counted up to EVENTS_CAP
ACCURACY_SPAN, LATENCY_SPAN, VIBRATION_SPAN, EVENTS_CAP = 2.0, 2.0, 3.0, 3.0


def logit(question: Question, feats: dict, traits: ObserverTraits, params: ObserverParams = DEFAULT) -> float:
    """The participant's latent judgement of a condition on `question` (logit of agreeing, or of a
    rating above the scale's middle): a yes/no question's P(yes) is its logistic function. An
    instrument's item is judged by its instrument (ease for the SUS, load for the NASA-TLX) in the
    direction its item runs (analysis.study.instruments.item_sign)."""
    sign, weights = instruments.item_sign(question), WEIGHTS.get(question.id, DEFAULT_WEIGHTS)
    if question.instrument == "sus":
        weights = EASE_WEIGHTS
    elif question.instrument == "nasa_tlx":
        weights = TLX_WEIGHTS[question.id]
    w_acc, w_lat, w_vib, w_safe = weights
    within = feats["within_jnd"]
    accuracy = min(within / P_WITHIN_PERFECT, 1.0) if math.isfinite(within) else 0.5  # nothing judged: neutral
    return sign * (params.base_logit + traits.bias + w_acc * ACCURACY_SPAN * (accuracy - 0.5) - w_lat * LATENCY_SPAN * feats["p_latency"]
                   - w_vib * VIBRATION_SPAN * feats["p_vibration"] - w_safe * min(feats["events"], EVENTS_CAP))


LIKERT_SPREAD = 3.0  # the outer thresholds of a rating scale on the logit scale (assumption, docs/synthetic.md)
VAS_NOISE_SD = 0.5  # logit units: where on a line a person marks the same judgement (assumption)


def likert_thresholds(points: int) -> np.ndarray:
    """Symmetric cut points of a `points`-point scale on the latent logit, evenly spaced over
    +-LIKERT_SPREAD: centred on the yes/no boundary (latent 0), which is an even scale's middle
    cut and the centre of an odd scale's middle point."""
    k = np.arange(1, points)
    return LIKERT_SPREAD * (k - points / 2.0) / (points / 2.0)


def likert_answer(eta: float, points: int, u: float) -> int:
    """A rating 1..points: the latent judgement plus logistic noise (inverse CDF at `u`), cut
    at the scale's thresholds: an ordered logit, P(rating > k) = logistic(eta - tau_k), whose
    latent is above 0 with the yes/no question's P(yes)."""
    u = min(max(u, 1e-12), 1.0 - 1e-12)
    latent = eta + math.log(u / (1.0 - u))
    return 1 + int(np.sum(likert_thresholds(points) < latent))


def vas_answer(eta: float, z: float) -> float:
    """A mark on a 0..100 line: the logistic of the judgement plus normal noise (`z`), to 0.1."""
    return round(100.0 / (1.0 + math.exp(-(eta + VAS_NOISE_SD * z))), 1)


def judged_answer(question, eta: float, uniform, normal):
    """An answer of a yes/no, rating or VAS question from the latent judgement `eta`, drawing one
    number: `uniform()` for yes/no (yes with probability logistic(eta)) and ratings, `normal()`
    for a VAS. Synthetic sessions and `plan` draw through it with their own generators."""
    if question.kind == Kind.YES_NO:
        return uniform() < 1.0 / (1.0 + math.exp(-eta))
    if question.kind == Kind.LIKERT:
        return likert_answer(eta, question.points, uniform())
    return vas_answer(eta, normal())
