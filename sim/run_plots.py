"""Force-time plot and trace CSV of a run (matplotlib, headless Agg backend)."""

from __future__ import annotations

import csv
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from sim.devices.base import OmniSpec


def _pyplot():
    matplotlib.use("Agg")
    return plt


# the two hands often pull alike, so their lines coincide: the first hand wide and pale below,
# the second narrow and dashed on top, so that each stays in sight where they meet
HAND_STYLES = ({"lw": 3.2, "alpha": 0.45, "color": "tab:blue", "zorder": 2},
               {"lw": 1.3, "ls": "--", "color": "tab:orange", "zorder": 3},
               {"lw": 1.3, "ls": ":", "color": "tab:green", "zorder": 4})


def force_plot(result, path: Path) -> None:
    plt = _pyplot()
    spec = OmniSpec()
    fig, ax = plt.subplots(figsize=(7.0, 3.6), dpi=100)
    mags = np.linalg.norm(result.forces, axis=2)
    for i, name in enumerate(result.hand_names):
        ax.plot(result.times, mags[:, i], label=f"{name} hand", **HAND_STYLES[i % len(HAND_STYLES)])
    ax.axhline(spec.continuous_force_n, color="0.5", ls="--", lw=0.8, label="Omni continuous force")
    top = max(float(mags.max()) if mags.size else 0.0, spec.continuous_force_n) * 1.15
    if top > spec.peak_force_n * 0.8:
        ax.axhline(spec.peak_force_n, color="tab:red", ls=":", lw=0.8, label="Omni peak force")
        top = spec.peak_force_n * 1.1
    ax.set_ylim(0, top)
    ax.set_xlim(0, result.duration)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("force sent to device (N)")
    ax.set_title(f"{result.scene_name}: {result.model}, servo {result.rate_hz:.0f} Hz ({result.mode})", fontsize=10)
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


TRACE_COLUMNS = ["t_s", "hand", "x_m", "y_m", "z_m", "fx_n", "fy_n", "fz_n", "button"]


def write_trace(result, path: Path) -> None:
    """One row per tick and hand: time, position and force (SI units)."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(TRACE_COLUMNS)
        for k, t in enumerate(result.times):
            for i, name in enumerate(result.hand_names):
                p, f = result.positions[k, i], result.forces[k, i]
                w.writerow([f"{t:.4f}", name, *(f"{c:.9g}" for c in p), *(f"{c:.6g}" for c in f), int(result.buttons[k, i])])
