"""The signal processing under analysis/validity/metrics.py: the movement's window, the position low-pass,
speed, spectral arc length (SPARC), and time above a force limit. Pure NumPy/SciPy on arrays, so
each piece is tested on its own against closed forms (tests/test_metrics.py)."""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfiltfilt

# Low-pass cut-off for positions before differentiation. The Omni's encoders quantise the tip to
# about 0.055 mm; at 1 kHz each step is a velocity spike of 55 mm/s, and a diagonal staircase is
# up to sqrt(3) longer than the line it steps along. 20 Hz removes that (it is broadband, up to
# 500 Hz) but keeps physiological tremor (8-12 Hz), which is part of a person's skill.
CUTOFF_HZ = 20.0

# SPARC's parameters as published (Balasubramanian et al. 2015, J NeuroEng Rehabil 12:112): the
# spectrum of the speed profile up to 10 Hz, cut adaptively where it falls below 5% of its peak,
# zero-padded 4 levels beyond the next power of two.
SPARC_FC_HZ = 10.0
SPARC_AMP_TH = 0.05
SPARC_PAD = 4


def tick_durations(times: np.ndarray) -> np.ndarray:
    """Each tick's duration (to the next tick; the last one: the median), so a state held for k
    ticks at 1 kHz counts k ms, the sample-and-hold the servo loop applies."""
    times = np.asarray(times, dtype=float)
    if len(times) < 2:
        return np.zeros(len(times))
    dt = np.diff(times)
    return np.append(dt, np.median(dt))


def movement_window(buttons: np.ndarray) -> slice:
    """The movement of one hand: from the first tick its button is held (the tissue grasped) to
    the last, inclusive (a brief release in between stays inside); the whole trial if it never is."""
    held = np.flatnonzero(np.asarray(buttons, dtype=bool))
    if len(held) == 0:
        return slice(0, len(buttons))
    return slice(int(held[0]), int(held[-1]) + 1)


def smooth_positions(times: np.ndarray, positions: np.ndarray, cutoff_hz: float = CUTOFF_HZ) -> np.ndarray:
    """Positions (ticks, 3) through a zero-phase 4th-order Butterworth low-pass (no lag, so the
    movement's timing is kept); unchanged when the trace is too short or sampled too slowly."""
    positions = np.asarray(positions, dtype=float)
    if len(times) < 2:
        return positions
    fs = 1.0 / float(np.median(np.diff(times)))
    if fs <= 4.0 * cutoff_hz or len(positions) <= 30:  # nothing to remove, or too few ticks for the filter's padding
        return positions
    sos = butter(4, cutoff_hz, fs=fs, output="sos")
    # padding by reflection about the end values: a movement that starts and ends at rest stays at rest
    return sosfiltfilt(sos, positions, axis=0, padtype="odd", padlen=min(len(positions) - 1, int(3 * fs / cutoff_hz)))


def speed(times: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Tip speed (ticks,) m/s by central differences (one-sided at the ends)."""
    if len(times) < 2:
        return np.zeros(len(times))
    v = np.gradient(np.asarray(positions, dtype=float), np.asarray(times, dtype=float), axis=0)
    return np.linalg.norm(v, axis=1)


def sparc(speed_profile: np.ndarray, fs: float, fc: float = SPARC_FC_HZ, amp_th: float = SPARC_AMP_TH,
          pad: int = SPARC_PAD) -> float:
    """Spectral arc length of a speed profile (Balasubramanian et al. 2015): minus the arc length of
    its normalised Fourier magnitude over normalised frequency, up to the adaptive cut-off. A
    minimum-jerk reach scores about -1.40 whatever its distance and duration (tests/test_metrics.py);
    less smooth, lower."""
    v = np.asarray(speed_profile, dtype=float)
    if len(v) < 2 or not np.any(v > 0):
        return float("nan")
    nfft = int(2 ** (np.ceil(np.log2(len(v))) + pad))
    f = np.arange(nfft) * (fs / nfft)
    mag = np.abs(np.fft.fft(v, nfft))
    mag = mag / mag.max()
    keep = f <= fc
    f, mag = f[keep], mag[keep]
    above = np.flatnonzero(mag >= amp_th)
    f, mag = f[above[0]:above[-1] + 1], mag[above[0]:above[-1] + 1]
    if len(f) < 2:
        return 0.0
    return float(-np.sum(np.sqrt((np.diff(f) / (f[-1] - f[0])) ** 2 + np.diff(mag) ** 2)))


def above_limit(force_n: np.ndarray, dt: np.ndarray, limit_n: float) -> tuple[float, float]:
    """(time above the limit s, integral of the excess N s): the ticks whose force magnitude
    exceeds `limit_n`, and the integral of max(|F| - limit, 0) over time."""
    excess = np.maximum(np.asarray(force_n, dtype=float) - limit_n, 0.0)
    return float(np.sum(dt[excess > 0])), float(np.sum(excess * dt))


def ramp(times: np.ndarray, distance: np.ndarray, low: float = 0.1, high: float = 0.9) -> tuple[float, float, float]:
    """A pull's ramp and hold from the tip's distance from where it grasped (ticks,): (its largest
    distance D, the rise time from first passing `low` D to first reaching `high` D, the hold: from
    there, the time the distance stays at or above `high` D, to the last tick). A rise time's
    10-90% is the step-response convention; a minimum-jerk pull over T rises in 0.507 T."""
    d = np.asarray(distance, dtype=float)
    t = np.asarray(times, dtype=float)
    if len(d) < 2 or not d.max() > 0:
        return float(d.max()) if len(d) else float("nan"), float("nan"), float("nan")
    top = float(d.max())
    a = int(np.argmax(d >= low * top))
    b = int(np.argmax(d >= high * top))
    below = np.flatnonzero(d[b:] < high * top)
    end = b + int(below[0]) if len(below) else len(d) - 1
    return top, float(t[b] - t[a]), float(t[end] - t[b])
