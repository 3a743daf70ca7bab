"""The hand's velocity as the servo estimates it from the positions it reads.

CHAI3D's estimate (`cGenericHapticDevice::estimateLinearVelocity`, CHAI3D 3.0): the position
now minus the oldest position read within the last `WINDOW_S` (15 ms, CHAI3D's default), over
the time between them. CHAI3D keeps the positions strictly younger than the window (a 14 ms span
at 1 kHz) and its last estimate until a second position is read; this keeps the 15 ms span, and
gives zero until then. A PHANTOM Omni reports its position in steps of about 55 um (its
encoders' resolution at the tip), so a difference over one 1 ms tick is 0 or about 55 mm/s;
over the 15 ms window the estimate moves in steps of 55 um / 15 ms = 3.7 mm/s, and it follows
a change of speed with a delay of half the window (7.5 ms).
"""

from __future__ import annotations

from collections import deque

WINDOW_S = 0.015
CLOCK_SLACK_S = 1e-9  # a tick's time is a float sum: 15 ms apart may read 15.000000001 ms


class VelocityEstimate:
    """The windowed estimate of one hand's velocity (m/s), updated every tick."""

    __slots__ = ("window", "_times", "_points")

    def __init__(self, window: float = WINDOW_S) -> None:
        if not window > 0:
            raise ValueError(f"window: {window!r} is out of range; allowed: > 0 s")
        self.window = float(window)
        self._times: deque = deque()
        self._points: deque = deque()

    def reset(self) -> None:
        """Forget the positions read (after a device fault, or when the run's clock starts again)."""
        self._times.clear()
        self._points.clear()

    def update(self, t: float, position) -> tuple[float, float, float]:
        """Add the position read at `t` (s) and return the velocity estimate: zero until a second
        position is read. A `t` not after the last one is a clock that started again (a paced
        run's first grasp, the time between runs): the window starts again from this position."""
        times, points = self._times, self._points
        if times and t <= times[-1]:
            times.clear()
            points.clear()
        times.append(t)
        points.append(position)
        while t - times[0] > self.window + CLOCK_SLACK_S:
            times.popleft()
            points.popleft()
        dt = t - times[0]
        if dt <= 0.0:
            return (0.0, 0.0, 0.0)
        p0 = points[0]
        return ((position[0] - p0[0]) / dt, (position[1] - p0[1]) / dt, (position[2] - p0[2]) / dt)
