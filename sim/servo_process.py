"""The servo loop in its own process, so rendering and deformation cannot delay it.

Threads of one Python process share an interpreter lock: measured here, open3d drawing a
frame in the visual thread holds it for about 40 ms, and a servo thread beside it ran 946 of
5000 ticks in 5 s (p99 interval 39 ms). So in real-time runs the devices and the servo tick live
in a child process (started with "spawn": a clean interpreter that imports only the servo's
modules), and the two sides talk through

- shared memory, written by the child every tick and read by the parent each frame: per hand
  the position, button, force sent, fault, and a grasp request (position + counter);
- a pipe from the parent: contacts (their force laws, sim/laws.py) when grasped, law updates
  after every frame, and stop; and from the child at the end: the tick log and the events.

The child polls the pipe once per tick (a microsecond or two when nothing is waiting).
"""

from __future__ import annotations

import math
import multiprocessing as mp
import time
from dataclasses import dataclass
from multiprocessing import shared_memory

import numpy as np

from sim.servo import Event, Hand, ServoLoop, wait_until

# per-hand slots in shared memory (float64); IN_P/IN_BUTTON are written by the parent (the
# view's pointer, for mouse devices), the rest by the servo
P, BUTTON, F, GRASP_SEQ, GRASP_AT, FAULT, HELD, IN_P, IN_BUTTON = 0, 3, 4, 7, 8, 11, 12, 13, 16
SLOT = 17
# global slots: ticks since the run's clock started, when the latest tick read its devices
# (perf_counter, one clock for both processes on Linux), whether the clock has started, ticks waited
TICKS, READ_T, STARTED, WAITED = 0, 1, 2, 3
GLOBAL = 4


@dataclass
class RemoteContact:
    """What the child knows of a contact: its anchor point and its force law."""

    hand: int
    point: tuple
    law: object


class LawModel:
    """The servo-side model: evaluates the laws the parent sent."""

    def __init__(self) -> None:
        self.unstable = False
        self.pair = None  # (hand a, hand b, PairTable)

    def force(self, contact, d):
        return contact.law.force(d)

    def forces(self, contacts, disps):
        if self.pair is not None and len(contacts) == 2 and (contacts[0].hand, contacts[1].hand) == self.pair[:2]:
            return self.pair[2].forces(disps[0], disps[1])
        return [c.law.force(d) for c, d in zip(contacts, disps)]


def _open_devices(recipes, board=None):
    devices = []
    rig_hands = [r for r in recipes if r[0] == "openhaptics"]
    rig_devices = []
    if rig_hands:
        from sim.devices.openhaptics import OpenHapticsDevice, OpenHapticsRig

        rig = OpenHapticsRig([r[2] for r in rig_hands])
        rig_devices = [OpenHapticsDevice(rig, i, origin=r[3]) for i, r in enumerate(rig_hands)]
    for r in recipes:
        if r[0] == "simulated":
            from sim.devices.simulated import SimulatedOmni

            devices.append(SimulatedOmni(r[1], name=r[2]))
        elif r[0] == "replay":
            from sim.devices.replay import ReplayDevice

            devices.append(ReplayDevice(r[1], r[2]))
        elif r[0] == "mouse":
            from sim.devices.mouse import MouseDevice

            base = GLOBAL + SLOT * r[1]

            def source(base=base):
                return (board[base + IN_P], board[base + IN_P + 1], board[base + IN_P + 2]), board[base + IN_BUTTON] > 0.5

            devices.append(MouseDevice(source, r[3], name=r[2]))
        else:
            devices.append(rig_devices.pop(0))
    return devices


def _realtime_priority() -> str:
    """Ask the OS to run this process first: SCHED_FIFO where allowed (root or CAP_SYS_NICE),
    else a higher nice level, else nothing. Returns what was granted."""
    import os

    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if len(cpus) > 1:  # a core of its own: the last one (the parent keeps off it during the run)
        os.sched_setaffinity(0, {cpus[-1]})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
        return "SCHED_FIFO"
    except (AttributeError, PermissionError, OSError):
        pass
    try:
        os.nice(-5)
        return "nice -5"
    except (PermissionError, OSError):
        return "default"


def _child(conn, shm_name: str, recipes, hand_names, rate: float, n_ticks: int, time_scale: float, peak: float,
           miss_streak: int, suspend_s: float, wait: bool):
    """The servo process. With `wait`, the run's clock starts at the first grasp request (or a
    "start" message) and runs `n_ticks` from there; waiting ticks render forces as usual but are
    not kept."""
    import gc

    shm = shared_memory.SharedMemory(name=shm_name)
    try:
        board = np.ndarray((GLOBAL + SLOT * len(recipes),), dtype=np.float64, buffer=shm.buf)
        try:
            devices = _open_devices(recipes, board)
        except Exception as exc:  # reported to the parent as a clean error
            conn.send(("error", str(exc)))
            return
        hands = [Hand(index=i, name=n, device=d) for i, (n, d) in enumerate(zip(hand_names, devices))]
        model = LawModel()
        servo = ServoLoop(model=model, hands=hands, peak_force=peak)
        grasp_seq = [0] * len(hands)
        starts = np.empty(n_ticks)
        misses = 0
        streak = 0
        priority = _realtime_priority()
        conn.send(("ready", None))
        period = 1.0 / (rate * time_scale)
        gc.disable()
        clock = time.perf_counter
        begin = clock()
        deadline = begin
        started = not wait
        started_by = "clock" if started else None
        stop = False
        k = 0  # ticks since the process began; the run's clock is k - k0
        k0 = 0
        board[STARTED] = 1.0 if started else 0.0
        while True:
            while conn.poll():  # contacts and law updates from the visual side
                msg = conn.recv()
                kind = msg[0]
                if kind == "contact":
                    _, i, point, law, t_contact = msg
                    if hands[i].button:
                        hands[i].contact_t = t_contact
                        hands[i].contact = RemoteContact(i, point, law)
                elif kind == "laws":
                    _, laws, pair, unstable = msg
                    for i, law in laws.items():
                        c = hands[i].contact
                        if c is not None:
                            c.law = law
                    model.pair, model.unstable = pair, unstable
                elif kind == "start" and not started:  # the experimenter's key
                    started, started_by, k0 = True, "key", k
                    servo.restart(k / rate, keep_last=False)
                    misses = streak = 0
                    board[STARTED], board[WAITED] = 1.0, k
                elif kind == "stop":
                    stop = True
            if stop or (started and k - k0 >= n_ticks):
                break
            wait_until(deadline, 5e-4)  # spin the last 0.5 ms: wake-ups run late under load
            now = clock()
            if started:
                starts[k - k0] = now
            if now > deadline + 0.5 * period:
                misses += 1
                streak += 1
                if streak >= miss_streak:
                    servo.suspend((k - k0) / rate, suspend_s, "deadline_streak")
            else:
                streak = 0
            servo.tick((k - k0) / rate)
            board[READ_T] = now
            if not started:
                if any(h.grasp_request is not None for h in hands):  # a grasp starts the clock
                    started, started_by, k0 = True, "grasp", k
                    servo.restart(k / rate, keep_last=True)
                    starts[0] = now
                    misses = streak = 0
                    board[STARTED], board[WAITED] = 1.0, k
                elif len(servo.rows) >= 4096:  # nothing kept while waiting
                    servo.rows.clear()
                    servo.events.clear()
            for i, h in enumerate(hands):
                base = GLOBAL + SLOT * i
                board[base + P : base + P + 3] = h.position
                board[base + BUTTON] = 1.0 if h.button else 0.0
                board[base + F : base + F + 3] = h.force
                board[base + FAULT] = 1.0 if h.fault else 0.0
                board[base + HELD] = 1.0 if h.contact is not None else 0.0
                if h.grasp_request is not None:
                    board[base + GRASP_AT : base + GRASP_AT + 3] = h.grasp_request
                    grasp_seq[i] += 1
                    board[base + GRASP_SEQ] = grasp_seq[i]  # written after the position
                    h.grasp_request = None
            k += 1
            board[TICKS] = k - k0 if started else 0
            deadline += period
            if clock() > deadline + period:  # far behind: resynchronise, never burst
                deadline = clock()
        gc.enable()
        for h in hands:
            h.device.write_force((0.0, 0.0, 0.0))
        for d in devices:
            d.close()
        rig = getattr(devices[0], "rig", None) if devices else None
        if rig is not None:
            rig.close()
        n = k - k0 if started else 0
        rows = servo.rows.array() if started else np.zeros((0, servo.rows.width))
        conn.send(("done", {"rows": rows, "events": servo.events if started else [], "starts": starts[:n], "misses": misses,
                            "wall": clock() - begin, "priority": priority, "started_by": started_by, "waited_s": k0 / rate}))
    finally:
        shm.close()


def device_recipes(scene) -> list[tuple]:
    """Picklable descriptions of the scene's devices, opened in the servo process."""
    out = []
    names = ("Left Device", "Right Device")
    for i, h in enumerate(scene.spec.hands):
        if h.device == "simulated":
            out.append(("simulated", scene.script(i), f"{h.name} (simulated)"))
        elif h.device == "replay":
            out.append(("replay", str(h.trace), h.trace_hand or h.name))
        elif h.device == "mouse":
            out.append(("mouse", i, f"{h.name} (mouse)", scene.script(i).start))
        else:
            out.append(("openhaptics", None, h.device_name or names[i], h.script(scene.mesh).start))
    return out


class ServoProcess:
    """Parent side: start the child, mirror its hands, send contacts and laws, collect the log."""

    def __init__(self, scene, n_ticks: int, time_scale: float = 1.0, peak: float = 3.3, miss_streak: int = 3,
                 suspend_s: float = 0.1, wait: bool = False):
        from sim.errors import DeviceError

        recipes = device_recipes(scene)
        self.n = len(recipes)
        self.rate = scene.spec.servo_rate_hz
        size = GLOBAL + SLOT * self.n
        self.shm = shared_memory.SharedMemory(create=True, size=8 * size)
        self.board = np.ndarray((size,), dtype=np.float64, buffer=self.shm.buf)
        self.board[:] = 0.0
        for i, r in enumerate(recipes):  # a mouse hand rests where the scene puts it
            if r[0] == "mouse":
                self.board[GLOBAL + SLOT * i + IN_P : GLOBAL + SLOT * i + IN_P + 3] = r[3]
        ctx = mp.get_context("spawn")
        self.conn, child_conn = ctx.Pipe()
        self.proc = ctx.Process(
            target=_child,
            args=(child_conn, self.shm.name, recipes, [h.name for h in scene.spec.hands], self.rate, n_ticks, time_scale, peak,
                  miss_streak, suspend_s, wait),
            daemon=True,
        )
        self.proc.start()
        kind, payload = self.conn.recv()
        if kind == "error":
            self.close()
            raise DeviceError(payload)
        self.hands = [Hand(index=i, name=h.name, device=None) for i, h in enumerate(scene.spec.hands)]
        self._grasp_seen = [0] * self.n
        self.read_t = 0.0  # when the devices were read for the state last synced

    def ticks(self) -> int:
        return int(self.board[TICKS])

    def started(self) -> bool:
        return bool(self.board[STARTED])

    def sync(self) -> None:
        """Copy the child's latest hand state into the mirrors (and new grasp requests)."""
        b = self.board
        self.read_t = float(b[READ_T])
        for i, h in enumerate(self.hands):
            base = GLOBAL + SLOT * i
            h.position = tuple(float(x) for x in b[base + P : base + P + 3])
            h.button = bool(b[base + BUTTON])
            h.force = tuple(float(x) for x in b[base + F : base + F + 3])
            seq = int(b[base + GRASP_SEQ])
            if seq != self._grasp_seen[i]:
                self._grasp_seen[i] = seq
                h.grasp_request = tuple(float(x) for x in b[base + GRASP_AT : base + GRASP_AT + 3])
            if not b[base + HELD] and h.contact is not None and not h.button:
                h.contact = None  # released (or dropped after a fault) in the servo

    def set_input(self, hand: int, target, pressed: bool) -> None:
        """The pointer's target and button for a mouse hand (read by its device every tick)."""
        base = GLOBAL + SLOT * hand
        self.board[base + IN_BUTTON] = 0.0 if not pressed else 1.0
        self.board[base + IN_P : base + IN_P + 3] = target

    def send(self, *msg) -> None:
        try:
            self.conn.send(msg)
        except (BrokenPipeError, OSError):
            pass

    def send_contact(self, hand: int, contact, t: float) -> None:
        self.send("contact", hand, contact.point, contact.law, t)

    def send_laws(self, model) -> None:
        held = [h for h in self.hands if h.contact is not None]
        laws = {h.index: h.contact.law for h in held}
        pair = None
        pair_law = getattr(model, "pair_law", None)
        if pair_law is not None and len(held) == 2:
            p = pair_law([h.contact for h in held])
            pair = (held[0].index, held[1].index, p) if p is not None else None
        self.send("laws", laws, pair, bool(getattr(model, "unstable", False)))

    def finish(self, timeout: float = 30.0) -> dict:
        self.send("stop")
        result = None
        if self.conn.poll(timeout):
            kind, result = self.conn.recv()
        self.close()
        return result or {"rows": np.zeros((0, 3)), "events": [], "starts": np.zeros(0), "misses": 0, "wall": math.nan,
                          "started_by": None, "waited_s": 0.0}

    def close(self) -> None:
        self.proc.join(timeout=5)
        if self.proc.is_alive():
            self.proc.terminate()
        self.shm.close()
        self.shm.unlink()


def _set_all_threads_affinity(cpus: set) -> None:
    """sched_setaffinity(0) moves only the calling thread; BLAS and renderer pools exist already."""
    import os

    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [0]
    for tid in tids:
        try:
            os.sched_setaffinity(tid, cpus)
        except OSError:
            pass


def run_in_process(scene, visual, n_ticks: int, rate: float, visual_rate: float, time_scale: float, frame=None, wait: bool = False):
    """Run the servo in a child process; this process runs the visual step and then
    `frame(sp, visual)` (the participant view: pointer input, drawing, keys), which may return
    "start" (start a waiting run's clock) or "stop". Returns (servo log, events)."""
    import os

    sp = ServoProcess(scene, n_ticks, time_scale, wait=wait)
    visual.hands = sp.hands  # the visual step works on the mirrors
    own = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if len(own) > 1:  # leave the servo's core to the servo: every thread of this process
        _set_all_threads_affinity(set(own[:-1]))
    period = 1.0 / (visual_rate * time_scale)
    try:
        next_frame = time.perf_counter()
        while sp.proc.is_alive() and not (sp.started() and sp.ticks() >= n_ticks):
            remaining = next_frame - time.perf_counter()
            if remaining > 0:
                time.sleep(remaining)
            sp.sync()
            before = {h.index: h.contact for h in sp.hands}
            visual(sp.ticks() / rate)
            for h in sp.hands:  # new contacts go to the servo
                if h.contact is not None and before[h.index] is not h.contact:
                    sp.send_contact(h.index, h.contact, h.contact_t)
            sp.send_laws(visual.model)
            if frame is not None:
                command = frame(sp, visual)
                if command == "stop":
                    break
                if command == "start":
                    sp.send("start")
            next_frame += period
            if time.perf_counter() > next_frame + period:
                next_frame = time.perf_counter()
    finally:
        out = sp.finish()
        if len(own) > 1:
            _set_all_threads_affinity(set(own))
    grasps = [e for e in visual.events if e.kind == "grasp" and e.t >= 0.0]
    events = list(out["events"]) + grasps
    events.sort(key=lambda e: e.t)
    return out, events


__all__ = ["ServoProcess", "run_in_process", "Event"]
