"""Report plots (matplotlib, headless): rates with intervals, deformation times, force traces
of every model against the FEM reference for the same pull (like the seed paper's Fig. 5)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.kind_results import ChoiceStats, RatingStats, ScoreStats
from analysis.psychometric import fit_psychometric
from sim.calibrate import jnd
from sim.run import run_scene
from sim.scene import Scene, load_scene
from studyctl.conditions import condition_scene_spec, scene_itself
from studyctl.observer import truth_forces
from studyctl.truth import load_truth


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


COLORS = {"fem": "#1f77b4", "mass_spring": "#ff7f0e", "plate_spring": "#2ca02c"}
OTHER_COLORS = ("#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf", "#393b79")


def color(name: str, k: int) -> str:
    """A model's own colour; a named condition (studyctl/conditions.py) the k-th of the others."""
    return COLORS.get(name) or OTHER_COLORS[k % len(OTHER_COLORS)]


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
                    color=color(m, j), label=m)
    ax.set_xticks(np.arange(len(items)), items, rotation=30, ha="right")
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("favourable rate (Wilson 95% CI)")
    ax.set_title(("SYNTHETIC DATA: " if synthetic else "") + "favourable rate per question and model", fontsize=10)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def deformation_plot(lat, path: Path, synthetic: bool) -> None:
    """Distribution of the deformation time per frame (trial means) per model, log scale
    (`lat`: ``model, value`` per trial, analysis.study_snapshot.Study.latency_trials)."""
    plt = _plt()
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
    ax.set_title(("SYNTHETIC DATA: " if synthetic else "") + "time for real-time deformation (trial means): benchmark of this machine", fontsize=10)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def force_traces(protocol, duration: float = 3.0) -> dict:
    """The scene's scripted pull, run with each of the study's conditions (lockstep); the
    converged reference's force (the synthetic observer's truth, studyctl/truth.py) for each
    run's own hand motion. Returns {condition: (t, force, reference)} for the first hand."""
    out = {}
    truth = load_truth(scene_itself(protocol))  # the scene's own, whatever a condition changes
    spec = load_scene(protocol.scene)
    for m in protocol.conditions:
        scene = Scene(condition_scene_spec(protocol, m, spec))
        r = run_scene(scene, duration=duration, time_scale=0)
        f = np.linalg.norm(r.forces[:, 0], axis=1)
        out[m] = (r.times, f, truth_forces(r, truth, scene.mesh)[:, 0])
    return out


def force_plot(traces: dict, path: Path) -> None:
    """Fig. 5-style: force of each model and the converged reference for the same pull, and
    the relative difference against the force JND."""
    plt = _plt()
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(7, 5.4), dpi=100, sharex=True)
    for k, (m, (t, f, ref)) in enumerate(traces.items()):
        ax.plot(t, f, color=color(m, k), lw=1.3, label=m)
        ax.plot(t, ref, color=color(m, k), lw=0.8, ls="--")
        mask = ref > 0.01
        bx.plot(t[mask], (f[mask] - ref[mask]) / ref[mask], color=color(m, k), lw=1.0, label=f"{m} vs reference")
    ax.set_ylabel("force on the hand (N)")
    ax.set_title("the scene's pull with each model; dashed: converged P2 reference for the same hand motion", fontsize=9)
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


PAPER_MS = {"plate_spring": 14.69, "fem": 21.35, "mass_spring": 23.08}  # seed paper, Table 1 (its 2014 PC)


def pareto(rows: list[dict]) -> list[bool]:
    """Rows no other row beats on both force error and frame time."""
    out = []
    for r in rows:
        out.append(not any(o is not r and o["force_error"] <= r["force_error"] and o["frame_ms"] <= r["frame_ms"]
                           and (o["force_error"] < r["force_error"] or o["frame_ms"] < r["frame_ms"]) for o in rows))
    return out


def pareto_plot(rows: list[dict], path: Path, reference: str = "") -> None:
    """Log-log: mean relative force error against deformation time per frame, one point per
    model setting; the Pareto front joined (black) and each class's own (dashed, its colour); the paper's deformation times as vertical marks."""
    fig = pareto_figure(rows, reference)
    fig.savefig(path)
    _plt().close(fig)


def pareto_figure(rows: list[dict], reference: str = ""):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 5.5), dpi=100)
    front = pareto(rows)
    for r, on in zip(rows, front):
        ax.scatter(r["frame_ms"], max(r["force_error"], 1e-4), color=COLORS.get(r["model"], "grey"), s=50 if on else 25,
                   edgecolor="black" if on else "none", zorder=3)
        ax.annotate(f"{r['setting']}", (r["frame_ms"], max(r["force_error"], 1e-4)), fontsize=7, xytext=(4, 3), textcoords="offset points")
    pts = sorted((r["frame_ms"], max(r["force_error"], 1e-4)) for r, on in zip(rows, front) if on)
    if pts:
        ax.step([p[0] for p in pts], [p[1] for p in pts], where="post", color="black", lw=0.8, zorder=2, label="Pareto front")
    for model in dict.fromkeys(r["model"] for r in rows):  # each class's own front: its best configurations
        mine = [r for r in rows if r["model"] == model]
        own = sorted((r["frame_ms"], max(r["force_error"], 1e-4)) for r, on in zip(mine, pareto(mine)) if on)
        if len(own) > 1:
            ax.step([p[0] for p in own], [p[1] for p in own], where="post", color=COLORS.get(model, "grey"), lw=0.8, ls="--", zorder=1)
    for k, (model, ms) in enumerate(PAPER_MS.items()):  # the three lie close together: stagger the labels
        ax.axvline(ms, color=COLORS[model], ls=":", lw=1)
        ax.text(ms, 0.98 - 0.07 * k, f" paper {model.replace('_', '-')} {ms} ms", color=COLORS[model], fontsize=7, va="top",
                ha="right", transform=ax.get_xaxis_transform())
    for model, color in COLORS.items():
        ax.scatter([], [], color=color, label=model)
    ax.axhline(0.10, color="grey", ls="--", lw=0.8)
    ax.text(0.99, 0.10, "force JND at or above 0.5 N (10%)", fontsize=7, va="bottom", ha="right", color="grey", transform=ax.get_yaxis_transform())
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("deformation time per visual frame, ms (median, this machine)")
    ax.set_ylabel("mean relative force error vs reference")
    ax.set_title("Force error vs deformation time" + (f" (reference {reference})" if reference else ""))
    # outside the axes: inside, "lower left" covered the best point (fast and accurate lies there)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    return fig


def stability_heatmap(outcomes: tuple, path: Path, title: str = "") -> None:
    """Outcome per model (rows) and case (columns): stable, refused, unstable, or n/a;
    `outcomes` is (rows, columns, codes) as `analysis.stability.outcome_grid` makes it."""
    from matplotlib.colors import ListedColormap

    plt = _plt()
    rows, cols, grid = outcomes
    fig, ax = plt.subplots(figsize=(max(8, 0.32 * len(cols) + 3), 0.45 * len(rows) + 2.4), dpi=100)
    cmap = ListedColormap(["#2ca02c", "#9e9e9e", "#d62728"]).with_extremes(bad="white")
    ax.imshow(np.ma.masked_invalid(grid), cmap=cmap, vmin=-0.5, vmax=2.5, aspect="auto")
    ax.set_xticks(range(len(cols)), cols, rotation=70, ha="right", fontsize=7)
    ax.set_yticks(range(len(rows)), rows, fontsize=8)
    for i in range(len(rows)):
        for j in range(len(cols)):
            if not np.isnan(grid[i, j]):
                ax.text(j, i, "SRU"[int(grid[i, j])], ha="center", va="center", fontsize=6, color="white")
    for label, color in (("stable", "#2ca02c"), ("refused", "#9e9e9e"), ("unstable", "#d62728")):
        ax.scatter([], [], marker="s", color=color, label=label)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax.set_title(title or "Stability sweep")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def likert_plot(ratings: dict[str, RatingStats], models: list[str], path: Path, synthetic: bool) -> None:
    """Diverging stacked bars (the field's convention for Likert items; Heiberger and Robbins
    2014): per item and condition, the share of each point, disagreeing points left of zero,
    agreeing ones right, the middle point split across zero."""
    plt = _plt()
    rows = [(v.question, m, np.asarray(v.conditions[m]["counts"], dtype=float)) for v in ratings.values() for m in models]
    points = max(len(c) for _, _, c in rows)
    cmap = plt.get_cmap("RdBu", points)
    fig, ax = plt.subplots(figsize=(10, 0.32 * len(rows) + 1.6), dpi=100)
    for y, (_, _, counts) in enumerate(rows):
        share = counts / counts.sum() if counts.sum() else counts
        k = len(share)
        mid = k // 2
        left = -(share[:mid].sum() + (share[mid] / 2 if k % 2 else 0.0))
        for j, s in enumerate(share):
            ax.barh(y, s, left=left, color=cmap(j * (points - 1) // max(k - 1, 1)), edgecolor="#888", linewidth=0.4, height=0.8,
                    label=str(j + 1) if y == 0 else None)
            left += s
    ax.axvline(0, color="#333", lw=0.8)
    ax.set_yticks(range(len(rows)), [f"{q[:38]}{'...' if len(q) > 38 else ''} | {m}" for q, m, _ in rows], fontsize=7)
    ax.invert_yaxis()
    ax.set_xlim(-1, 1)
    ax.set_xlabel("share of participants (left: below the middle of the scale; right: above)")
    ax.legend(title="rating", fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title("Ratings per condition" + (" (SYNTHETIC DATA)" if synthetic else ""))
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def scores_plot(scores: dict[str, ScoreStats], meas, models: list[str], path: Path, synthetic: bool) -> None:
    """Each score per condition: a box plot with every participant's value as a point."""
    plt = _plt()
    items = list(scores)
    fig, axes = plt.subplots(1, len(items), figsize=(3.2 * len(items) + 1, 3.8), dpi=100, squeeze=False)
    rng = np.random.default_rng(0)  # horizontal jitter only: the values are drawn as they are
    for ax, item in zip(axes[0], items):
        data = [meas[(meas["item"] == item) & (meas["model"] == m)]["answer"].to_numpy(float) for m in models]
        ax.boxplot(data, tick_labels=models, showfliers=False, widths=0.5)
        for j, (m, v) in enumerate(zip(models, data)):
            ax.scatter(j + 1 + rng.uniform(-0.12, 0.12, len(v)), v, s=12, color=color(m, j), alpha=0.8, zorder=3)
        ax.set_title(scores[item].label, fontsize=9)
        ax.tick_params(axis="x", labelsize=8, rotation=20)
    fig.suptitle("Scores per condition" + (" (SYNTHETIC DATA)" if synthetic else ""))
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def choice_plot(choice: ChoiceStats, models: list[str], path: Path, synthetic: bool) -> None:
    """Share of participants choosing each condition, with Wilson 95% intervals."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 3.4), dpi=100)
    s = [choice.shares[m] for m in models]
    share = np.array([x["share"] for x in s])
    ax.bar(range(len(models)), share, color=[color(m, j) for j, m in enumerate(models)])
    ax.errorbar(range(len(models)), share, yerr=[share - [x["wilson_low"] for x in s], np.array([x["wilson_high"] for x in s]) - share],
                fmt="none", color="#333", capsize=4)
    ax.axhline(1 / len(models), color="#999", ls="--", lw=0.8)
    ax.set_xticks(range(len(models)), models)
    ax.set_ylim(0, 1)
    ax.set_ylabel("share chosen")
    ax.set_title(choice.question[:60] + (" (SYNTHETIC)" if synthetic else ""), fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def psychometric_plot(trials, rows: list[dict], condition: str, path: Path, synthetic: bool) -> None:
    """One condition's discrimination: every participant's fitted psychometric function
    (analysis/psychometric.py, refitted here for its curve) and Weber fraction, and the pooled
    proportion correct in bins of the increment (point size: trials), on a log axis."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    d = trials["stimulus"].to_numpy(dtype=float)
    lo, hi = float(d.min()) / 1.5, float(d.max()) * 1.5
    grid = np.geomspace(lo, hi, 200)
    for _, g in trials.groupby("code", sort=True):
        fit = fit_psychometric(g["stimulus"], g["correct"])
        ax.plot(grid, fit.p_correct(grid), color="#1f77b4", alpha=0.35, lw=1)
        ax.plot([fit.weber], [0.75 - fit.lapse / 2], "o", color="#1f77b4", ms=3, alpha=0.6)
    edges = np.geomspace(d.min() * 0.999, d.max() * 1.001, 9)
    idx = np.clip(np.digitize(d, edges) - 1, 0, len(edges) - 2)
    correct = trials["correct"].to_numpy(dtype=float)
    for b in range(len(edges) - 1):
        sel = idx == b
        if sel.any():
            ax.scatter(np.exp(np.log(d[sel]).mean()), correct[sel].mean(), s=8 + 2 * sel.sum(), color="k", alpha=0.7, zorder=3)
    ax.axhline(0.75, color="0.6", lw=0.8, ls="--")
    ax.set_xscale("log")
    ax.set_ylim(0.35, 1.02)
    ax.set_xlabel("increment in stiffness (comparison / reference - 1)")
    ax.set_ylabel("proportion correct")
    gm = np.exp(np.mean(np.log([r["weber"] for r in rows if r["weber"] == r["weber"] and r["weber"] > 0]))) if rows else float("nan")
    ax.set_title(("SYNTHETIC DATA: " if synthetic else "") + f"{condition}: {len(rows)} participants, geometric-mean Weber fraction {gm:.1%}",
                 fontsize=9)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
