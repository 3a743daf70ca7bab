"""A font atlas: crisp text for an OpenGL view at any size, from NumPy and Pillow alone.

Text is drawn as textured quads, one per glyph, sampling a single-channel coverage image (the
atlas). Scaling one bitmap to every size would blur small text and block large text, so there is
one atlas per integer pixel size, each glyph rasterised (and hinted) by FreeType at that size.
Glyphs sit on integer pixels, both in the atlas and on screen, so a line drawn 1:1 at an integer
position is pixel for pixel what Pillow draws for the same string: the pen positions are Pillow's
own (HarfBuzz shaping, kerning included), rounded as Pillow rounds them. Ligatures are switched
off (DejaVu Sans joins ff, fi, fl): an atlas of single characters has no glyph for them.

The font is DejaVu Sans as shipped inside matplotlib; the characters are printable ASCII and
printable Latin-1, anything else is laid out as "?". The GL side uploads `Atlas.image` with row 0
at t = 0 and draws what `Atlas.layout` returns.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from types import MappingProxyType

import matplotlib
import numpy as np
from PIL import Image, ImageDraw, ImageFont

FONT_PATH = Path(matplotlib.get_data_path()) / "fonts/ttf/DejaVuSans.ttf"
PX_MIN, PX_MAX = 4, 400
CHARS = "".join(map(chr, [*range(32, 127), *range(160, 256)]))
FALLBACK = "?"
PAD = 2  # empty pixels around every glyph box: drawn texel for texel now, and linear sampling at another scale would not reach a neighbour's ink
LINE_SPACING = 1.2  # line height over the em size


@dataclass(frozen=True)
class Glyph:
    """One character: where its ink lies in the atlas, and where it goes relative to the pen."""

    box: tuple[int, int, int, int]  # column, row, width, height of the ink in the atlas (0, 0, 0, 0: no ink)
    offset: tuple[int, int]  # the box's top-left from the pen on the baseline (x right, y down)
    advance: float  # pixels, as Pillow lays this character out alone


@dataclass(frozen=True, eq=False)  # eq=False: hashed by identity, so layouts can be cached per atlas
class Atlas:
    """The glyphs of one pixel size in one image, and how to lay a line of text out over them."""

    px: int
    image: np.ndarray  # (H, W) uint8 coverage, row 0 = top, W a power of two
    ascent: int
    descent: int
    line_height: int  # 1.2 px, rounded
    glyphs: Mapping[str, Glyph]
    font: ImageFont.FreeTypeFont
    features: tuple[str, ...] | None  # Pillow's `features` for the same layout: no ligatures (None without raqm)

    def layout(self, text: str) -> tuple[np.ndarray, float]:
        """One line: (quads (n, 8) float32 x0 y0 x1 y1 s0 t0 s1 t1, advance width in pixels).

        x0..y1 are pixels from the pen origin (on the baseline at the start of the line, y down);
        s, t are in 0..1 with t = 0 at the image's top row. Characters without ink give no quad.
        The array is cached and read-only.
        """
        return _layout(self, text)

    def ink(self, text: str) -> tuple[float, float, float, float]:
        """The ink's extent (x0, y0, x1, y1) from the pen origin; (0, 0, 0, 0) when there is none."""
        quads, _ = self.layout(text)
        if not len(quads):
            return (0.0, 0.0, 0.0, 0.0)
        return (
            float(quads[:, 0].min()),
            float(quads[:, 1].min()),
            float(quads[:, 2].max()),
            float(quads[:, 3].max()),
        )


def atlas(px: int) -> Atlas:
    """The atlas for font size `px` (the em size in pixels, 4..400), built once per size."""
    px = operator.index(px)  # a float size would not be an atlas size: TypeError
    if not PX_MIN <= px <= PX_MAX:
        raise ValueError(f"font size {px} px is outside {PX_MIN}..{PX_MAX}")
    return _atlas(px)


def printable(text: str) -> str:
    """`text` with every character the atlas lacks replaced by "?"."""
    return "".join(c if c in _CHARSET else FALLBACK for c in text)


_CHARSET = frozenset(CHARS)


@lru_cache(maxsize=32)
def _atlas(px: int) -> Atlas:
    font = ImageFont.truetype(str(FONT_PATH), px)
    bitmaps = {c: _rasterise(font, c) for c in CHARS}
    (height, width), places = _pack({c: bm.shape for c, (bm, _) in bitmaps.items()})
    image = np.zeros((height, width), np.uint8)
    glyphs = {}
    for c, (bm, offset) in bitmaps.items():
        h, w = bm.shape
        col, row = places.get(c, (0, 0))
        image[row : row + h, col : col + w] = bm
        glyphs[c] = Glyph((col, row, w, h) if c in places else (0, 0, 0, 0), offset, font.getlength(c))
    image.flags.writeable = False
    ascent, descent = font.getmetrics()
    # without raqm Pillow neither shapes ligatures nor accepts `features`
    features = ("-liga",) if font.layout_engine == ImageFont.Layout.RAQM else None
    return Atlas(px, image, ascent, descent, round(LINE_SPACING * px), MappingProxyType(glyphs), font, features)


def _rasterise(font: ImageFont.FreeTypeFont, char: str) -> tuple[np.ndarray, tuple[int, int]]:
    """The glyph's coverage trimmed to its ink, and the ink's top-left from the pen (x right, y down).

    Drawn by Pillow at an integer pen position, so the bitmap is exactly the one Pillow pastes
    when it draws this character inside a string (it renders each glyph at a whole pixel).
    """
    x0, y0, x1, y1 = font.getbbox(char, anchor="ls")
    margin = 2  # in case FreeType's ink reaches past the box Pillow reports
    canvas = Image.new("L", (x1 - x0 + 2 * margin, y1 - y0 + 2 * margin))
    pen = (margin - x0, margin - y0)
    ImageDraw.Draw(canvas).text(pen, char, font=font, fill=255, anchor="ls")
    cover = np.asarray(canvas)
    rows, cols = np.flatnonzero(cover.any(axis=1)), np.flatnonzero(cover.any(axis=0))
    if not len(rows):
        return np.zeros((0, 0), np.uint8), (0, 0)
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    return cover[r0:r1, c0:c1].copy(), (int(c0 - pen[0]), int(r0 - pen[1]))


def _pack(shapes: dict[str, tuple[int, int]]) -> tuple[tuple[int, int], dict[str, tuple[int, int]]]:
    """Shelf packing, tallest first: ((height, width) of the image, {char: (column, row)}) of the inked glyphs.

    Each box gets PAD empty pixels on every side (2 * PAD between neighbours). The width is the
    smallest power of two at least the side of a square of the same area (and the widest glyph),
    so the image stays near square and within GL's texture size limit up to 400 px.
    """
    inked = {c: (h, w) for c, (h, w) in shapes.items() if h and w}
    area = sum((h + 2 * PAD) * (w + 2 * PAD) for h, w in inked.values())
    widest = max((w + 2 * PAD for _, w in inked.values()), default=1)
    width = 1 << math.ceil(math.log2(max(math.sqrt(area), widest, 64)))
    places: dict[str, tuple[int, int]] = {}
    col = row = shelf = 0
    for c in sorted(inked, key=lambda c: (-inked[c][0], c)):
        h, w = inked[c]
        if col + w + 2 * PAD > width:  # next shelf
            col, row, shelf = 0, row + shelf, 0
        places[c] = (col + PAD, row + PAD)
        col += w + 2 * PAD
        shelf = max(shelf, h + 2 * PAD)
    return (max(row + shelf, 1), width), places


@lru_cache(maxsize=256)
def _layout(atlas: Atlas, text: str) -> tuple[np.ndarray, float]:
    text = printable(text)
    height, width = atlas.image.shape
    quads = []
    for pen, c in zip(_pens(atlas, text), text):
        glyph = atlas.glyphs[c]
        col, row, w, h = glyph.box
        if not w:
            continue
        x0, y0 = pen + glyph.offset[0], glyph.offset[1]
        quads.append((x0, y0, x0 + w, y0 + h, col / width, row / height, (col + w) / width, (row + h) / height))
    out = np.array(quads, np.float32).reshape(-1, 8)
    out.flags.writeable = False  # shared by every caller of the cache
    return out, atlas.font.getlength(text, features=atlas.features)


def _pens(atlas: Atlas, text: str) -> list[int]:
    """Each character's pen x in whole pixels, as Pillow places it when drawing `text`.

    Shaping puts the kerning of a pair into the first glyph's advance, so the pen of character i
    is the length of text[:i + 1] less character i's own advance (getlength(text[:i]) would miss
    the kerning between i - 1 and i). Pillow rounds the 26.6 pen half up to a pixel.
    """

    def length(s: str) -> float:
        return atlas.font.getlength(s, features=atlas.features)

    return [math.floor(length(text[: i + 1]) - atlas.glyphs[c].advance + 0.5) for i, c in enumerate(text)]
