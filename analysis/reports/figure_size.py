"""Figure sizes and style for the report plots (analysis/reports/plots.py): the screen size the HTML
report inlines, and journal sizes (one and two columns, 85 and 175 mm wide) written as PDF, SVG
and 600-dpi PNG with embedded fonts no smaller than 6 pt where printed; text wrapped to the
width it has; what a written figure file measures."""

from __future__ import annotations

import re
import struct
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
from cycler import cycler
from matplotlib.backends.backend_agg import RendererAgg
from matplotlib.font_manager import FontProperties

MM = 1 / 25.4  # inches per mm
PAGE_MM = 230.0  # the tallest figure a journal page holds beside its caption
# Okabe and Ito (2008), "Color universal design": told apart with every common colour-vision deficiency
OKABE_ITO = ("#E69F00", "#56B4E9", "#009E73", "#F0E442", "#0072B2", "#D55E00", "#CC79A7", "#000000")
CYCLE = ("#0072B2", "#D55E00", "#009E73", "#E69F00", "#CC79A7", "#56B4E9", "#000000", "#F0E442")  # yellow last: faint on white


@dataclass(frozen=True)
class FigureSize:
    """How big a figure is drawn and in which files: `width_mm` None is the screen size (each
    figure's own, in inches); fonts in points at the size the figure is printed or shown."""

    name: str
    width_mm: float | None
    dpi: int  # of the PNG
    font_pt: float  # titles and axis labels
    small_pt: float  # tick labels, legends
    tiny_pt: float  # annotations inside the axes
    formats: tuple[str, ...]

    @property
    def is_print(self) -> bool:
        return self.width_mm is not None

    def figsize(self, screen: tuple[float, float], single_mm: float, double_mm: float) -> tuple[float, float]:
        """Inches: the screen figure's own, or the journal width by the height given for this
        width (at most a page). The width is a whole number of PNG pixels, so that the PNG is
        exactly round(width / 25.4 * dpi) pixels wide."""
        if self.width_mm is None:
            return screen
        px = round(self.width_mm * MM * self.dpi)
        height = min(single_mm if self.name == "single" else double_mm, PAGE_MM)
        return ((px + 0.01) / self.dpi, height * MM)

    def rc(self) -> dict:
        """matplotlib rcParams for this size: fonts (TrueType embedded in PDF and PS: type 42;
        SVG text as paths, so a viewer lacking the font draws it as measured here), sizes,
        the colour-blind-safe colour cycle."""
        thin = self.is_print
        return {"pdf.fonttype": 42, "ps.fonttype": 42, "svg.fonttype": "path", "svg.hashsalt": "brainsim", "font.family": "DejaVu Sans",
                "font.size": self.font_pt, "axes.titlesize": self.font_pt, "axes.labelsize": self.font_pt,
                "figure.titlesize": self.font_pt, "xtick.labelsize": self.small_pt, "ytick.labelsize": self.small_pt,
                "legend.fontsize": self.small_pt, "legend.title_fontsize": self.small_pt, "figure.dpi": 100, "savefig.dpi": self.dpi,
                "savefig.bbox": None, "axes.prop_cycle": cycler(color=CYCLE),
                "axes.linewidth": 0.6 if thin else 0.8, "lines.linewidth": 1.0 if thin else 1.5,
                "xtick.major.width": 0.6 if thin else 0.8, "ytick.major.width": 0.6 if thin else 0.8,
                "xtick.major.size": 2.5 if thin else 3.5, "ytick.major.size": 2.5 if thin else 3.5,
                "lines.markersize": 3.5 if thin else 6.0, "legend.handlelength": 1.5 if thin else 2.0,
                **{f"boxplot.{part}.linewidth": 0.7 if thin else 1.0 for part in ("boxprops", "whiskerprops", "capprops", "medianprops")}}

    @contextmanager
    def style(self):
        matplotlib.use("Agg")
        with matplotlib.rc_context(self.rc()):
            yield


def wrap(text: str, pt: float, width_in: float) -> str:
    """`text` broken at spaces into lines no wider than `width_in` at `pt` points (a word
    wider than that stays whole on its own line)."""
    lines = []
    for w in text.split():
        if lines and text_width(f"{lines[-1]} {w}", pt) <= width_in * 72:
            lines[-1] += f" {w}"
        else:
            lines.append(w)
    return "\n".join(lines)


def fit(text: str, pt: float, width_in: float) -> str:
    """`text` on one line no wider than `width_in`, shortened with an ellipsis if it must be."""
    if text_width(text, pt) <= width_in * 72:
        return text
    for n in range(len(text) - 1, 0, -1):
        short = text[:n].rstrip() + "..."
        if text_width(short, pt) <= width_in * 72:
            return short
    return text[:1]


_RENDERERS = []


def text_width(text: str, pt: float) -> float:
    """Width in points of one line of `text` in the default font at `pt` points: the widest of
    the screen's and the print PNG's rendering (hinting makes them differ by a few percent),
    with 2% to spare."""
    if not _RENDERERS:
        _RENDERERS.extend(RendererAgg(10, 10, dpi) for dpi in (100, 600))
    prop = FontProperties(family="DejaVu Sans", size=pt)
    return 1.02 * max(r.get_text_width_height_descent(text, prop, ismath=False)[0] * 72 / r.dpi for r in _RENDERERS)


SCREEN = FigureSize("screen", None, 100, 10.0, 9.0, 7.0, ("png", "svg"))
SINGLE = FigureSize("single", 85.0, 600, 7.0, 6.0, 6.0, ("pdf", "svg", "png"))
DOUBLE = FigureSize("double", 175.0, 600, 8.0, 7.0, 6.0, ("pdf", "svg", "png"))
SIZES = {s.name: s for s in (SCREEN, SINGLE, DOUBLE)}


def figure_size(size: str | FigureSize) -> FigureSize:
    """A size by its name (screen, single, double) or itself."""
    if isinstance(size, FigureSize):
        return size
    if size not in SIZES:
        raise ValueError(f"unknown figure size {size!r}: one of {', '.join(SIZES)}")
    return SIZES[size]


def save(fig, stem: Path, size: FigureSize, close: bool = True) -> list[Path]:
    """`fig` as `stem`.EXT for each of the size's formats (the figure's own size: no tight
    bounding box, the layout is constrained); closed unless `close` is False."""
    out = []
    with size.style():
        for ext in size.formats:
            path = Path(f"{stem}.{ext}")
            fig.savefig(path, dpi=size.dpi, bbox_inches=None, metadata=_METADATA.get(ext))
            out.append(path)
    if close:
        plt.close(fig)
    return out


# no creation date: the same study gives the same files
_METADATA = {"pdf": {"CreationDate": None}, "svg": {"Date": None}, "png": None}


def file_info(path: Path) -> dict:
    """What a written figure measures: format, bytes, width and height in mm (PDF: its
    MediaBox; SVG: its width and height in pt; PNG: pixels and resolution)."""
    path = Path(path)
    data = path.read_bytes()
    ext = path.suffix.lstrip(".").lower()
    info = {"path": str(path), "format": ext, "bytes": len(data)}
    if ext == "pdf":
        m = re.search(rb"/MediaBox\s*\[\s*([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s*\]", data)
        if m:
            x0, y0, x1, y1 = (float(v) for v in m.groups())
            info.update(width_mm=round((x1 - x0) / 72 * 25.4, 2), height_mm=round((y1 - y0) / 72 * 25.4, 2))
    elif ext == "svg":
        m = re.search(rb'<svg[^>]*\swidth="([\d.]+)pt"[^>]*\sheight="([\d.]+)pt"', data)
        if m:
            info.update(width_mm=round(float(m.group(1)) / 72 * 25.4, 2), height_mm=round(float(m.group(2)) / 72 * 25.4, 2))
    elif ext == "png" and data[:8] == b"\x89PNG\r\n\x1a\n":
        w, h = struct.unpack(">II", data[16:24])
        info.update(width_px=w, height_px=h)
        k = data.find(b"pHYs")
        if k > 0:
            ppm_x, _, unit = struct.unpack(">IIB", data[k + 4:k + 13])
            if unit == 1 and ppm_x:
                dpi = round(ppm_x * 0.0254)
                info.update(dpi=dpi, width_mm=round(w / ppm_x * 1000, 2), height_mm=round(h / ppm_x * 1000, 2))
    return info
