"""Figures at journal sizes (issue 46): `report plots --size single|double` writes PDF, SVG and
600-dpi PNG exactly 85 or 175 mm wide, fonts embedded and no smaller than 6 pt where printed,
nothing cut at the figure's edge, the conditions in Okabe-Ito colours, one colour each in
every plot; the synthetic label in sight."""

from __future__ import annotations

import json
import re
import struct

import numpy as np
import pandas as pd
import pytest
from matplotlib.text import Text

from analysis.reports import plots, report
from analysis.reports.figure_size import DOUBLE, OKABE_ITO, PAGE_MM, SINGLE, figure_size
from studyctl.cli.common import read_snapshot
from studyctl.synthetic.force_traces import force_traces
from tests.helpers import studyctl

PRINT = {"single": 85.0, "double": 175.0}
TALL = {"ratings", "force", "stability"}  # as tall as their content: rows, panels, cases


def shown_texts(fig) -> list[Text]:
    """Every text the figure draws: visible, not empty, not in a hidden axes, and, for tick
    labels, only those of ticks inside the axis' view (matplotlib keeps others unused)."""
    unused = set()
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            lo, hi = sorted(axis.get_view_interval())
            slack = 1e-9 * max(abs(lo), abs(hi), 1.0)
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                loc = tick.get_loc()
                if loc is None or not lo - slack <= loc <= hi + slack:
                    unused |= {id(tick.label1), id(tick.label2)}
    return [t for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip() and id(t) not in unused
            and not (t.axes is not None and not t.axes.get_visible())]


def check_figure(fig, size, name: str) -> list[str]:
    """After the figure was saved (its own size, no tight bounding box, as in the files): every
    shown text inside the figure (its window extent, by the canvas' renderer at the PNG's
    resolution, within fig.bbox) and, at a print size, none under 6 pt. Returns the texts.
    The figure is laid out again at that resolution first: savefig leaves the legends' offsets
    in the pixels of the last format written."""
    dpi = fig.dpi
    fig.set_dpi(size.dpi)
    try:
        fig.draw_without_rendering()
        renderer = fig.canvas.get_renderer()
        box = fig.bbox
        texts = shown_texts(fig)
        assert texts, name
        for t in texts:
            e = t.get_window_extent(renderer)
            inside = e.x0 >= box.x0 - 1 and e.y0 >= box.y0 - 1 and e.x1 <= box.x1 + 1 and e.y1 <= box.y1 + 1
            assert inside, f"{name} ({size.name}): {t.get_text()!r} at {e.bounds} is cut by the figure's edge {box.bounds}"
            if size.is_print:
                assert t.get_fontsize() >= 6.0, f"{name} ({size.name}): {t.get_text()!r} is {t.get_fontsize()} pt"
    finally:
        fig.set_dpi(dpi)
    return [t.get_text() for t in texts]


def pdf_mm(path) -> tuple[float, float]:
    m = re.search(rb"/MediaBox\s*\[\s*0\s+0\s+([\d.]+)\s+([\d.]+)\s*\]", path.read_bytes())
    assert m, path
    return float(m.group(1)) / 72 * 25.4, float(m.group(2)) / 72 * 25.4


def png_px(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


def check_files(files: list, size) -> None:
    """The written files: PDF page and PNG pixels at the journal width, fonts embedded."""
    width = PRINT[size.name]
    assert {f.suffix for f in files} == {".pdf", ".svg", ".png"}
    for f in files:
        if f.suffix == ".pdf":
            w, h = pdf_mm(f)
            assert abs(w - width) <= 0.5, (f.name, w)
            assert h <= PAGE_MM + 0.5, (f.name, h)
            assert f.stem in TALL or size.name != "single" or h <= 0.8 * width + 0.5, (f.name, h)
            data = f.read_bytes()
            assert b"/FontFile2" in data, f.name  # TrueType (type 42) embedded, no type 3
            assert b"/Type3" not in data, f.name
        elif f.suffix == ".png":
            assert png_px(f)[0] == round(width / 25.4 * 600), f.name
        else:
            svg = f.read_text()
            m = re.search(r'<svg[^>]*\swidth="([\d.]+)pt"', svg)
            assert m, f.name
            assert abs(float(m.group(1)) / 72 * 25.4 - width) <= 0.5, f.name
            assert "<text" not in svg, f.name  # svg.fonttype "path": glyphs drawn as paths


@pytest.fixture
def checked(monkeypatch):
    """plots.save, with every figure checked after it is saved as the files are; returns the
    texts of each figure by its file name."""
    seen = {}
    save = plots.save

    def checking(fig, stem, size, close=True):
        out = save(fig, stem, size, close=False)
        seen[stem.name] = check_figure(fig, size, stem.name)
        plots._plt().close(fig)
        return out

    monkeypatch.setattr(plots, "save", checking)
    return seen


@pytest.mark.parametrize("which,size", [("paper", "single"), ("paper", "double"), ("variants", "single"), ("variants", "double"),
                                        ("variants", "screen")])
def test_every_report_plot_fits_its_size(which, size, small_study, variants_study, checked, tmp_path):
    db = small_study if which == "paper" else variants_study
    size = figure_size(size)
    traces = which == "paper" and size.name == "single"  # the force traces once: they run the scene with each condition
    study = read_snapshot(db)
    files = report.write_plots(study, tmp_path, force_traces(study.protocol) if traces else None, size=size)
    names = {"paper": ["rates", "deformation"] + ["force"] * traces, "variants": ["ratings", "scores", "choice_most_like_tissue", "deformation"]}
    assert list(checked) == names[which]
    assert [f.name for f in files] == [f"{n}.{ext}" for n in names[which] for ext in size.formats]
    for name, texts in checked.items():  # the synthetic label stays on every figure of participants' answers
        assert name == "force" or any("SYNTHETIC" in t for t in texts), name
    if size.is_print:
        check_files(files, size)
    else:
        assert [f.suffix for f in files[:2]] == [".png", ".svg"]
        assert png_px(files[0])[0] < 2000


def test_the_deformation_title_is_not_cut_on_screen(small_study, checked, tmp_path):
    """The HTML report's deformation figure had its title cut at the right edge: now wrapped."""
    report.write_plots(read_snapshot(small_study), tmp_path)
    title = next(t for t in checked["deformation"] if t.startswith("SYNTHETIC DATA"))
    assert "benchmark of this machine" in title.replace("\n", " ")


def _pareto_rows():
    rng = np.random.default_rng(1)
    return [{"model": m, "setting": f"{m[:5]}-{k}", "frame_ms": float(rng.uniform(0.5, 40)), "force_error": float(rng.uniform(0.01, 1))}
            for m in ("plate_spring", "fem", "mass_spring") for k in range(4)]


def _stability():
    from analysis.verification.stability import make_cases, outcome_grid

    rng = np.random.default_rng(2)
    cases = [{"model": c.model, "case": c.case, "outcome": ("stable", "refused", "unstable")[int(rng.integers(3))]} for c in make_cases()]
    return outcome_grid(cases)


def _psychometric():
    rng = np.random.default_rng(3)
    stim = np.tile(np.geomspace(0.02, 0.6, 8), 10)
    frames = [pd.DataFrame({"code": f"P{p}", "stimulus": stim, "correct": (rng.random(len(stim)) < 0.5 + 0.5 * (stim > 0.1 * (p + 1))).astype(int)})
              for p in range(3)]
    return pd.concat(frames), [{"weber": 0.1 * (p + 1)} for p in range(3)]


@pytest.mark.parametrize("size", [SINGLE, DOUBLE])
def test_the_bench_and_discrimination_plots_fit_too(size, tmp_path):
    trials, rows = _psychometric()
    figures = {"pareto": plots.pareto_figure(_pareto_rows(), "fem P2 4 mm", size=size),
               "stability": plots.stability_figure(_stability(), size=size),
               "psychometric": plots.psychometric_figure(trials, rows, "fem", True, size=size)}
    for name, fig in figures.items():
        files = plots.save(fig, tmp_path / name, size, close=False)
        texts = check_figure(fig, size, name)
        plots._plt().close(fig)
        check_files(files, size)
        assert name != "psychometric" or any(t.startswith("SYNTHETIC DATA") for t in texts)


def test_one_colour_per_condition_in_every_plot(variants_study):
    from matplotlib.colors import to_hex

    pal = plots.palette(["paper", "located", "fem_linear", "fem"])
    assert pal["fem"] == plots.COLORS["fem"]
    assert len(set(pal.values())) == 4
    assert set(pal.values()) <= set(OKABE_ITO)
    assert plots.palette(["plate_spring", "fem", "mass_spring"]) == plots.COLORS  # the models' own, whatever the study
    study = read_snapshot(variants_study)
    models = list(study.protocol.conditions)
    pal = plots.palette(models)
    from analysis.statistics import table1
    from analysis.statistics.kinds import kind_stats

    answers, _ = table1.complete_answers(study)
    choice = next(iter(kind_stats(study, answers).choices.values()))
    fig = plots.choice_figure(choice, models, True, size="single")
    assert [to_hex(p.get_facecolor()) for p in fig.axes[0].patches] == [pal[m].lower() for m in models]
    fig = plots.deformation_figure(study.latency_trials, True, size="single", models=models)
    assert [to_hex(c.get_facecolor()[0]) for c in fig.axes[0].collections] == [pal[m].lower() for m in models]
    plots._plt().close("all")


def test_cli_writes_journal_sizes_and_lists_them(small_study, tmp_path):
    res = studyctl("report", "plots", "--db", small_study, "--out", tmp_path / "fig", "--size", "double", "--json")
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert doc["size"] == "double"
    assert [f["path"].rsplit("/", 1)[1] for f in doc["files"]] == [
        f"{n}.{ext}" for n in ("rates", "deformation", "force") for ext in ("pdf", "svg", "png")]
    for f in doc["files"]:
        assert abs(f["width_mm"] - 175) <= 0.5
        assert 0 < f["height_mm"] <= PAGE_MM
        assert f["bytes"] == (tmp_path / "fig" / f["path"].rsplit("/", 1)[1]).stat().st_size
        assert f["format"] != "png" or (f["width_px"] == 4134 and f["dpi"] == 600)
    assert studyctl("report", "plots", "--db", small_study, "--out", tmp_path / "x", "--size", "a4").exit_code == 2


def test_the_check_sees_a_cut_title_and_small_text(tmp_path):
    """The check itself: a title wider than the figure (the old deformation figure's fault) and
    5-pt text at a print size are both caught."""
    plt = plots._plt()
    for size, text, pt in ((SINGLE, "a title far too long for one column of a journal page, cut at both edges " * 2, 7), (SINGLE, "small", 5)):
        with size.style():
            fig, ax = plt.subplots(figsize=size.figsize((4, 3), 60, 60), layout="constrained")
            ax.set_title(text, fontsize=pt)
            plots.save(fig, tmp_path / "bad", size, close=False)
            with pytest.raises(AssertionError, match="cut by the figure's edge" if pt == 7 else "is 5.0 pt"):
                check_figure(fig, size, "bad")
            plt.close(fig)


# the full bench's raw rows (docs/accuracy.md): the settings of one class lie close together
SHIPPED_ROWS = [{"model": m, "setting": s, "frame_ms": ms, "force_error": e} for m, s, ms, e in (
    ("plate_spring", "paper", 0.0404, 1.498), ("plate_spring", "continuous", 0.0405, 1.498), ("plate_spring", "scene-fit", 0.0275, 0.550),
    ("plate_spring", "located", 0.0282, 0.126), ("fem", "linear-8mm", 0.156, 0.261), ("fem", "linear-6mm", 0.169, 0.203),
    ("fem", "linear-4mm", 0.202, 0.146), ("fem", "linear-p2-8mm", 0.504, 0.157), ("fem", "linear-p2-6mm", 0.588, 0.159),
    ("fem", "corotational-8mm", 6.45, 0.283), ("fem", "corotational-6mm", 8.04, 0.235), ("mass_spring", "explicit-8mm", 26.7, 0.663),
    ("mass_spring", "implicit-8mm", 131.0, 0.284), ("mass_spring", "local-global-8mm", 6.01, 0.302),
    ("mass_spring", "local-global-6mm", 14.1, 0.197), ("mass_spring", "local-global-4mm", 48.0, 0.232),
    ("mass_spring", "local-global-8mm-3it", 2.26, 0.409))]


@pytest.mark.parametrize("size", ["screen", "single", "double"])
def test_the_pareto_plots_labels_do_not_overlap(size):
    """paper and continuous, linear-p2-8mm and -6mm were drawn over each other."""
    fig = plots.pareto_figure(SHIPPED_ROWS, size=size)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    names = {r["setting"] for r in SHIPPED_ROWS}
    boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in fig.axes[0].texts if t.get_text() in names]
    plots._plt().close(fig)
    assert [(a, b) for i, (a, p) in enumerate(boxes) for b, q in boxes[i + 1:] if p.overlaps(q)] == []


def _traces():
    t = np.linspace(0.0, 1.0, 101)
    ref = 0.5 * t
    return {"fem": (t, 0.5 * ref, ref), "plate_spring": (t, 1.2 * ref, ref)}


def test_the_force_plots_difference_panel_draws_what_its_legend_says():
    """The pull plot showed the FEM 50% below the reference beside a table's 10.6%: the panel's
    numbers are its own (this pull, uncalibrated), given in the legend and said how they differ."""
    fig = plots.force_figure(_traces())
    lines = fig.axes[1].get_lines()[:2]
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    title = fig.axes[1].get_title().replace("\n", " ")
    plots._plt().close(fig)
    assert np.allclose(lines[0].get_ydata(), -0.5)
    assert legend[0] == "fem: mean |difference| 50%"
    assert "not the accuracy table's force error" in title


def test_the_force_differences_leave_out_a_reference_below_the_floor():
    t, rel, mean = plots.force_differences(_traces())["plate_spring"]
    assert t.min() > 0.0  # 0.5 t > 0.01 N from t = 0.03 s on
    assert mean == pytest.approx(0.2)
