"""The questionnaire's widgets in the participant view: a rating scale (boxes side by side: a
rating's points, or blind condition labels) and a visual analogue scale (a line from 0 to 100
and a mark), laid out for a view's size and drawn as flat rectangles and text; `WidgetPanel` holds the one
a question shows and turns keys and clicks into choices (the view, sim/view/window.py, owns one)."""

from __future__ import annotations

from dataclasses import dataclass, field

from sim.view.font import atlas
from sim.view.hud import TEXT

PANEL = (0.96, 0.96, 0.97)  # behind a widget
BOX = (0.86, 0.89, 0.94)  # a point of a scale
BORDER = (0.35, 0.38, 0.45)
SELECTED = (0.12, 0.40, 0.85)  # the chosen point, the slider's mark
WHITE = (1.0, 1.0, 1.0)


@dataclass
class Widget:
    """A `scale` or a `slider` (0..100). Geometry in window pixels (x right, y down), as the
    mouse reports them; laid out again when the window resizes (`place`)."""

    kind: str  # "scale" or "slider"
    labels: tuple[str, ...] = ()
    anchors: tuple[str, str] | None = None
    selected: int | None = None  # scale: index of the chosen box (None: none yet)
    value: float | None = None  # slider: the mark, 0..100 (None: not set yet; there is no default)
    confirmed: bool = False  # scale: the chosen box was clicked again
    boxes: list = field(default_factory=list)  # scale: (u0, v0, u1, v1) of each label's box
    line: tuple = ()  # slider: (u0, u1, v), the line from 0 to 100
    dragging: bool = False

    def value_at(self, u: float) -> float:
        """The slider's value at pixel column u (0 at the left end, 100 at the right, 0.1 steps)."""
        u0, u1, _ = self.line
        return round(min(max((u - u0) / (u1 - u0), 0.0), 1.0) * 100.0, 1)


def place(w: Widget, width: int, height: int, ui: float) -> None:
    """The boxes or the line, centred in a width x height view (`ui`: its height over 720).
    With anchors a scale spans 55% of the width, so its ends stay where they are whatever the
    number of points."""
    cx, vc = width / 2.0, height / 2.0
    span = round(0.55 * width)
    if w.kind == "scale":
        n = len(w.labels)
        if w.anchors:
            b = min(56.0 * ui, span / (n + 0.25 * (n - 1)))
        else:
            b = 72.0 * ui
            span = n * b + (n - 1) * 0.75 * b
        gap = (span - n * b) / (n - 1) if n > 1 else 0.0
        left = cx - span / 2.0
        w.boxes = [(round(left + k * (b + gap)), round(vc - b / 2), round(left + k * (b + gap) + b), round(vc + b / 2)) for k in range(n)]
    else:
        u0 = round(cx - span / 2.0)
        w.line = (u0, u0 + span, round(vc))


def press(w: Widget, x: float, y: float, ui: float):
    """A click at (x, y): the box it hits (a second click on the chosen box confirms it), or the
    slider's value under it (and a drag begins); None when it misses."""
    if w.kind == "scale":
        for k, (u0, v0, u1, v1) in enumerate(w.boxes):
            if u0 - 4 <= x <= u1 + 4 and v0 - 4 <= y <= v1 + 4:
                if w.selected == k:
                    w.confirmed = True
                return k
        return None
    u0, u1, v = w.line
    if u0 - 20 * ui <= x <= u1 + 20 * ui and abs(y - v) <= 30 * ui:
        w.dragging = True
        return w.value_at(x)
    return None


def shapes(w: Widget, ui: float) -> tuple[list, list]:
    """(rectangles (x0, y0, x1, y1, rgba), texts (text, x, baseline y, pixel size, rgb, align))
    of the widget as it is: a panel, the boxes or the line, the mark, labels and anchors."""
    quads, texts = [], []
    anchor_px = max(4, round(18 * ui))
    if w.kind == "scale":
        first, last = w.boxes[0], w.boxes[-1]
        b = first[2] - first[0]
        bottom = first[3] + (58 if w.anchors else 26) * ui
        quads.append((first[0] - 48 * ui, first[1] - 34 * ui, last[2] + 48 * ui, bottom, (*PANEL, 1.0)))
        for k, (u0, v0, u1, v1) in enumerate(w.boxes):
            chosen = k == w.selected
            quads.append((u0 - 2 * ui, v0 - 2 * ui, u1 + 2 * ui, v1 + 2 * ui, (*(SELECTED if chosen else BORDER), 1.0)))
            quads.append((u0, v0, u1, v1, (*(SELECTED if chosen else BOX), 1.0)))
            px = fit_px(w.labels[k], 0.5 * b if len(w.labels[k]) <= 2 else 0.3 * b, b - 6 * ui)
            texts.append((w.labels[k], (u0 + u1) / 2, (v0 + v1) / 2 + 0.36 * px, px, WHITE if chosen else TEXT, "middle"))
        ends = (first[0], last[2], first[3] + 34 * ui, (last[2] - first[0]) / 2 - 12 * ui)
    else:
        u0, u1, v = w.line
        quads.append((u0 - 56 * ui, v - 76 * ui, u1 + 56 * ui, v + 64 * ui, (*PANEL, 1.0)))
        quads.append((u0, v - 2 * ui, u1, v + 2 * ui, (*BORDER, 1.0)))
        for u in (u0, u1):
            quads.append((u - 2 * ui, v - 14 * ui, u + 2 * ui, v + 14 * ui, (*BORDER, 1.0)))
        if w.value is not None:
            u = u0 + (u1 - u0) * w.value / 100.0
            quads.append((u - 3 * ui, v - 22 * ui, u + 3 * ui, v + 22 * ui, (*SELECTED, 1.0)))
            texts.append((f"{w.value:g}", u, v - 32 * ui, max(4, round(24 * ui)), SELECTED, "middle"))
        ends = (u0, u1, v + 44 * ui, (u1 - u0) / 2 - 12 * ui)
    if w.anchors:  # under the two ends, each at most half the span wide
        left, right, y, half = ends
        texts.append((w.anchors[0], left, y, fit_px(w.anchors[0], anchor_px, half), TEXT, "left"))
        texts.append((w.anchors[1], right, y, fit_px(w.anchors[1], anchor_px, half), TEXT, "right"))
    return quads, texts


def fit_px(text: str, px: float, max_width: float) -> int:
    """A pixel size at most `px` at which `text` is at most `max_width` wide."""
    px = max(4, round(px))
    width = atlas(px).layout(text)[1]
    return max(4, int(px * max_width / width)) if width > max_width else px


class WidgetPanel:
    """The widget a question shows in the view (at most one), its shapes and texts in pixels,
    and the choices keys and clicks make on it. `changed` is called whenever its drawing changes."""

    def __init__(self, changed) -> None:
        self.widget: Widget | None = None
        self.quads: list = []
        self.texts: list = []
        self._changed = changed
        self._view = (1, 1, 1.0)  # the view's width, height and text scale, where it lays out

    def show_scale(self, labels, anchors: tuple[str, str] | None = None) -> Widget:
        """Boxes side by side, one per label (a rating's points "1".."n", or blind labels), the
        anchors under the two ends; nothing chosen yet. With anchors the scale spans 55% of the
        width, so its ends stay where they are whatever the number of points."""
        self.widget = Widget("scale", labels=tuple(str(x) for x in labels), anchors=tuple(anchors) if anchors else None)
        self.layout(*self._view)
        return self.widget

    def show_slider(self, anchors: tuple[str, str] | None = None) -> Widget:
        """A visual analogue scale: a horizontal line (55% of the width) from 0 to 100 with the
        anchors under its ends, and no mark until the person sets one."""
        self.widget = Widget("slider", anchors=tuple(anchors) if anchors else None)
        self.layout(*self._view)
        return self.widget

    def clear(self) -> None:
        self.widget = None
        self.layout(*self._view)

    def select(self, index: int | None) -> None:
        """Choose a box of the scale (None: none)."""
        w = self.widget
        if w is not None and w.kind == "scale" and index != w.selected:
            w.selected = None if index is None else min(max(int(index), 0), len(w.labels) - 1)
            self._build()

    def set_value(self, value: float | None) -> None:
        """Set (or with None, take away) the slider's mark."""
        w = self.widget
        if w is not None and w.kind == "slider":
            value = None if value is None else round(min(max(float(value), 0.0), 100.0), 1)
            if value != w.value:
                w.value = value
                self._build()

    def move(self, step: int) -> None:
        """An arrow key: the scale's choice moves by `step` boxes (with none chosen yet, right
        chooses the first and left the last); the slider's mark moves by `step` (none set: nothing)."""
        w = self.widget
        if w is None:
            return
        if w.kind == "scale":
            if w.selected is None:
                self.select(0 if step > 0 else len(w.labels) - 1)
            else:
                self.select(w.selected + step)
        elif w.value is not None:
            self.set_value(w.value + step)

    def press(self, x: float, y: float) -> None:
        """A click at window pixel (x, y): the box or the slider's value under it."""
        hit = press(self.widget, x, y, self._view[2])
        if self.widget.kind == "scale" and hit is not None:
            self.select(hit)
        elif hit is not None:
            self.set_value(hit)

    def resize(self, width: int, height: int, ui: float) -> None:
        """The view's size changed: remembered, and the widget shown laid out again."""
        self._view = (width, height, ui)
        if self.widget is not None:
            self.layout(width, height, ui)

    def layout(self, width: int, height: int, ui: float) -> None:
        """Where the widget's boxes or line are in a view of this size."""
        self._view = (width, height, ui)
        if self.widget is not None:
            place(self.widget, width, height, ui)
        self._build()

    def _build(self) -> None:
        self._changed()
        self.quads, self.texts = shapes(self.widget, self._view[2]) if self.widget is not None else ([], [])
