"""Report plots (matplotlib, headless): rates with intervals, deformation times, force traces
of every model against the FEM reference for the same pull (like the seed paper's Fig. 5).

Each figure is made by a `*_figure` function at a size (analysis/reports/figure_size.py: the screen's,
or 85 or 175 mm wide for a journal) with a constrained layout, so that nothing is cut at the
figure's edge at the width asked; `*_plot` writes one file, `save` every format of the size.
The conditions keep one colour in every plot (`palette`, Okabe-Ito: colour-blind safe)."""

from __future__ import annotations

import functools
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.transforms import Bbox, blended_transform_factory

from analysis.discrimination.psychometric import fit_psychometric
from analysis.reports.figure_size import SCREEN, FigureSize, figure_size, fit, wrap
from analysis.reports.figure_size import save as save  # write_plots saves every format through plots.save
from analysis.statistics.kind_results import ChoiceStats, RatingStats, ScoreStats
from analysis.verification.paper import deformation_ms
from sim.perception import force_jnd
from sim.text import counted


def _plt():
    matplotlib.use("Agg")
    return plt


# Okabe-Ito (analysis.reports.figure_size.OKABE_ITO): the three models keep theirs in every study
COLORS = {"fem": "#0072B2", "mass_spring": "#E69F00", "plate_spring": "#009E73"}
OTHER_COLORS = ("#D55E00", "#CC79A7", "#56B4E9", "#000000", "#F0E442")


def color(name: str, k: int) -> str:
    """A model's own colour; a named condition (studyctl/conditions.py) the k-th of the others."""
    return COLORS.get(name) or OTHER_COLORS[k % len(OTHER_COLORS)]


def palette(models) -> dict[str, str]:
    """Each condition's colour, the same in every plot of a study: a model its own; the named
    conditions, in the study's order, the Okabe-Ito colours no model of the study has."""
    models = list(dict.fromkeys(models))
    taken = {COLORS[m] for m in models if m in COLORS}
    free = [c for c in OTHER_COLORS + tuple(COLORS.values()) if c not in taken]
    out, k = {}, 0
    for m in models:
        if m in COLORS:
            out[m] = COLORS[m]
        else:
            out[m] = free[k % len(free)]
            k += 1
    return out


def styled(build):
    """A figure function drawn in its size's style (fonts, lines, colours): `size` a name or a FigureSize."""
    @functools.wraps(build)
    def drawn(*args, size: str | FigureSize = SCREEN, **kwargs):
        size = figure_size(size)
        with size.style():
            return build(*args, size=size, **kwargs)
    return drawn


def _figure(size: FigureSize, screen, single_mm: float, double_mm: float, nrows: int = 1, ncols: int = 1, **kw):
    fig, axes = _plt().subplots(nrows, ncols, figsize=size.figsize(screen, single_mm, double_mm), dpi=100, layout="constrained", **kw)
    fig.get_layout_engine().set(w_pad=2 / 72, h_pad=2 / 72)
    return fig, axes


def _suptitle(fig, text: str, size: FigureSize) -> None:
    """A figure's title, wrapped to its width (the synthetic label stays whole and in sight)."""
    fig.suptitle(wrap(text, size.font_pt, fig.get_figwidth() - 0.15), fontsize=size.font_pt)


def _legend(fig, size: FigureSize, ncols: int, **kw):
    """The legend below the axes, outside them (it covers no data; above them it would lie on the
    figure's title: the constrained layout stacks neither on the other)."""
    return fig.legend(loc="outside lower center", ncols=ncols, frameon=False, fontsize=size.small_pt, **kw)


def _save_one(fig, path: Path, size: FigureSize) -> None:
    with size.style():
        fig.savefig(path, dpi=size.dpi)
    _plt().close(fig)


def _kind(synthetic: bool | str) -> str:
    """The data's kind as a title says it: `synthetic` is False (people), True (simulated
    participants only) or "mixed" (people and simulated participants pooled)."""
    return "MIXED DATA" if synthetic == "mixed" else "SYNTHETIC DATA" if synthetic else ""


def _flag(synthetic: bool | str) -> str:
    return f"{_kind(synthetic)}: " if synthetic else ""


@styled
def rates_figure(rates, synthetic: bool, size: FigureSize = SCREEN, models=None):
    """Favourable rate per question and model, with Wilson 95% intervals."""
    items = list(dict.fromkeys(rates["item"]))
    models = list(models or dict.fromkeys(rates["model"]))
    pal = palette(models)
    fig, ax = _figure(size, (9, 4.2), 68, 80)
    width = 0.8 / len(models)
    for j, m in enumerate(models):
        g = rates[rates["model"] == m].set_index("item").reindex(items)
        x = np.arange(len(items)) + (j - (len(models) - 1) / 2) * width
        ax.errorbar(x, g["rate"], yerr=[g["rate"] - g["wilson_low"], g["wilson_high"] - g["rate"]], fmt="o",
                    capsize=2 if size.is_print else 3, color=pal[m], label=m)
    ax.set_xticks(np.arange(len(items)), items, rotation=30, ha="right", rotation_mode="anchor")
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("favourable rate (Wilson 95% CI)")
    ax.grid(axis="y", alpha=0.3)
    _suptitle(fig, _flag(synthetic) + "favourable rate per question and model", size)
    _legend(fig, size, len(models))
    return fig


@styled
def deformation_figure(lat, synthetic: bool, size: FigureSize = SCREEN, models=None):
    """Distribution of the deformation time per frame (trial means) per model, log scale
    (`lat`: ``model, value`` per trial, analysis.study.study_snapshot.Study.latency_trials)."""
    present = list(dict.fromkeys(lat["model"]))
    pal = palette(list(models or []) + present)
    models = [m for m in (models or present) if m in present] + [m for m in present if m not in (models or present)]
    fig, ax = _figure(size, (6, 3.6), 60, 70)
    data = [lat.loc[lat["model"] == m, "value"].to_numpy() for m in models]
    ax.boxplot(data, showfliers=False, medianprops={"color": "black"})
    rng = np.random.default_rng(0)
    for i, (m, v) in enumerate(zip(models, data), start=1):
        ax.scatter(i + rng.uniform(-0.15, 0.15, len(v)), v, s=3 if size.is_print else 6, alpha=0.6, color=pal[m])
    turn = size.name == "single" and len(models) > 3
    ax.set_xticks(range(1, len(models) + 1), models, rotation=30 if turn else 0, ha="right" if turn else "center", rotation_mode="anchor")
    ax.set_yscale("log")
    ax.set_ylabel("deformation time per frame (ms)")
    ax.grid(axis="y", alpha=0.3)
    _suptitle(fig, _flag(synthetic) + "time for real-time deformation (trial means): benchmark of this machine", size)
    return fig


FORCE_FLOOR_N = 0.01  # the relative difference is drawn where the reference is above this
# what the lower panel is, beside the accuracy table's force error (another quantity: said on the figure)
DIFFERENCE_WORDS = ("relative difference to the reference on the scene's own pull, each condition as the study ran it "
                    "(uncalibrated), every servo sample with the reference above 0.01 N, to the pull's end; not the accuracy "
                    "table's force error (a mean of |difference| over held-out pulls' decided samples, raw and calibrated). "
                    "Dotted: force JND, 25% below 0.5 N and 10% above")


def force_differences(traces: dict) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
    """What the force figure's lower panel draws per condition: the times and (F - F_ref) / F_ref
    where the reference is above `FORCE_FLOOR_N`, and the mean |relative difference| its legend gives."""
    out = {}
    for m, (t, f, ref) in traces.items():
        mask = ref > FORCE_FLOOR_N
        rel = (f[mask] - ref[mask]) / ref[mask]
        out[m] = (t[mask], rel, float(np.mean(np.abs(rel))) if rel.size else float("nan"))
    return out


@styled
def force_figure(traces: dict, size: FigureSize = SCREEN):
    """Fig. 5-style: force of each model and the converged reference for the same pull, and
    the relative difference against the force JND (`force_differences`)."""
    pal = palette(traces)
    fig, (ax, bx) = _figure(size, (7, 5.4), 100, 110, 2, 1, sharex=True)
    thin = 0.7 if size.is_print else 1.0
    diffs = force_differences(traces)
    for m, (t, f, ref) in traces.items():
        td, rel, mean = diffs[m]
        ax.plot(t, f, color=pal[m], lw=1.3 * thin, label=f"{m}: mean |difference| {mean:.0%}")
        ax.plot(t, ref, color=pal[m], lw=0.8 * thin, ls="--")
        bx.plot(td, rel, color=pal[m], lw=1.0 * thin)
    panel = fig.get_figwidth() - 0.6  # the axes' width, about: the y labels take the rest
    ax.set_ylabel("force on the hand (N)")
    ax.set_title(wrap("the scene's pull with each model; dashed: converged P2 reference for the same hand motion", size.small_pt, panel),
                 fontsize=size.small_pt)
    ax.grid(alpha=0.3)
    tt = np.linspace(0, max(t.max() for t, _, _ in traces.values()), 2)
    for sign in (1, -1):
        bx.plot(tt, sign * force_jnd(np.array([0.0, 0.0])), color="0.5", ls=":", lw=0.8 * thin)
        bx.plot(tt, sign * force_jnd(np.array([1.0, 1.0])), color="0.3", ls=":", lw=0.8 * thin)
    bx.set_ylabel("relative difference to the reference")
    bx.set_xlabel("time (s)")
    bx.set_ylim(-1.0, 5.0)
    bx.set_title(wrap(DIFFERENCE_WORDS, size.small_pt, panel), fontsize=size.small_pt)
    bx.grid(alpha=0.3)
    _legend(fig, size, min(len(traces), 1 if size.name == "single" else 2))
    return fig


def force_plot(traces: dict, path: Path, size: str | FigureSize = SCREEN) -> None:
    _save_one(force_figure(traces, size=size), path, figure_size(size))


def pareto(rows: list[dict]) -> list[bool]:
    """Rows no other row beats on both force error and frame time."""
    out = []
    for r in rows:
        out.append(not any(o is not r and o["force_error"] <= r["force_error"] and o["frame_ms"] <= r["frame_ms"]
                           and (o["force_error"] < r["force_error"] or o["frame_ms"] < r["frame_ms"]) for o in rows))
    return out


def pareto_plot(rows: list[dict], path: Path, reference: str = "", size: str | FigureSize = SCREEN) -> None:
    """Log-log: mean relative force error against deformation time per frame, one point per
    model setting; the Pareto front joined (black) and each class's own (dashed, its colour); the paper's deformation times as vertical marks."""
    _save_one(pareto_figure(rows, reference, size=size), path, figure_size(size))


@styled
def pareto_figure(rows: list[dict], reference: str = "", size: FigureSize = SCREEN):
    fig, ax = _figure(size, (10, 5.5), 68, 100)
    pal = palette(list(COLORS) + [r["model"] for r in rows])
    front = pareto(rows)
    big, small = (25, 10) if size.is_print else (50, 25)
    labels = []
    for r, on in zip(rows, front):
        ax.scatter(r["frame_ms"], max(r["force_error"], 1e-4), color=pal[r["model"]], s=big if on else small,
                   edgecolor="black" if on else "none", linewidth=0.5 if size.is_print else 1.0, zorder=3)
        labels.append(ax.annotate(f"{r['setting']}", (r["frame_ms"], max(r["force_error"], 1e-4)), fontsize=size.tiny_pt, xytext=(3, 2),
                                  textcoords="offset points"))
    pts = sorted((r["frame_ms"], max(r["force_error"], 1e-4)) for r, on in zip(rows, front) if on)
    if pts:
        ax.step([p[0] for p in pts], [p[1] for p in pts], where="post", color="black", lw=0.8, zorder=2, label="Pareto front")
    for model in dict.fromkeys(r["model"] for r in rows):  # each class's own front: its best configurations
        mine = [r for r in rows if r["model"] == model]
        own = sorted((r["frame_ms"], max(r["force_error"], 1e-4)) for r, on in zip(mine, pareto(mine)) if on)
        if len(own) > 1:
            ax.step([p[0] for p in own], [p[1] for p in own], where="post", color=pal[model], lw=0.8, ls="--", zorder=1)
    for k, (model, ms) in enumerate(deformation_ms().items()):  # the three lie close together: stagger the labels
        ax.axvline(ms, color=COLORS[model], ls=":", lw=1)
        ax.text(ms, 0.98 - 0.07 * k, f" paper {model.replace('_', '-')} {ms} ms", color=COLORS[model], fontsize=size.tiny_pt, va="top",
                ha="right", transform=ax.get_xaxis_transform())
    for model in dict.fromkeys([*COLORS, *(r["model"] for r in rows)]):
        ax.scatter([], [], color=pal[model], label=model)
    ax.axhline(0.10, color="grey", ls="--", lw=0.8)
    ax.text(0.99, 0.10, "force JND at or above 0.5 N (10%)", fontsize=size.tiny_pt, va="bottom", ha="right", color="grey",
            transform=ax.get_yaxis_transform())
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("deformation time per visual frame, ms (median, this machine)")
    ax.set_ylabel("mean force error (decided samples)")
    _suptitle(fig, "Force error vs deformation time" + (f" (reference {reference})" if reference else ""), size)
    # outside the axes: inside, "lower left" covered the best point (fast and accurate lies there)
    _legend(fig, size, 3 if size.name == "single" else 6)
    place_labels(fig, labels, size.tiny_pt)
    return fig


def _label_offsets(height_pt: float, rings: int = 8):
    """Offsets (points) and alignment to try for a point's label, nearest first: right or left
    of the point, above or below, then further up and down a line at a time."""
    for k in range(rings):
        for dy in (2 + k * height_pt, -height_pt - k * height_pt):
            for dx, ha in ((3, "left"), (-3, "right")):
                yield dx, dy, ha


def place_labels(fig, labels: list, font_pt: float) -> None:
    """Each label at the nearest of `_label_offsets` where it overlaps no label placed before it
    (the settings of one class lie close together: their labels were drawn over each other), and,
    where one is free, no other text and no point either. The layout is drawn first, so the boxes
    are the ones the file shows."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    ax = labels[0].axes if labels else None
    others = [t.get_window_extent(renderer) for t in (ax.texts if ax else []) if t not in labels]
    dot = font_pt * fig.dpi / 72 / 3  # a point's marker, about
    others += [Bbox.from_extents(x - dot, y - dot, x + dot, y + dot) for x, y in (ax.transData.transform(t.xy) for t in labels)]
    placed = []
    for label in labels:
        fits = []
        for dx, dy, ha in _label_offsets(font_pt * 1.25):
            label.xyann = (dx, dy)
            label.set_horizontalalignment(ha)
            box = label.get_window_extent(renderer)
            if not any(box.overlaps(b) for b in placed):
                fits.append((dx, dy, ha))
                if not any(box.overlaps(b) for b in others):
                    break
        else:  # no spot free of other texts: the nearest free of labels
            if fits:
                label.xyann = fits[0][:2]
                label.set_horizontalalignment(fits[0][2])
        placed.append(label.get_window_extent(renderer))


STABILITY_COLORS = (("stable", "#009E73"), ("refused", "#9e9e9e"), ("unstable", "#D55E00"))


@styled
def stability_figure(outcomes: tuple, title: str = "", size: FigureSize = SCREEN):
    """Outcome per model (rows) and case (columns): stable, refused, unstable, or n/a;
    `outcomes` is (rows, columns, codes) as `analysis.verification.stability.outcome_grid` makes it. At a
    print size whose width has no room for a column per case (one line of text each), the
    cases are the rows instead, and the figure as tall as they need."""
    rows, cols, grid = outcomes
    turned = size.is_print and len(cols) * size.small_pt * 1.6 / 72 * 25.4 > size.width_mm * 0.8
    if turned:
        rows, cols, grid = cols, rows, np.asarray(grid).T
    line = size.small_pt * 1.6 / 72 * 25.4  # mm: one row of cells
    label = max((len(c) for c in cols), default=0) * size.tiny_pt * 0.55 / 72 * 25.4  # mm: the longest turned column label
    tall = line * len(rows) + 22 + 0.95 * label  # and the title, the legend
    fig, ax = _figure(size, (max(8, 0.32 * len(cols) + 3), 0.45 * len(rows) + 2.4), tall, tall)
    cmap = ListedColormap([c for _, c in STABILITY_COLORS]).with_extremes(bad="white")
    ax.imshow(np.ma.masked_invalid(grid), cmap=cmap, vmin=-0.5, vmax=2.5, aspect="auto")
    ax.set_xticks(range(len(cols)), cols, rotation=70, ha="right", rotation_mode="anchor", fontsize=size.tiny_pt)
    ax.set_yticks(range(len(rows)), rows, fontsize=size.small_pt)
    for i in range(len(rows)):
        for j in range(len(cols)):
            if not np.isnan(grid[i, j]):
                ax.text(j, i, "SRU"[int(grid[i, j])], ha="center", va="center", fontsize=size.tiny_pt, color="white")
    for label, c in STABILITY_COLORS:
        ax.scatter([], [], marker="s", color=c, label=f"{label} ({label[0].upper()})")
    _suptitle(fig, title or "Stability sweep", size)
    _legend(fig, size, 3)
    return fig


def stability_heatmap(outcomes: tuple, path: Path, title: str = "", size: str | FigureSize = SCREEN) -> None:
    _save_one(stability_figure(outcomes, title, size=size), path, figure_size(size))


@styled
def likert_figure(ratings: dict[str, RatingStats], models: list[str], synthetic: bool, size: FigureSize = SCREEN):
    """Diverging stacked bars (the field's convention for Likert items; Heiberger and Robbins
    2014): per item and condition, the share of each point, disagreeing points left of zero,
    agreeing ones right, the middle point split across zero. Each question is a header line
    above its conditions' bars (written once, as long as the figure's width lets it be)."""
    plt = _plt()
    groups = [(v.question, [(m, np.asarray(v.conditions[m].counts, dtype=float)) for m in models]) for v in ratings.values()]
    lines = sum(1 + len(g) for _, g in groups)
    points = max(len(c) for _, g in groups for _, c in g)
    cmap = plt.get_cmap("RdBu", points)  # diverging, told apart with red-green deficiencies
    row_mm = 1.45 * size.small_pt * 25.4 / 72
    fig, ax = _figure(size, (10, 0.3 * lines + 1.8), lines * row_mm + 30, lines * row_mm + 30)
    header = blended_transform_factory(fig.transFigure, ax.transData)
    y, ticks, labels = 0, [], []
    for question, rows in groups:
        t = ax.text(0.01, y + 0.1, fit(question, size.small_pt, fig.get_figwidth() * 0.97), transform=header, fontsize=size.small_pt,
                    fontweight="bold", va="center", ha="left")
        t.set_in_layout(False)  # it lies across the axes on a line of its own; the layout leaves it be
        ax.vlines(0, y + 0.55, y + len(rows) + 0.45, color="#333", lw=0.8)
        for m, counts in rows:
            y += 1
            ticks.append(y)
            labels.append(m)
            share = counts / counts.sum() if counts.sum() else counts
            k = len(share)
            left = -(share[:k // 2].sum() + (share[k // 2] / 2 if k % 2 else 0.0))
            for j, s in enumerate(share):
                ax.barh(y, s, left=left, color=cmap(j * (points - 1) // max(k - 1, 1)), edgecolor="#888", linewidth=0.3, height=0.8,
                        label=str(j + 1) if y == 1 else None)
                left += s
        y += 1
    ax.set_yticks(ticks, labels)
    ax.tick_params(axis="y", length=0)
    for side in ("left", "right", "top"):
        ax.spines[side].set_visible(False)
    ax.set_ylim(y - 0.5, -0.6)
    ax.set_xlim(-1, 1)
    ax.set_xlabel(wrap("share of participants (left: below the middle of the scale; right: above)", size.font_pt, fig.get_figwidth() - 0.3))
    _suptitle(fig, "Ratings per condition" + (f" ({_kind(synthetic)})" if synthetic else ""), size)
    _legend(fig, size, points, title="rating", handlelength=1.2, columnspacing=1.0)
    return fig


@styled
def scores_figure(scores: dict[str, ScoreStats], meas, models: list[str], synthetic: bool, size: FigureSize = SCREEN):
    """Each score per condition: a box plot with every participant's value as a point."""
    items = list(scores)
    pal = palette(models)
    ncols = min(len(items), {"single": 2, "double": 3}.get(size.name, len(items)))
    nrows = -(-len(items) // ncols)
    fig, axes = _figure(size, (3.2 * len(items) + 1, 3.8), 14 + 50 * nrows, 14 + 60 * nrows, nrows, ncols, squeeze=False)
    rng = np.random.default_rng(0)  # horizontal jitter only: the values are drawn as they are
    for ax in axes.flat[len(items):]:
        ax.set_visible(False)
    for ax, item in zip(axes.flat, items):
        data = [meas[(meas["item"] == item) & (meas["model"] == m)]["answer"].to_numpy(float) for m in models]
        ax.boxplot(data, tick_labels=models, showfliers=False, widths=0.5, medianprops={"color": "black"})
        for j, (m, v) in enumerate(zip(models, data)):
            ax.scatter(j + 1 + rng.uniform(-0.12, 0.12, len(v)), v, s=6 if size.is_print else 12, color=pal[m], alpha=0.8, zorder=3)
        ax.set_title(wrap(scores[item].label, size.small_pt, fig.get_figwidth() / ncols - 0.4), fontsize=size.small_pt)
        ax.tick_params(axis="x", rotation=30)
        for t in ax.get_xticklabels():
            t.set(ha="right", rotation_mode="anchor")
    _suptitle(fig, "Scores per condition" + (f" ({_kind(synthetic)})" if synthetic else ""), size)
    return fig


@styled
def choice_figure(choice: ChoiceStats, models: list[str], synthetic: bool, size: FigureSize = SCREEN):
    """Share of participants choosing each condition, with Wilson 95% intervals."""
    pal = palette(models)
    fig, ax = _figure(size, (5, 3.4), 62, 70)
    s = [choice.shares[m] for m in models]
    share = np.array([x.share for x in s])
    ax.bar(range(len(models)), share, color=[pal[m] for m in models], width=0.6 if size.name == "double" else 0.8)
    ax.errorbar(range(len(models)), share, yerr=[share - [x.wilson_low for x in s], np.array([x.wilson_high for x in s]) - share],
                fmt="none", color="#333", capsize=3 if size.is_print else 4, lw=0.8 if size.is_print else 1.5)
    ax.axhline(1 / len(models), color="#999", ls="--", lw=0.8)
    turn = size.name == "single" and len(models) > 3
    ax.set_xticks(range(len(models)), models, rotation=30 if turn else 0, ha="right" if turn else "center", rotation_mode="anchor")
    ax.set_ylim(0, 1)
    ax.set_ylabel("share chosen (Wilson 95% CI)")
    _suptitle(fig, choice.question + (f" ({_kind(synthetic)})" if synthetic else ""), size)
    return fig


@styled
def psychometric_figure(trials, rows: list[dict], condition: str, synthetic: bool, size: FigureSize = SCREEN):
    """One condition's discrimination: every participant's fitted psychometric function
    (analysis/discrimination/psychometric.py, refitted here for its curve) and Weber fraction, and the pooled
    proportion correct in bins of the increment (point size: trials), on a log axis."""
    fig, ax = _figure(size, (6, 4), 68, 80)
    c = COLORS.get(condition, "#0072B2")
    d = trials["stimulus"].to_numpy(dtype=float)
    lo, hi = float(d.min()) / 1.5, float(d.max()) * 1.5
    grid = np.geomspace(lo, hi, 200)
    for _, g in trials.groupby("code", sort=True):
        fit_ = fit_psychometric(g["stimulus"], g["correct"])
        ax.plot(grid, fit_.p_correct(grid), color=c, alpha=0.35, lw=0.7 if size.is_print else 1)
        ax.plot([fit_.weber], [0.75 - fit_.lapse / 2], "o", color=c, ms=2 if size.is_print else 3, alpha=0.6)
    edges = np.geomspace(d.min() * 0.999, d.max() * 1.001, 9)
    idx = np.clip(np.digitize(d, edges) - 1, 0, len(edges) - 2)
    correct = trials["correct"].to_numpy(dtype=float)
    scale = 0.5 if size.is_print else 1.0
    for b in range(len(edges) - 1):
        sel = idx == b
        if sel.any():
            ax.scatter(np.exp(np.log(d[sel]).mean()), correct[sel].mean(), s=scale * (8 + 2 * sel.sum()), color="k", alpha=0.7, zorder=3)
    ax.axhline(0.75, color="0.6", lw=0.8, ls="--")
    ax.set_xscale("log")
    ax.set_ylim(0.35, 1.02)
    ax.set_xlabel("increment in stiffness (comparison / reference - 1)")
    ax.set_ylabel("proportion correct")
    gm = np.exp(np.mean(np.log([r["weber"] for r in rows if r["weber"] == r["weber"] and r["weber"] > 0]))) if rows else float("nan")
    _suptitle(fig, _flag(synthetic) + f"{condition}: {counted(len(rows), 'participant')}, geometric-mean Weber fraction {gm:.1%}", size)
    ax.grid(alpha=0.3)
    return fig


def psychometric_plot(trials, rows: list[dict], condition: str, path: Path, synthetic: bool, size: str | FigureSize = SCREEN) -> None:
    _save_one(psychometric_figure(trials, rows, condition, synthetic, size=size), path, figure_size(size))
