"""The font atlas (sim/view/font.py) against Pillow drawing the same strings itself."""

import random

import numpy as np
import pytest
from PIL import Image, ImageDraw, ImageFont

from sim.view import font

STRINGS = [
    "Grasp the brain to start",
    "Condition A (2 of 3) - trial 1 of 3",
    "AVAWAY To",
    "Is interaction real and natural?",
    "Çà et là: naïve Ærø, ½ ± 3 °C, «ÿ» ¿ß?",
]
SIZES = [18, 24, 34]
MARGIN = 6


def _pillow(text: str, a: font.Atlas, features=None) -> tuple[np.ndarray, tuple[int, int]]:
    """Pillow's own drawing of `text` at size a.px, and the pen origin (x, baseline) it used."""
    width = int(ImageFont.truetype(str(font.FONT_PATH), a.px).getlength(text)) + 1
    canvas = Image.new("L", (width + 2 * MARGIN + a.px, a.ascent + a.descent + 2 * MARGIN))
    origin = (MARGIN, MARGIN + a.ascent)
    fnt = ImageFont.truetype(str(font.FONT_PATH), a.px)
    ImageDraw.Draw(canvas).text(origin, text, font=fnt, fill=255, anchor="ls", features=features)
    return np.asarray(canvas), origin


def _over(dst: np.ndarray, src: np.ndarray) -> np.ndarray:
    """Pillow's compositing of a glyph over what is under it (_imagingft.c: src + dst (255 - src) / 255)."""
    src, dst = src.astype(np.int32), dst.astype(np.int32)
    tmp = dst * (255 - src) + 128
    out = np.where(dst > 0, np.minimum(src + (((tmp >> 8) + tmp) >> 8), 255), src)
    return np.where(src > 0, out, dst).astype(np.uint8)


def _from_quads(text: str, a: font.Atlas, shape: tuple[int, int], origin: tuple[int, int]) -> np.ndarray:
    """Each quad's atlas bitmap pasted at its place, in order, as a GL renderer would blend them."""
    quads, _ = a.layout(text)
    height, width = a.image.shape
    out = np.zeros(shape, np.uint8)
    for x0, y0, x1, y1, s0, t0, s1, t1 in quads.astype(np.float64):
        cols, rows = np.array([s0, s1]) * width, np.array([t0, t1]) * height
        # integer texels and integer pixels, one texel per pixel: drawn 1:1 it is crisp
        assert np.allclose(cols, np.round(cols), atol=1e-3)
        assert np.allclose(rows, np.round(rows), atol=1e-3)
        assert (x0, y0, x1, y1) == tuple(map(round, (x0, y0, x1, y1)))
        c0, c1, r0, r1 = (int(round(v)) for v in (*cols, *rows))
        assert (c1 - c0, r1 - r0) == (x1 - x0, y1 - y0)
        place = np.s_[int(y0) + origin[1] : int(y1) + origin[1], int(x0) + origin[0] : int(x1) + origin[0]]
        out[place] = _over(out[place], a.image[r0:r1, c0:c1])
    return out


def _assert_same(text: str, a: font.Atlas, features=None, expected: str | None = None):
    reference, origin = _pillow(text if expected is None else expected, a, features)
    drawn = _from_quads(text, a, reference.shape, origin)
    differ = np.count_nonzero(drawn != reference)
    assert reference.any()
    assert differ == 0, f"{text!r} at {a.px} px: {differ} of {np.count_nonzero(reference)} ink pixels differ"


@pytest.mark.parametrize("px", SIZES)
@pytest.mark.parametrize("text", STRINGS)
def test_quads_redraw_what_pillow_draws(text, px):
    """Exact, kerning included (AV, AW, To overlap): Pillow places each glyph at its rounded pen
    position and composites overlaps "over" (as GL alpha blending does). Pasting with max()
    instead differs only where kerned glyphs overlap: 916 of 6.6 million ink pixels over random
    strings, up to 64 levels."""
    _assert_same(text, font.atlas(px))


def test_random_strings_of_every_character():
    rng = random.Random(7)
    for px in (11, 24):
        a = font.atlas(px)
        for _ in range(40):
            text = "".join(rng.choice(font.CHARS) for _ in range(rng.randint(1, 30)))
            _assert_same(text, a, features=a.features)


def test_no_ligatures():
    """DejaVu Sans joins ff, fi, fl; the atlas has single characters, so they stay apart, as Pillow
    draws them when told so."""
    a = font.atlas(24)
    _assert_same("difficult office: fluid, fine", a, features=a.features)
    if a.features is not None:  # with raqm, Pillow's default draws the ligature: not what we lay out
        default, origin = _pillow("fi", a)
        assert np.any(default != _from_quads("fi", a, default.shape, origin))


@pytest.mark.parametrize("px", SIZES)
def test_width_is_pillows_advance(px):
    a = font.atlas(px)
    fnt = ImageFont.truetype(str(font.FONT_PATH), px)
    for text in [*STRINGS, " ", "  x  "]:
        _, width = a.layout(text)
        assert width == pytest.approx(fnt.getlength(text), abs=1)


def test_unknown_characters_are_question_marks():
    a = font.atlas(24)
    for text, same in [("→", "?"), ("a\u4e2db", "a?b"), ("x\ny\t€", "x?y??")]:
        quads, width = a.layout(text)
        expected, expected_width = a.layout(same)
        np.testing.assert_array_equal(quads, expected)
        assert width == expected_width
    _assert_same("café → 中", a, expected="café ? ?")


def test_empty_and_blank():
    a = font.atlas(24)
    quads, width = a.layout("")
    assert quads.shape == (0, 8)
    assert quads.dtype == np.float32
    assert width == 0
    quads, width = a.layout("   \u00a0")
    assert len(quads) == 0
    assert width > 0
    assert a.ink("") == a.ink("   ") == (0, 0, 0, 0)


def test_ink_is_the_union_of_the_quads():
    a = font.atlas(24)
    x0, y0, x1, y1 = a.ink("Ty g")
    assert y0 < -a.px / 2 < 0 < y1 <= a.descent  # caps above the baseline (y down), g below it
    quads, width = a.layout("Ty g")
    assert (x0, y0, x1, y1) == (quads[:, 0].min(), quads[:, 1].min(), quads[:, 2].max(), quads[:, 3].max())
    assert x0 <= 0
    assert x1 == pytest.approx(width, abs=2)


@pytest.mark.parametrize("px", [4, 18, 24, 64, 400])
def test_atlas_packing(px):
    a = font.atlas(px)
    height, width = a.image.shape
    assert a.image.dtype == np.uint8
    assert width & (width - 1) == 0
    boxes = np.array([g.box for g in a.glyphs.values() if g.box[2]])
    assert len(boxes) > 180  # every printable character but the blanks has ink
    x, y, w, h = boxes.T
    assert (x >= 2).all()
    assert (y >= 2).all()
    assert (x + w <= width - 2).all()
    assert (y + h <= height - 2).all()
    # the gap between two boxes: the larger of the horizontal and the vertical one
    gap_x = np.maximum(x[:, None] - (x + w)[None, :], x[None, :] - (x + w)[:, None])
    gap_y = np.maximum(y[:, None] - (y + h)[None, :], y[None, :] - (y + h)[:, None])
    gap = np.maximum(gap_x, gap_y)
    np.fill_diagonal(gap, np.iinfo(gap.dtype).max)
    assert gap.min() >= 2
    # all the ink is inside the boxes, so the padding is empty
    inside = np.zeros(a.image.shape, bool)
    for bx, by, bw, bh in boxes:
        inside[by : by + bh, bx : bx + bw] = True
    assert not a.image[~inside].any()
    assert a.ascent > 0
    assert a.descent > 0
    assert a.line_height == round(1.2 * px)


def test_cached():
    assert font.atlas(24) is font.atlas(24) is font.atlas(np.int64(24))
    a = font.atlas(24)
    first = a.layout("Grasp the brain to start")
    assert a.layout("Grasp the brain to start") is first
    assert not first[0].flags.writeable
    assert not a.image.flags.writeable


@pytest.mark.parametrize("px", [3, 401, 0, -24])
def test_size_out_of_range(px):
    with pytest.raises(ValueError):
        font.atlas(px)


def test_size_must_be_an_integer():
    with pytest.raises(TypeError):
        font.atlas(24.5)
