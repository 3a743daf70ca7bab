"""Report plots (matplotlib, headless): rates with intervals, deformation times, force traces
of every model against the FEM reference for the same pull (like the seed paper's Fig. 5)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


COLORS = {"fem": "#1f77b4", "mass_spring": "#ff7f0e", "plate_spring": "#2ca02c"}


def rates_plot(rates, path: Path, synthetic: bool) -> None:
    """Favourable rate per question and model, with Wilson 95% intervals."""
    plt = _plt()
    items = list(dict.fromkeys(rates["item"]))
    models = list(dict.fromkeys(rates["model"]))
    fig, ax = plt.subplots(figsize=(9, 4.2), dpi=100)
    width = 0.8 / len(models)
    for j, m in enumerate(models):
        g = rates[rates["model"] == m].set_index("item").loc[items]
        x = np.arange(len(items)) + (j - (len(models) - 1) / 2) * width
        ax.errorbar(x, g["rate"], yerr=[g["rate"] - g["wilson_low"], g["wilson_high"] - g["rate"]], fmt="o", ms=5, capsize=3,
                    color=COLORS.get(m), label=m)
    ax.set_xticks(np.arange(len(items)), items, rotation=30, ha="right")
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("favourable rate (Wilson 95% CI)")
    ax.set_title(("SYNTHETIC DATA: " if synthetic else "") + "favourable rate per question and model", fontsize=10)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def deformation_plot(db, path: Path, synthetic: bool) -> None:
    """Distribution of the deformation time per frame (trial means) per model, log scale."""
    from analysis.table1 import _query

    plt = _plt()
    lat = _query(db, "select model, value from latency where measure = 'deformation_ms'")
    models = list(dict.fromkeys(lat["model"]))
    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=100)
    data = [lat.loc[lat["model"] == m, "value"].to_numpy() for m in models]
    ax.boxplot(data, showfliers=False)
    rng = np.random.default_rng(0)
    for i, (m, v) in enumerate(zip(models, data), start=1):
        ax.scatter(i + rng.uniform(-0.15, 0.15, len(v)), v, s=6, alpha=0.5, color=COLORS.get(m))
    ax.set_xticks(range(1, len(models) + 1), models)
    ax.set_yscale("log")
    ax.set_ylabel("deformation time per frame (ms)")
    ax.set_title(("SYNTHETIC DATA: " if synthetic else "") + "time for real-time deformation (trial means)", fontsize=10)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def force_traces(scene_path, models=("plate_spring", "fem", "mass_spring"), duration: float = 3.0) -> dict:
    """The scene's scripted pull, run with every model (lockstep); the FEM reference force for
    each run's own hand motion. Returns {model: (t, force, reference)} for the first hand."""
    from sim.run import run_scene
    from sim.scene import build_scene
    from studyctl.synthetic import reference_forces

    ref = build_scene(scene_path, "fem")
    out = {}
    for m in models:
        scene = build_scene(scene_path, m)
        r = run_scene(scene, duration=duration, time_scale=0)
        f = np.linalg.norm(r.forces[:, 0], axis=1)
        out[m] = (r.times, f, reference_forces(r, ref.model, ref.mesh)[:, 0])
    return out


def force_plot(traces: dict, path: Path) -> None:
    """Fig. 5-style: force of each model and the FEM reference for the same pull, and the
    relative difference against the force JND."""
    from sim.calibrate import jnd

    plt = _plt()
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(7, 5.4), dpi=100, sharex=True)
    for m, (t, f, ref) in traces.items():
        ax.plot(t, f, color=COLORS.get(m), lw=1.3, label=m)
        if m != "fem":
            ax.plot(t, ref, color=COLORS.get(m), lw=0.8, ls="--")
            mask = ref > 0.01
            bx.plot(t[mask], (f[mask] - ref[mask]) / ref[mask], color=COLORS.get(m), lw=1.0, label=f"{m} vs FEM")
    ax.set_ylabel("force on the hand (N)")
    ax.set_title("the scene's pull with each model; dashed: linear FEM for the same hand motion", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    tt = np.linspace(0, max(t.max() for t, _, _ in traces.values()), 2)
    for sign in (1, -1):
        bx.plot(tt, sign * jnd(np.array([0.0, 0.0])), color="0.5", ls=":", lw=0.8)
        bx.plot(tt, sign * jnd(np.array([1.0, 1.0])), color="0.3", ls=":", lw=0.8)
    bx.set_ylabel("relative difference")
    bx.set_xlabel("time (s)")
    bx.set_ylim(-1.0, 5.0)
    bx.set_title("dotted: force JND, 25% below 0.5 N and 10% above", fontsize=9)
    bx.legend(fontsize=8)
    bx.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
