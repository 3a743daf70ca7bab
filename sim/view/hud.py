"""The participant view's on-screen text: where each slot goes, how large, and how it wraps,
for a view of any size (sizes are given for a 720-pixel-high view and scale with its height)."""

from __future__ import annotations

from sim.view.font import atlas

TEXT = (0.05, 0.05, 0.12)
ACCENT = (0.70, 0.10, 0.05)
ARROW = (0.85, 0.15, 0.10)  # the force: its arrow and its numbers
DESIGN_HEIGHT = 720.0
# x, y (pixels of a 1280x720 view; a fraction of the width where 0 < x < 1; from the right or
# bottom edge where negative), size, colour, alignment, and whether further lines go down from
# the first (else up from the last)
SLOTS = {
    "top": (24, 34, 22, TEXT, "left", True),  # the status line
    "center": (0.5, 92, 34, ACCENT, "center", True),  # the main message, large
    "question": (0.5, 92, 24, TEXT, "center", True),  # a question of the questionnaire
    "bottom": (0.5, -30, 20, TEXT, "center", False),  # instructions
    "corner": (-24, -62, 18, ARROW, "right", False),  # the forces
    "notice": (24, -62, 18, ACCENT, "left", False),  # the devices' notices
}
MARGIN = 24.0  # pixels a side that wrapped text keeps free


def size(slot: str, ui: float) -> int:
    """The pixel size of a slot's text in a view `ui` times 720 pixels high."""
    return max(4, round(SLOTS[slot][2] * ui))


def wrap(text: str, px: int, room: float) -> str:
    """`text` broken into lines at spaces so each is at most `room` pixels wide at size `px`."""
    a = atlas(px)
    lines = []
    for paragraph in text.split("\n"):
        line = ""
        for word in paragraph.split(" "):
            trial = f"{line} {word}" if line else word
            if line and a.layout(trial)[1] > room:
                lines.append(line)
                line = word
            else:
                line = trial
        lines.append(line)
    return "\n".join(lines)


def items(texts: dict[str, str], width: int, height: int) -> list[tuple]:
    """Each slot's text as drawn in a width x height view: (text wrapped to the width, x,
    baseline y, pixel size, rgb, align)."""
    ui = height / DESIGN_HEIGHT
    out = []
    for slot, text in texts.items():
        if not text:
            continue
        x, y, _, colour, align, down = SLOTS[slot]
        px = size(slot, ui)
        text = wrap(text, px, width - 2 * MARGIN * ui)
        x = width * x if 0 < x < 1 else (x * ui if x >= 0 else width + x * ui)
        y = y * ui if y >= 0 else height + y * ui
        if not down:
            y -= text.count("\n") * atlas(px).line_height
        out.append((text, x, y, px, colour, align))
    return out


# -- the hands' targets: a progress bar per hand ---------------------------------------------
# pixels of a 720-pixel-high view: each bar under the status line, the left hand's at the
# left edge, the right hand's at the right edge; a bar fills outwards, the way its hand pulls
BAR = {"margin": 24, "width": 300, "top": 78, "height": 16, "label": 68, "warning": 116, "label_px": 16}
BAR_RANGE = 1.3  # the bar's far end, in target distances: an overshoot shows
TARGET_AWAY = (0.92, 0.16, 0.72)  # magenta: nothing else on the screen has it
TARGET_ON = (0.12, 0.78, 0.22)  # green: within the tolerance
TARGET_HELD = (1.0, 0.74, 0.0)  # gold: held for the hold time
TRACK = (0.86, 0.86, 0.89, 1.0)
BAND = (0.70, 0.92, 0.70, 1.0)
OUTLINE = (0.30, 0.30, 0.35, 1.0)
WARNING = (0.86, 0.05, 0.05)
PANEL = (1.0, 1.0, 1.0, 0.82)  # behind a bar over the brain (the view's text backing)


def bar_rect(side: float, width: int, ui: float) -> tuple[float, float, float, float]:
    """The bar of the hand on `side` (< 0: left, else right) in a view `width` pixels wide."""
    m, w = BAR["margin"] * ui, BAR["width"] * ui
    x0 = m if side < 0 else width - m - w
    return x0, BAR["top"] * ui, x0 + w, (BAR["top"] + BAR["height"]) * ui


def _span(rect, side: float, a: float, b: float) -> tuple[float, float]:
    """Pixels x of progress a..b (0..BAR_RANGE) along a bar that fills outwards."""
    x0, _, x1, _ = rect
    f = (x1 - x0) / BAR_RANGE
    return (x1 - b * f, x1 - a * f) if side < 0 else (x0 + a * f, x0 + b * f)


def target_bars(bars: list[tuple], width: int, ui: float) -> list[tuple]:
    """The bars' rectangles (x0, y0, x1, y1, rgba), for `bars` of (side, progress, band: (low,
    high) in target distances or None, on_target, held, over_limit)."""
    quads = []
    for side, progress, band, on_target, _held, over in bars:
        r = bar_rect(side, width, ui)
        x0, y0, x1, y1 = r
        pad, line = 6 * ui, max(1.0, round((3 if over else 1.5) * ui))
        quads.append((x0 - pad, y0 - pad, x1 + pad, y1 + pad, PANEL))
        quads.append((x0 - line, y0 - line, x1 + line, y1 + line, (*WARNING, 1.0) if over else OUTLINE))
        quads.append((*r, TRACK))
        if band is not None:
            a, b = _span(r, side, max(band[0], 0.0), min(band[1], BAR_RANGE))
            quads.append((a, y0, b, y1, BAND))
        p = min(max(float(progress), 0.0), BAR_RANGE) if progress == progress else 0.0
        if p > 0.0:
            a, b = _span(r, side, 0.0, p)
            colour = TARGET_ON if on_target else TARGET_AWAY
            quads.append((a, y0 + 2 * ui, b, y1 - 2 * ui, (*colour, 1.0)))
        a, b = _span(r, side, 1.0, 1.0)  # the target itself: a mark across the bar
        quads.append((a - max(1.0, ui), y0 - 4 * ui, a + max(1.0, ui), y1 + 4 * ui, (*TEXT, 1.0)))
    return quads


def target_labels(bars: list[tuple], names: list[str], width: int, ui: float) -> list[tuple]:
    """The bars' text items: the hand's name at its outer end, "held" at its inner end once held,
    and a warning under it while the force is above the safe limit."""
    px = max(4, round(BAR["label_px"] * ui))
    out = []
    for (side, _, _, _, held, over), name in zip(bars, names):
        x0, _, x1, _ = bar_rect(side, width, ui)
        outer, inner = (x0, x1) if side < 0 else (x1, x0)
        out.append((f"{name} target", outer, BAR["label"] * ui, px, TEXT, "left" if side < 0 else "right"))
        if held:
            out.append(("held", inner, BAR["label"] * ui, px, tuple(c * 0.7 for c in TARGET_ON), "right" if side < 0 else "left"))
        if over:
            out.append(("Force above safe limit", outer, BAR["warning"] * ui, px, WARNING, "left" if side < 0 else "right"))
    return out
