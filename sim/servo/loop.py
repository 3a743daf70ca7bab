"""The servo tick: read devices, force from the contact state, safety, write, record.

A tick touches only precomputed contact state; grasping (which may take tens of ms) is
requested here and done by the visual step (`sim.run`). Safety rules for every force sent:
zero on NaN or infinity, zero while the model reports itself unstable or the loop is suspended
after missed deadlines, a linear ramp over `ramp_s` after a grasp, never above the device's
peak force. A device that raises, reports a fault, returns a non-finite position or jumps more
than `jump_m` in one tick gets zero force and loses its grasp. Every intervention is an event
with its time.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from sim.models.base import BUDGETS, Contact
from sim.servo.velocity import VelocityEstimate

NO_FORCE = (0.0, 0.0, 0.0)
FORCE_BUDGET_S = BUDGETS["force_us_p99"] * 1e-6
SLOW_CALLS_MIN = 3  # one slow call (a cold cache, a collection) is not a model's cost


def too_many_slow_calls(over: int, calls: int) -> bool:
    """Whether `over` of a run's `calls` past their budget say the model is slow: more than 1% of
    them (the budgets are 99th percentiles) and at least `SLOW_CALLS_MIN`."""
    return over > 0.01 * calls and over >= SLOW_CALLS_MIN


def wait_until(deadline: float, spin: float) -> None:
    """Sleep until `spin` seconds before `deadline` on perf_counter, then spin: sleep alone
    wakes up late by a fraction of a millisecond."""
    while True:
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            return
        if remaining > spin + 1e-4:
            time.sleep(remaining - spin)


@dataclass
class Event:
    t: float
    hand: int
    kind: str
    detail: str = ""


@dataclass
class Hand:
    """Mutable per-hand runtime state shared by the servo and visual steps.

    The servo writes `position`, `force`, `button` and `grasp_request`; the visual step writes
    `contact` and `contact_t`. Each field has a single writer, and rebinding an attribute is
    atomic in CPython, so the two threads need no lock.
    """

    index: int
    name: str
    device: object
    position: tuple = NO_FORCE
    force: tuple = NO_FORCE
    button: bool = False
    grasp_request: tuple | None = None
    contact: Contact | None = None
    contact_t: float = 0.0
    max_force: float = 0.0
    safety: str | None = None  # the safety rule acting on the last tick, if any
    fault: str | None = None  # the device fault of the last tick, if any
    ticks: int = 0
    reversals: list = field(default_factory=list)  # times the rendered force flipped direction (chatter monitor)
    mean_square: float = 0.0  # moving mean of |force|^2 over `budget_tau_s` (the continuous-force budget)
    over_budget: bool = False
    # the hand's velocity (m/s), estimated from the positions read, for a model that uses time
    # (`sim.servo.velocity`); the servo writes both, and only for such a model
    velocity: tuple = NO_FORCE
    estimate: VelocityEstimate = field(default_factory=VelocityEstimate)


def _not_a_force(f):
    raise ValueError(f"returned {len(f)} numbers; allowed: (fx, fy, fz), three floats in N")


def limit_force(force, peak: float) -> tuple[tuple[float, float, float], str | None]:
    """Clamp to `peak`; zero for non-finite input. Returns (force, event kind or None)."""
    fx, fy, fz = force
    mag = math.sqrt(fx * fx + fy * fy + fz * fz)
    if not math.isfinite(mag):
        return NO_FORCE, "nan_force"
    if mag > peak:
        s = peak / mag
        return (fx * s, fy * s, fz * s), "force_clamped"
    return (fx, fy, fz), None


class TickLog:
    """The per-tick rows of a run in preallocated float64 blocks, 8 bytes a column: a tuple of
    Python floats per tick would cost many times that over a long live run (docs/scenes.md)."""

    BLOCK = 8192

    def __init__(self) -> None:
        self._blocks: list[np.ndarray] = []
        self._n = 0  # rows in the last block
        self.width = 0

    def append(self, row) -> None:
        if not self._blocks or self._n == self.BLOCK:
            self.width = len(row)
            self._blocks.append(np.empty((self.BLOCK, self.width)))
            self._n = 0
        self._blocks[-1][self._n] = row
        self._n += 1

    def extend(self, rows: np.ndarray) -> None:
        """Rows (an array, one per tick) appended in order."""
        for row in rows:  # a block's copy of each: a few us for a frame's 33 rows
            self.append(row)

    def __len__(self) -> int:
        return (len(self._blocks) - 1) * self.BLOCK + self._n if self._blocks else 0

    def clear(self) -> None:
        self._blocks, self._n = [], 0

    def array(self) -> np.ndarray:
        if not self._blocks:
            return np.zeros((0, self.width))
        return np.concatenate(self._blocks[:-1] + [self._blocks[-1][: self._n]])


@dataclass
class ServoLoop:
    model: object
    hands: list[Hand]
    peak_force: float
    ramp_s: float = 0.05
    jump_m: float = 0.02  # a larger move in one tick (20 m/s) is a glitch, not a hand
    events: list[Event] = field(default_factory=list)
    rows: TickLog = field(default_factory=TickLog)  # (t, compute_s, io_s, then per hand px py pz fx fy fz button)
    suspended_until: float = -math.inf
    model_fault: bool = False  # the model raised in a force call (logged once)
    # a limit cycle: the force flips direction (both sides above 0.05 N) this many times within
    # the window; a contact stiffer than the device renders at this rate does this
    chatter_reversals: int = 10
    chatter_window_s: float = 0.05
    # the continuous-force budget: when the force's moving root-mean-square (time constant
    # budget_tau_s) passes the device's nominal continuous force, the force is held at that
    # force until the mean falls below 80% of it (the Omni: 0.88 N; motors heat with |F|^2)
    continuous_force: float = math.inf
    budget_tau_s: float = 5.0
    dt: float = 1e-3
    # the model's force calls against their budget (sim.models.api.BUDGETS, the 99th percentile):
    # counted here, judged once at the end of a run (`budget_line`), never one event a call
    force_calls: int = 0
    force_over: int = 0
    force_worst_s: float = 0.0
    timed: bool = False  # the model uses time: it is told the tick's time and the hands' velocities

    def __post_init__(self) -> None:
        self.timed = bool(self.model is not None and self.model.uses_time)

    @classmethod
    def for_devices(cls, model, hands: list[Hand], rate: float) -> ServoLoop:
        """The loop for `hands` (their devices opened): the devices' peak and continuous force
        limits, one tick of 1 / `rate` seconds."""
        specs = [h.device.spec for h in hands]
        return cls(model=model, hands=hands, peak_force=min(s.peak_force_n for s in specs),
                   continuous_force=min(s.continuous_force_n for s in specs), dt=1.0 / rate)

    def suspend(self, t: float, duration: float, reason: str) -> None:
        """Send zero force to every device until t + duration (e.g. after missed deadlines)."""
        if t >= self.suspended_until:
            self.events.append(Event(t, -1, reason))
        self.suspended_until = max(self.suspended_until, t + duration)

    def budget_line(self) -> str | None:
        """One line when more than 1% of this run's force calls, and at least `SLOW_CALLS_MIN`, took
        longer than the force budget (its 99th percentile), else None; the count starts again."""
        calls, over, worst = self.force_calls, self.force_over, self.force_worst_s
        self.force_calls, self.force_over, self.force_worst_s = 0, 0, 0.0
        if not too_many_slow_calls(over, calls):
            return None
        return (f"over_budget: force: {over} of {calls} calls took over {FORCE_BUDGET_S * 1e6:g} us (worst {worst * 1e6:.0f} us); "
                f"budget: {FORCE_BUDGET_S * 1e6:g} us at the 99th percentile (docs/models.md)")

    def restart(self, keep_last: bool) -> None:
        """A paced run's clock starts now (at the first grasp, or a start key): the waiting
        ticks are dropped and the tick just run (kept with `keep_last`: the grasp) becomes t = 0.
        Devices keep their own clock (`tick`'s `device_t`)."""
        last = self.rows.array()[-1].copy() if keep_last and len(self.rows) else None
        t_last = float(last[0]) if last is not None else math.nan
        self.rows.clear()
        self.events[:] = [Event(0.0, e.hand, e.kind, e.detail) for e in self.events if e.t == t_last]
        if last is not None:
            last[0] = 0.0
            self.rows.append(last)
        self.suspended_until = -math.inf
        self.force_calls, self.force_over, self.force_worst_s = 0, 0, 0.0
        for h in self.hands:
            h.reversals.clear()
            h.contact_t = 0.0
            # the velocity's window on the new clock: from the tick kept (t = 0), or empty
            h.estimate.reset()
            h.velocity = NO_FORCE
            if last is not None:
                h.estimate.update(0.0, h.position)

    def tick(self, t: float, device_t: float | None = None) -> None:
        """One tick at run time `t`; devices read at `device_t` (default `t`).

        Kept as one function on purpose: it is the 1 kHz hot loop, where every Python call spends
        some of a 1 ms budget shared with the device I/O (the cost: docs/scenes.md); its parts
        are marked below."""
        clock, isfinite = time.perf_counter, math.isfinite
        start = clock()
        row: list[float] = [t, 0.0, 0.0]
        hands = self.hands
        read_at = [start] * len(hands)
        # 1. read every device (so coupled contacts see the same instant)
        for i, h in enumerate(hands):
            fault = None
            try:
                state = h.device.read(t if device_t is None else device_t)
                read_at[i] = clock()
            except Exception as exc:  # a disconnected or failing device: zero force, never a crash
                state, fault = None, f"device_fault: {exc}"
            if state is not None and state.fault:
                fault = f"device_fault: {state.fault}"
            if state is not None and fault is None:
                p = state.position
                if not (isfinite(p[0]) and isfinite(p[1]) and isfinite(p[2])):
                    fault = "nan_position"
                else:
                    q = h.position
                    step = math.sqrt((p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2 + (p[2] - q[2]) ** 2)
                    if h.ticks > 0 and step > self.jump_m:
                        fault = "position_jump"
            h.ticks += 1
            if fault is not None:
                kind = fault.split(":")[0]
                if kind != h.fault:
                    self.events.append(Event(t, h.index, kind, fault))
                h.fault = kind
                # drop the grasp: after a fault the participant must grasp again
                h.contact, h.grasp_request = None, None
                if self.timed:  # a position after a fault is a new hand's: no velocity across it
                    h.estimate.reset()
                    h.velocity = NO_FORCE
                if state is not None and all(math.isfinite(c) for c in state.position):
                    h.position = state.position
                    h.button = state.button
                continue
            h.fault = None
            h.position = state.position
            if self.timed:
                h.velocity = h.estimate.update(t, state.position)
            if state.button and not h.button:
                h.grasp_request = state.position
                self.events.append(Event(t, h.index, "grasp_request"))
            elif not state.button and h.button:
                h.grasp_request = None
                h.contact = None
                self.events.append(Event(t, h.index, "release"))
            h.button = state.button
        # 2. forces from the precomputed contacts
        held = [h for h in hands if h.contact is not None]
        raw: list = []
        if held:
            contacts = [h.contact for h in held]
            disps = []
            for h, c in zip(held, contacts):
                p, a = h.position, c.point
                disps.append((p[0] - a[0], p[1] - a[1], p[2] - a[2]))
            try:
                f0 = clock()
                raw = self.model.forces(contacts, disps, velocities=[h.velocity for h in held], t=t) if self.timed \
                    else self._forces(contacts, disps)
                took = clock() - f0
                self.force_calls += 1
                if took > FORCE_BUDGET_S:
                    self.force_over += 1
                    if took > self.force_worst_s:
                        self.force_worst_s = took
                # what the loop below unpacks: three numbers per contact, else a fault here
                if len(raw) != len(held):
                    raise ValueError(f"{len(raw)} forces for {len(held)} contacts; allowed: one (fx, fy, fz) per contact")
                raw = [(float(f[0]), float(f[1]), float(f[2])) if len(f) == 3 else _not_a_force(f) for f in raw]
            except Exception as exc:  # a model that throws renders nothing: never a crash in the loop
                raw = [NO_FORCE] * len(held)
                if not self.model_fault:
                    self.events.append(Event(t, -1, "model_fault", f"model_fault: force: {exc}"))
                self.model_fault = True
        # 3. safety, write, record
        try:
            unstable = bool(self.model.unstable)
        except Exception as exc:  # a model that cannot say: as if unstable (zero force), logged once
            unstable = True
            if not self.model_fault:
                self.events.append(Event(t, -1, "model_fault", f"model_fault: unstable: {exc}"))
            self.model_fault = True
        suspended = t < self.suspended_until
        k = 0
        io = 0.0
        for i, h in enumerate(hands):
            force = NO_FORCE
            if k < len(held) and held[k] is h:
                fx, fy, fz = raw[k]
                k += 1
                ramp = (t - h.contact_t) / self.ramp_s
                if ramp < 1.0:
                    ramp = max(ramp, 0.0)
                    fx, fy, fz = fx * ramp, fy * ramp, fz * ramp
                force, kind = limit_force((fx, fy, fz), self.peak_force)
                force, kind = self._budget(h, force, kind)
                detail = ""
                if unstable:  # the model says its state blew up: render nothing
                    force, kind = NO_FORCE, "model_unstable"
                elif suspended:  # the loop missed its deadlines: render nothing for a while
                    force, kind = NO_FORCE, "suspended"
                # the monitor sees the force that would be sent, after every other rule
                elif self._chatter(h, t, force):  # a limit cycle: drop the grasp, zero force until grasped again
                    # the withheld force (exact reprs) completes the last reversal, which the
                    # recorded trace, holding the zero sent instead, cannot show
                    detail = (f"force_chatter: {self.chatter_reversals} reversals within {self.chatter_window_s * 1e3:g} ms; "
                              f"withheld force ({force[0]!r}, {force[1]!r}, {force[2]!r}) N")
                    force, kind = NO_FORCE, "force_chatter"
                    h.contact = None
                if kind is not None and kind != h.safety:  # log when a rule starts acting
                    self.events.append(Event(t, h.index, kind, detail))  # detail: set for chatter only
                h.safety = kind
            try:
                h.device.write_force(force)
            except Exception as exc:
                if h.fault != "device_fault":
                    self.events.append(Event(t, h.index, "device_fault", f"device_fault: {exc}"))
                h.fault = "device_fault"
                h.contact = None
                force = NO_FORCE
            io = max(io, clock() - read_at[i])  # device read to force out, this hand
            h.force = force
            m2 = force[0] ** 2 + force[1] ** 2 + force[2] ** 2
            self._heat(h, m2)
            mag = math.sqrt(m2)
            if mag > h.max_force:
                h.max_force = mag
            row.extend(h.position)
            row.extend(force)
            row.append(1.0 if h.button else 0.0)
        row[1] = clock() - start
        row[2] = io
        self.rows.append(row)

    def _budget(self, h: Hand, force, kind):
        """Hold the force at the continuous force while the hand is over its budget."""
        m2 = force[0] ** 2 + force[1] ** 2 + force[2] ** 2
        c = self.continuous_force
        if h.over_budget and m2 > c * c:
            s = c / math.sqrt(m2)
            return (force[0] * s, force[1] * s, force[2] * s), "force_budget"
        return force, kind

    def _heat(self, h: Hand, m2: float) -> None:
        """The moving mean of |F|^2 (motors heat with it, and cool when the force drops)."""
        c2 = self.continuous_force ** 2
        h.mean_square += (m2 - h.mean_square) * self.dt / self.budget_tau_s
        if not h.over_budget and h.mean_square > c2:
            h.over_budget = True
        elif h.over_budget and h.mean_square < 0.64 * c2:
            h.over_budget = False

    def _chatter(self, h: Hand, t: float, force) -> bool:
        """The chatter monitor: True on the tick whose force completes `chatter_reversals`
        reversals within `chatter_window_s` (ends included). A reversal: this force and the
        last one sent point apart (negative dot product), both above 0.05 N."""
        p = h.force
        # products summed in this order (analysis.verification.stability.peak_reversals repeats it on a trace)
        if p[0] * force[0] + p[1] * force[1] + p[2] * force[2] < 0.0 and \
                p[0] * p[0] + p[1] * p[1] + p[2] * p[2] > 0.0025 and force[0] * force[0] + force[1] * force[1] + force[2] * force[2] > 0.0025:
            r = h.reversals
            r.append(t)
            while r and r[0] < t - self.chatter_window_s:
                r.pop(0)
            if len(r) >= self.chatter_reversals:
                r.clear()
                return True
        return False

    def _forces(self, contacts, disps):
        return self.model.forces(contacts, disps)
