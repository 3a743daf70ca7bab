"""The participant view's on-screen text: where each slot goes, how large, and how it wraps,
for a view of any size (sizes are given for a 720-pixel-high view and scale with its height)."""

from __future__ import annotations

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
    from sim.font import atlas

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
    from sim.font import atlas

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
