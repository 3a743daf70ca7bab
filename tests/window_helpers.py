"""What the window tests share: xdotool on the participant view's real X window (Xvfb), a recorder of its texts and screenshots, pixel counts."""

import os
import subprocess
import threading
import time
from pathlib import Path

import numpy as np

PATCH = np.array([0.20, 0.55, 0.95]) * 255  # the grasped patch's colour in a screenshot


def run_xdotool(*args):
    """Run `xdotool ARGS` (X key and mouse events, window search); the completed process."""
    return subprocess.run(["xdotool", *map(str, args)], capture_output=True, text=True, timeout=10)


def window():
    """The participant view's X window id, or None while it is not shown."""
    out = run_xdotool("search", "--name", "Brain surgery simulator").stdout.split()
    return out[0] if out else None


class Recorder:
    """Wraps the view: every text it shows, and a screenshot at each change of its main message.
    A watchdog closes the views after `limit_s`, so a lost X event fails the test, never hangs it."""

    def __init__(self, monkeypatch, limit_s: float = 150.0):
        from sim.view.window import ParticipantView

        self.texts, self.shots, self.views = [], [], []
        rec = self

        def watchdog():
            time.sleep(limit_s)
            for v in rec.views:
                v.closed = True  # paced runs stop, the window questionnaire raises

        threading.Thread(target=watchdog, daemon=True).start()
        set_text, draw, idle = ParticipantView.set_text, ParticipantView.draw, ParticipantView.idle

        def set_text_spy(view, **slots):
            set_text(view, **slots)
            rec.texts.extend(t for t in slots.values() if t)

        def shoot(view, hands, displacement):
            text = view.text()
            key = (text.get("center", "") or text.get("question", ""), text.get("top", ""))
            if not rec.shots or rec.shots[-1][0] != key:
                rec.shots.append((key, view.image(), [h.position for h in hands], [h.grasped_vertex for h in hands], displacement))
                if os.environ.get("BRAINSIM_SHOTS"):  # keep them to look at (docs/img comes from here)
                    view.screenshot(Path(os.environ["BRAINSIM_SHOTS"]) / f"shot_{len(rec.shots):03d}.png")

        def draw_spy(view, displacement, hands, read_t=None, latch=None):
            draw(view, displacement, hands, read_t, latch=latch)
            if view not in rec.views:
                rec.views.append(view)
            rec.hands = view._last_hands  # as drawn: late-latched
            shoot(view, rec.hands, displacement)

        def idle_spy(view):
            idle(view)
            shoot(view, getattr(rec, "hands", []), None)

        monkeypatch.setattr(ParticipantView, "idle", idle_spy)

        monkeypatch.setattr(ParticipantView, "set_text", set_text_spy)
        monkeypatch.setattr(ParticipantView, "draw", draw_spy)


def brain_pixels(img):
    """Pixels of a screenshot that are not the white background (the brain and what is drawn on it)."""
    return int(np.sum(np.all(img < 245, axis=2)))


def patch_pixels(img):
    """Pixels of a screenshot in the grasped patch's colour."""
    return int(np.sum(np.linalg.norm(img.astype(float) - PATCH, axis=2) < 60))
