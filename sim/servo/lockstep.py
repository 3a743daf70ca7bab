"""The lockstep servo's quiet ticks, compiled (numba).

A synthetic study spends most of its servo time in Python: 3000 ticks a 3 s pull, each reading
two simulated Omnis (the operator's hand dynamics), evaluating two force laws and the safety
rules (the cost: docs/scenes.md). Most ticks are quiet: no button changes, no fault, no safety rule
acts, nothing is logged. `CompiledTicks` runs those in one compiled loop with the arithmetic of
`ServoLoop.tick`, `SimulatedOmni.read`/`write_force`, `PullScript.target` and the laws
(`sim/laws.py`) written out in the same order, so the trace is the same to the bit (Python's `x ** 2` and `t ** 3` are the C library's pow, which
is not always `x * x`: the kernel calls pow with the exponent as a value it cannot fold; tested
against the Python tick on the shipped scenes and on random scripts). The first tick that would
do anything else (an event, a rule acting, a reversal of the force) is left undone and the
Python tick runs it. Runs that this cannot mirror (another device, a law it does not know, a
scripted glitch, a model that is not law-driven now) run every tick in Python.
"""

from __future__ import annotations

import math
import time

import numba
import numpy as np

import sim.devices.simulated as simulated
import sim.servo.loop
from sim.devices.simulated import PullScript, SimulatedOmni
from sim.laws import Coupling, Linearised, RadialTable, TensorTable, Zero
from sim.models.api import servo_laws
from sim.servo.loop import ServoLoop, limit_force

# law kinds
NONE, RADIAL, TENSOR, LINEARISED, COUPLING, ZERO = range(6)
LAW_KINDS = {RadialTable: RADIAL, TensorTable: TENSOR, Linearised: LINEARISED, Coupling: COUPLING, Zero: ZERO}
LAW_WIDTH = 16  # floats of a law's fixed part (Linearised: 9 + 3 + 3)

# columns of the per-hand arrays (`CompiledTicks` fills them)
# dev: x 0-2, v 3-5, t 6, force 7-9, held_back 10, max_force_applied 11
# cst: origin 0-2, half 3-5, step 6, resolution 7, stiffness 8, damping 9, mass 10, peak 11, along 12-14
# scr: start 0-2, pull 3-5, grasp_at 6, pull_start 7, pull_time 8, release_at 9, tremor_m 10,
#      tremor_hz 11, tremor_phase 12-14, back 15-17, has_back 18, back_start 19, back_time 20,
#      restraint 21, safe_force 22
# hand: position 0-2, force 3-5, button 6, contact_t 7, max_force 8, ticks 9, mean_square 10, over_budget 11
DEV, CST, SCR, HAND = 12, 15, 23, 12

ENABLED = True  # False: every tick in Python (the tests compare the two)

# what the compiled ticks mirror, as imported: a run where any of it was replaced (a test's
# fault injection, a subclass) runs its ticks in Python
MIRRORED = {(cls, name): getattr(cls, name) for cls, names in (
    (SimulatedOmni, ("read", "write_force", "_advance")), (PullScript, ("target", "button")),
    (ServoLoop, ("tick", "_forces", "_budget", "_heat", "_chatter")),
    *((law, ("force",)) for law in (RadialTable, TensorTable, Linearised, Coupling, Zero))) for name in names}
_LIMIT_FORCE = limit_force


@numba.njit(cache=True, fastmath=False, inline="always")
def _min_jerk(tau, three):
    if tau <= 0.0:
        return 0.0
    if tau >= 1.0:
        return 1.0
    return math.pow(tau, three) * (10.0 - 15.0 * tau + 6.0 * tau * tau)


@numba.njit(cache=True, fastmath=False)
def _target(sc, t, out, three):
    """`PullScript.target` (no jump: such scripts never come here)."""
    if sc[8] > 0:
        s = _min_jerk((t - sc[7]) / sc[8], three)
    else:
        s = 1.0 if t >= sc[7] else 0.0
    x0 = sc[0] + s * sc[3]
    x1 = sc[1] + s * sc[4]
    x2 = sc[2] + s * sc[5]
    if sc[18] != 0.0:  # a back movement
        if sc[20] > 0:
            s = _min_jerk((t - sc[19]) / sc[20], three)
        else:
            s = 1.0 if t >= sc[19] else 0.0
        x0, x1, x2 = x0 + s * sc[15], x1 + s * sc[16], x2 + s * sc[17]
    if sc[10] != 0.0:  # tremor
        w = 2.0 * math.pi * sc[11] * t
        m = sc[10]
        x0 += m * math.sin(w + sc[12])
        x1 += m * math.sin(w + sc[13])
        x2 += m * math.sin(w + sc[14])
    out[0], out[1], out[2] = x0, x1, x2


@numba.njit(cache=True, fastmath=False)
def _advance(dev, cst, sc, t, target, prm):
    """`SimulatedOmni._advance` on the state row `dev` (changed in place)."""
    k, c, m = cst[8], cst[9], cst[10]
    gain = sc[21] * prm[10]
    excess = 0.0
    if gain != 0.0:
        excess = math.sqrt(dev[7] * dev[7] + dev[8] * dev[8] + dev[9] * dev[9]) - prm[9] * sc[22]
    while dev[6] + 1e-12 < t:
        h = min(cst[6], t - dev[6])
        _target(sc, dev[6] + h, target, prm[8])
        if gain != 0.0:
            back = dev[10] + h * gain * excess
            back = back if back > 0.0 else 0.0
            dev[10] = back
            target[0] = target[0] - back * cst[12]
            target[1] = target[1] - back * cst[13]
            target[2] = target[2] - back * cst[14]
        for i in range(3):
            a = (k * (target[i] - dev[i]) - c * dev[3 + i] + dev[7 + i]) / m
            dev[3 + i] += h * a
            dev[i] += h * dev[3 + i]
            rel = dev[i] - cst[i]
            half = cst[3 + i]
            if rel > half or rel < -half:
                dev[i] = cst[i] + max(-half, min(half, rel))
                dev[3 + i] = 0.0
        dev[6] += h


@numba.njit(cache=True, fastmath=False)
def _law(kind, p, x0, f0, slope, n, dx, dy, dz, out):
    """The force of a law (`sim/laws.py`) at displacement d."""
    if kind == RADIAL or kind == TENSOR:
        x = math.sqrt(dx * dx + dy * dy + dz * dz)
        if x == 0.0:
            out[0], out[1], out[2] = 0.0, 0.0, 0.0
            return
        k = np.searchsorted(x0[:n], x, side="right") - 1
        if k < 0:
            k += n  # a Python list's index -1
        if kind == RADIAL:
            s = -(f0[k] + slope[k] * (x - x0[k])) / x
            out[0], out[1], out[2] = s * dx, s * dy, s * dz
        else:
            s = -(f0[k] + slope[k] * (x - x0[k])) / (p[0] * x)
            out[0] = s * (p[1] * dx + p[2] * dy + p[3] * dz)
            out[1] = s * (p[4] * dx + p[5] * dy + p[6] * dz)
            out[2] = s * (p[7] * dx + p[8] * dy + p[9] * dz)
    elif kind == LINEARISED:
        ex, ey, ez = dx - p[12], dy - p[13], dz - p[14]
        out[0] = -(p[9] + p[0] * ex + p[1] * ey + p[2] * ez)
        out[1] = -(p[10] + p[3] * ex + p[4] * ey + p[5] * ez)
        out[2] = -(p[11] + p[6] * ex + p[7] * ey + p[8] * ez)
    elif kind == COUPLING:
        k, g = p[0], p[10]
        out[0] = -k * (p[1] + dx - p[4] - g * (dx - p[7]))
        out[1] = -k * (p[2] + dy - p[5] - g * (dy - p[8]))
        out[2] = -k * (p[3] + dz - p[6] - g * (dz - p[9]))
    else:
        out[0], out[1], out[2] = 0.0, 0.0, 0.0


@numba.njit(cache=True, fastmath=False)
def _ticks(k0, k1, rate, dev, cst, scr, hand, point, kinds, laws, x0, f0, slope, nseg, prm, rows):
    """Ticks k0..k1-1 while they are quiet; returns how many ran (their rows in `rows`).

    prm: peak_force, ramp_s, jump_m, continuous_force, dt, budget_tau_s, suspended_until, then
    the exponents 2 and 3 and the devices' RESTRAINT_ONSET and RESTRAINT_GAIN."""
    nh = dev.shape[0]
    peak, ramp_s, jump_m, cont, dt, tau, suspended_until = prm[0], prm[1], prm[2], prm[3], prm[4], prm[5], prm[6]
    two = prm[7]
    ndev = dev.copy()
    target = np.empty(3)
    pos = np.empty((nh, 3))
    out = np.empty(3)
    frc = np.empty((nh, 3))
    for k in range(k0, k1):
        t = k / rate
        if t < suspended_until:
            return k - k0
        # 1. read every device (a copy: nothing is kept of a tick left to the Python tick)
        for i in range(nh):
            for j in range(DEV):
                ndev[i, j] = dev[i, j]
            _advance(ndev[i], cst[i], scr[i], t, target, prm)
            r = cst[i, 7]
            o = cst[i]
            for j in range(3):
                pos[i, j] = o[j] + np.rint((ndev[i, j] - o[j]) / r) * r
            if not (math.isfinite(pos[i, 0]) and math.isfinite(pos[i, 1]) and math.isfinite(pos[i, 2])):
                return k - k0
            step = math.sqrt(math.pow(pos[i, 0] - hand[i, 0], two) + math.pow(pos[i, 1] - hand[i, 1], two) + math.pow(pos[i, 2] - hand[i, 2], two))
            if hand[i, 9] > 0 and step > jump_m:
                return k - k0
            button = 1.0 if (scr[i, 6] <= t and t < scr[i, 9]) else 0.0
            if button != hand[i, 6]:
                return k - k0
        # 2. forces, 3. safety: any rule acting leaves the tick to Python
        for i in range(nh):
            if kinds[i] == NONE:
                frc[i, 0], frc[i, 1], frc[i, 2] = 0.0, 0.0, 0.0
                continue
            _law(kinds[i], laws[i], x0[i], f0[i], slope[i], nseg[i],
                 pos[i, 0] - point[i, 0], pos[i, 1] - point[i, 1], pos[i, 2] - point[i, 2], out)
            fx, fy, fz = out[0], out[1], out[2]
            ramp = (t - hand[i, 7]) / ramp_s
            if ramp < 1.0:
                if ramp < 0.0:
                    ramp = 0.0
                fx, fy, fz = fx * ramp, fy * ramp, fz * ramp
            mag = math.sqrt(fx * fx + fy * fy + fz * fz)
            if not math.isfinite(mag) or mag > peak:
                return k - k0
            m2 = math.pow(fx, two) + math.pow(fy, two) + math.pow(fz, two)
            if hand[i, 11] > 0 and m2 > cont * cont:
                return k - k0
            p0, p1, p2 = hand[i, 3], hand[i, 4], hand[i, 5]
            if p0 * fx + p1 * fy + p2 * fz < 0.0 and p0 * p0 + p1 * p1 + p2 * p2 > 0.0025 and fx * fx + fy * fy + fz * fz > 0.0025:
                return k - k0  # a reversal: the chatter monitor's list is Python's
            frc[i, 0], frc[i, 1], frc[i, 2] = fx, fy, fz
        # the tick is quiet: keep it (write, heat, record)
        row = rows[k - k0]
        row[0] = t
        c2 = math.pow(cont, two)
        for i in range(nh):
            fx, fy, fz = frc[i, 0], frc[i, 1], frc[i, 2]
            for j in range(DEV):
                dev[i, j] = ndev[i, j]
            mag = math.sqrt(fx * fx + fy * fy + fz * fz)  # SimulatedOmni.write_force
            if not math.isfinite(mag):
                fx = fy = fz = mag = 0.0
            elif mag > cst[i, 11]:
                s = cst[i, 11] / mag
                fx, fy, fz, mag = fx * s, fy * s, fz * s, cst[i, 11]
            dev[i, 7], dev[i, 8], dev[i, 9] = fx, fy, fz
            if mag > dev[i, 11]:  # max(max_force_applied, mag)
                dev[i, 11] = mag
            fx, fy, fz = frc[i, 0], frc[i, 1], frc[i, 2]
            hand[i, 0], hand[i, 1], hand[i, 2] = pos[i, 0], pos[i, 1], pos[i, 2]
            hand[i, 3], hand[i, 4], hand[i, 5] = fx, fy, fz
            hand[i, 9] += 1
            m2 = math.pow(fx, two) + math.pow(fy, two) + math.pow(fz, two)
            hand[i, 10] += (m2 - hand[i, 10]) * dt / tau
            if hand[i, 11] == 0 and hand[i, 10] > c2:
                hand[i, 11] = 1.0
            elif hand[i, 11] > 0 and hand[i, 10] < 0.64 * c2:
                hand[i, 11] = 0.0
            mag = math.sqrt(m2)
            if mag > hand[i, 8]:
                hand[i, 8] = mag
            b = 3 + 7 * i
            row[b], row[b + 1], row[b + 2] = pos[i, 0], pos[i, 1], pos[i, 2]
            row[b + 3], row[b + 4], row[b + 5] = fx, fy, fz
            row[b + 6] = hand[i, 6]
    return k1 - k0


class CompiledTicks:
    """The quiet ticks of a lockstep `ServoLoop` whose every device is a `SimulatedOmni`."""

    def __init__(self, servo) -> None:
        self.servo = servo
        hands = servo.hands
        nh = len(hands)
        self.cst = np.zeros((nh, CST))
        self.scr = np.zeros((nh, SCR))
        for i, h in enumerate(hands):
            d, sc = h.device, h.device.script
            imp = d.impedance
            self.cst[i] = (*d.origin, *d._half, d._step, d.spec.resolution_m, imp.stiffness_n_per_m, imp.damping_ns_per_m,
                           imp.mass_kg, d.spec.peak_force_n, *d._along)
            back = sc.back_start is not None
            self.scr[i] = (*sc.start, *sc.pull, sc.grasp_at, sc.pull_start, sc.pull_time, sc.release_at, sc.tremor_m, sc.tremor_hz,
                           *sc.tremor_phase, *sc.back, 1.0 if back else 0.0, sc.back_start if back else 0.0, sc.back_time,
                           sc.restraint, sc.safe_force)
        self.rows = np.empty((0, 3 + 7 * nh))
        # set when the model's state rules these ticks out (unstable, laws they do not know):
        # that holds until the next frame, so the loop stops asking until then (`frame`)
        self.idle = False

    def frame(self) -> None:
        """A visual frame ran: the model's laws and state may have changed."""
        self.idle = False

    @classmethod
    def for_loop(cls, servo) -> CompiledTicks | None:
        """The compiled ticks for `servo`, or None where the run is not one they mirror."""
        if not ENABLED or type(servo) is not ServoLoop or not servo.hands or vars(servo).keys() & {"tick", "_forces"}:
            return None
        if servo.timed:  # the ticks know laws of d alone, and would leave the velocity estimates cold
            return None
        if sim.servo.loop.limit_force is not _LIMIT_FORCE or any(getattr(c, name) is not f for (c, name), f in MIRRORED.items()):
            return None
        for h in servo.hands:
            d = h.device
            if type(d) is not SimulatedOmni or vars(d).keys() & {"read", "write_force", "_advance"}:
                return None
            if type(d.script) is not PullScript or d.script.jump_at is not None:
                return None
        return cls(servo)

    def _laws(self):
        """Per hand: the law's kind and numbers, or None when a held hand's force is not a law
        these ticks know (or the model is not law-driven now)."""
        servo = self.servo
        hands = servo.hands
        nh = len(hands)
        held = [h for h in hands if h.contact is not None]
        laws = servo_laws(servo.model, [h.contact for h in held]) if held else []
        if laws is None:
            return None
        kinds = np.zeros(nh, dtype=np.int64)
        p = np.zeros((nh, LAW_WIDTH))
        point = np.zeros((nh, 3))
        n = max([len(law.x0) for law in laws if type(law) in (RadialTable, TensorTable)], default=1)
        x0, f0, slope = np.zeros((nh, n)), np.zeros((nh, n)), np.zeros((nh, n))
        nseg = np.ones(nh, dtype=np.int64)
        by_hand = {h.index: law for h, law in zip(held, laws)}
        for i, h in enumerate(hands):
            if h.contact is None:
                continue
            if h.safety is not None:
                return None
            law = by_hand[h.index]
            kind = LAW_KINDS.get(type(law))
            if kind is None:
                return None
            kinds[i] = kind
            point[i] = h.contact.point
            if kind in (RADIAL, TENSOR):
                m = len(law.x0)
                if m == 0 or len(law.f0) < m or len(law.slope) < m:  # the Python tick reports such a table's fault
                    return None
                x0[i, :m], f0[i, :m], slope[i, :m], nseg[i] = law.x0, law.f0, law.slope, m
                if kind == TENSOR:
                    p[i, :10] = (law.k0, *law.S)
            elif kind == LINEARISED:
                p[i, :15] = (*law.K, *law.f_frame, *law.d_frame)
            elif kind == COUPLING:
                p[i, :11] = (law.k, *law.anchor, *law.patch, *law.d_frame, law.gain)
        return kinds, p, point, x0, f0, slope, nseg

    def run(self, k0: int, k1: int, rate: float) -> int:
        """Ticks k0..k1-1 while they are quiet, their rows appended to the loop's log; returns
        how many ran (0: the Python tick runs tick k0)."""
        servo = self.servo
        hands = servo.hands
        if any(h.fault is not None for h in hands):
            return 0
        try:
            unstable = bool(servo.model.unstable)
        except Exception:  # the Python tick logs it
            unstable = True
        laws = None if unstable else self._laws()
        if laws is None:
            self.idle = True
            return 0
        kinds, p, point, x0, f0, slope, nseg = laws
        nh = len(hands)
        dev = np.empty((nh, DEV))
        hand = np.empty((nh, HAND))
        for i, h in enumerate(hands):
            d = h.device
            dev[i] = (*d._x, *d._v, d._t, *d._force, d.held_back, d.max_force_applied)
            hand[i] = (*h.position, *h.force, 1.0 if h.button else 0.0, h.contact_t, h.max_force, h.ticks, h.mean_square,
                       1.0 if h.over_budget else 0.0)
        # read now, as the Python tick reads them; the constants passed as values: numba would
        # freeze a module's constant in its disk cache, which a change elsewhere does not clear
        prm = np.array([servo.peak_force, servo.ramp_s, servo.jump_m, servo.continuous_force, servo.dt, servo.budget_tau_s,
                        servo.suspended_until, 2.0, 3.0, simulated.RESTRAINT_ONSET, simulated.RESTRAINT_GAIN])
        if len(self.rows) < k1 - k0:
            self.rows = np.empty((k1 - k0, 3 + 7 * nh))
        try:
            # the first call of a process loads or compiles the kernel (tens to hundreds of ms):
            # paid here, on no tick, so the timed batch below is the ticks' own work
            _ticks(k0, k0, float(rate), dev, self.cst, self.scr, hand, point, kinds, p, x0, f0, slope, nseg, prm, self.rows)
        except Exception:
            return 0
        start = time.perf_counter()
        try:
            done = _ticks(k0, k1, float(rate), dev, self.cst, self.scr, hand, point, kinds, p, x0, f0, slope, nseg, prm, self.rows)
        except Exception:  # e.g. a law dividing by zero: nothing is kept, the Python tick runs it (and logs the fault)
            return 0
        if done == 0:
            return 0
        rows = self.rows[:done]
        # a compiled tick's compute and read-to-force times are the loop's mean per tick: lockstep
        # has no device I/O, and these ticks are not timed one by one
        rows[:, 1] = rows[:, 2] = (time.perf_counter() - start) / done
        servo.rows.extend(rows)
        for i, h in enumerate(hands):
            d, r = h.device, dev[i]
            d._x[:], d._v[:] = [float(c) for c in r[0:3]], [float(c) for c in r[3:6]]
            d._t, d._force, d.held_back, d.max_force_applied = float(r[6]), tuple(float(c) for c in r[7:10]), float(r[10]), float(r[11])
            s = hand[i]
            h.position, h.force = tuple(float(c) for c in s[0:3]), tuple(float(c) for c in s[3:6])
            h.max_force, h.ticks, h.mean_square, h.over_budget = float(s[8]), int(s[9]), float(s[10]), bool(s[11] > 0)
        return done
