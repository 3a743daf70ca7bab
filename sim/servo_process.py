"""The servo loop in its own process, so rendering and deformation cannot delay it.

Threads of one Python process share an interpreter lock: measured here, open3d drawing a
frame in the visual thread holds it for about 40 ms, and a servo thread beside it ran 946 of
5000 ticks in 5 s (p99 interval 39 ms). So in real-time runs the devices and the servo tick live
in a child process (started with "spawn": a clean interpreter that imports only the servo's
modules), and the two sides talk through

- shared memory, written by the child every tick and read by the parent each frame: per hand
  the position, button, force sent, fault, and a grasp request (position + counter); the
  pointer's target for mouse devices (written by the parent); the run's clock and state;
- a pipe from the parent: "run" (a new run and its device recipes), contacts (their force laws,
  sim/laws.py) when grasped, law updates after every frame, "start", "stop", "pulse", "close";
  and from the child: each run's tick log and events when it ends, and the devices' notices.

The child opens its devices once and serves run after run (a session's training and trials)
until closed; between runs it keeps reading the devices and sends no force. Simulated devices
tick on the child's own clock; real ones on the HD library's scheduler thread. The child polls
the pipe once per tick (a microsecond or two when nothing is waiting).
"""

from __future__ import annotations

import math
import multiprocessing as mp
import threading
import time
from dataclasses import dataclass
from multiprocessing import shared_memory

import numpy as np

from sim.models.api import servo_law, servo_state
from sim.servo import Event, Hand, ServoLoop, wait_until

# per-hand slots in shared memory (float64); IN_P/IN_BUTTON are written by the parent (the
# view's pointer, for mouse devices), the rest by the servo
P, BUTTON, F, GRASP_SEQ, GRASP_AT, FAULT, HELD, IN_P, IN_BUTTON = 0, 3, 4, 7, 8, 11, 12, 13, 16
SLOT = 17
# global slots: ticks since the run's clock started, when the latest tick read its devices
# (perf_counter, one clock for both processes on Linux), whether the clock has started, and the
# run whose state the board shows
TICKS, READ_T, STARTED, RUN_SEQ = 0, 1, 2, 3
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


def _open_device(r, board, rig):
    if r[0] == "simulated":
        from sim.devices.simulated import SimulatedOmni

        return SimulatedOmni(r[1], name=r[2])
    if r[0] == "replay":
        from sim.devices.replay import ReplayDevice

        return ReplayDevice(r[1], r[2])
    if r[0] == "mouse":
        from sim.devices.mouse import MouseDevice

        base = GLOBAL + SLOT * r[1]

        def source(base=base):
            return (board[base + IN_P], board[base + IN_P + 1], board[base + IN_P + 2]), board[base + IN_BUTTON] > 0.5

        return MouseDevice(source, r[3], name=r[2])
    from sim.devices.openhaptics import OpenHapticsDevice

    return OpenHapticsDevice(rig, r[4], frame=r[3])


def _open_devices(recipes, board=None):
    """The devices of `recipes`; real ones share one rig (opened here, started by the runner)."""
    rig = None
    names = [r[2] for r in recipes if r[0] == "openhaptics"]
    if names:
        from sim.devices.openhaptics import OpenHapticsRig

        rig = OpenHapticsRig(names, library=next(r[5] for r in recipes if r[0] == "openhaptics"))
    try:
        return [_open_device(r, board, rig) for r in recipes], rig
    except Exception:
        if rig is not None:
            rig.close()
        raise


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


class _Runner:
    """The servo process's state: its devices (opened once, kept across runs), the servo loop,
    and the current run. `tick` is called at 1 kHz by a pacer: this process's own clock, or the
    HD library's scheduler thread for real devices; `handle` runs messages from the parent. Both
    take the lock, so a message never lands in the middle of a tick."""

    def __init__(self, conn, board, recipes, hand_names, rate, time_scale, miss_streak, suspend_s):
        self.conn, self.board, self.rate = conn, board, rate
        self.period = 1.0 / (rate * time_scale)
        self.miss_streak, self.suspend_s = miss_streak, suspend_s
        self.devices, self.rig = _open_devices(recipes, board)
        self.hands = [Hand(index=i, name=n, device=d) for i, (n, d) in enumerate(zip(hand_names, self.devices))]
        self.model = LawModel()
        self.servo = ServoLoop.for_devices(self.model, self.hands, rate)
        self.lock = threading.Lock()
        self.grasp_seq = [0] * len(self.hands)
        self.k = 0  # ticks since the process began
        self.k_device = 0  # the devices' clock starts here (each run's begin)
        self.run_seq = 0
        self.pulse_end: dict[int, int] = {}
        self.run: dict | None = None  # the current run; None between runs
        self.done: dict | None = None  # a finished run's log, sent by the pacer's thread
        self.closing = False
        self.last_start = None

    # -- messages ------------------------------------------------------------------------------
    def handle(self, msg) -> None:
        with self.lock:
            kind = msg[0]
            hands = self.hands
            if kind == "contact":
                _, i, point, law, t_contact = msg
                if self.run is not None and hands[i].button:
                    hands[i].contact_t = t_contact
                    hands[i].contact = RemoteContact(i, point, law)
            elif kind == "laws":
                _, laws, pair, unstable = msg
                for i, law in laws.items():
                    c = hands[i].contact
                    if c is not None:
                        c.law = law
                self.model.pair, self.model.unstable = pair, unstable
            elif kind == "pulse" and self.run is not None:  # the device check: a short, gentle force
                _, i, force, seconds = msg
                from sim.laws import Constant

                hands[i].contact_t = (self.k - self.run["k0"]) / self.rate
                hands[i].contact = RemoteContact(i, hands[i].position, Constant(tuple(force)))
                self.pulse_end[i] = self.k + int(seconds * self.rate)
            elif kind == "run":
                self.run_seq = msg[1]
                self._begin(*msg[2:])
            elif kind == "start" and self.run is not None and not self.run["started"]:  # the experimenter's key
                self._start("key", keep_last=False)
            elif kind == "stop" and self.run is not None:
                self._finish()
            elif kind == "close":
                if self.run is not None:
                    self._finish()
                self.closing = True

    def _begin(self, n_ticks: int, wait: bool, recipes) -> None:
        """A new run. Scripted and replayed devices are re-made from the run's recipes; mouse and
        real devices are kept (a rig is opened once per servo process)."""
        for i, r in enumerate(recipes):
            if r[0] in ("simulated", "replay"):  # a script or recording plays from its start each run
                self.devices[i] = self.hands[i].device = _open_device(r, self.board, self.rig)
                self.hands[i].ticks = 0
        self._drop_contacts()
        self.run = {"n": n_ticks, "started": False, "started_by": None, "k0": self.k, "starts": np.empty(n_ticks), "misses": 0,
                    "streak": 0, "begin": time.perf_counter(), "waited_s": 0.0}
        self.k_device = self.k  # the run begins: scripted devices start their script, waiting is counted from here
        self.board[TICKS], self.board[STARTED] = 0, 0.0
        if not wait:
            self._start("clock", keep_last=False)

    def _start(self, by: str, keep_last: bool) -> None:
        """The run's clock starts at tick `self.k`: the one running now (a grasp, kept) or the next
        (a key, or a run that does not wait)."""
        run = self.run
        run.update(started=True, started_by=by, k0=self.k, misses=0, streak=0, waited_s=(self.k - self.k_device) / self.rate)
        self.servo.restart(keep_last=keep_last)
        if keep_last:
            run["starts"][0] = self.last_start
        self.board[STARTED] = 1.0

    def _finish(self) -> None:
        run = self.run
        n = self.k - run["k0"] if run["started"] else 0
        rows = self.servo.rows.array() if run["started"] else np.zeros((0, self.servo.rows.width))
        self.done = {"rows": rows, "events": list(self.servo.events) if run["started"] else [], "starts": run["starts"][:n],
                     "misses": run["misses"], "wall": time.perf_counter() - run["begin"], "started_by": run["started_by"],
                     "waited_s": run["waited_s"], "pacer": "hd-scheduler" if self.rig is not None else "process"}
        self.run = None
        self._drop_contacts()
        self.servo.rows.clear()
        self.servo.events.clear()

    def _drop_contacts(self) -> None:
        for h in self.hands:
            h.contact, h.grasp_request = None, None

    # -- the tick ------------------------------------------------------------------------------
    def tick(self, now: float, late: bool) -> None:
        with self.lock:
            run, servo, hands, board = self.run, self.servo, self.hands, self.board
            self.last_start = now
            started = run is not None and run["started"]
            if run is not None:
                if started:
                    run["starts"][self.k - run["k0"]] = now
                if late:
                    run["misses"] += 1
                    run["streak"] += 1
                    if run["streak"] >= self.miss_streak:  # the loop cannot keep time: no force for a while
                        servo.suspend((self.k - run["k0"]) / self.rate, self.suspend_s, "deadline_streak")
                else:
                    run["streak"] = 0
            for i, end in list(self.pulse_end.items()):
                if self.k >= end:
                    hands[i].contact = None
                    del self.pulse_end[i]
            t = (self.k - run["k0"]) / self.rate if run is not None else 0.0
            servo.tick(t, (self.k - self.k_device) / self.rate)
            if run is None:  # between runs: hands are shown, nothing is grasped or kept
                for h in hands:
                    h.grasp_request = None
                if len(servo.rows) >= 4096:
                    servo.rows.clear()
                    servo.events.clear()
            elif not started:
                if any(h.grasp_request is not None for h in hands):  # a grasp starts the clock
                    self._start("grasp", keep_last=True)
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
                    self.grasp_seq[i] += 1
                    board[base + GRASP_SEQ] = self.grasp_seq[i]  # written after the position
                    h.grasp_request = None
            board[READ_T] = now  # after the hands: a frame's late latch never pairs this read with older positions
            board[RUN_SEQ] = self.run_seq  # after the hands: the parent then sees this run's state
            self.k += 1
            run = self.run
            if run is not None and run["started"]:
                board[TICKS] = self.k - run["k0"]
                if self.k - run["k0"] >= run["n"]:
                    self._finish()

    def send_pending(self) -> None:
        done, self.done = self.done, None
        if done is not None:
            self.conn.send(("done", done))
        if self.rig is not None:
            for notice in self.rig.take_notices():  # calibration guidance, warm motors
                self.conn.send(("notice", notice))

    # -- pacers --------------------------------------------------------------------------------
    def serve_self_paced(self) -> None:
        clock, period, conn = time.perf_counter, self.period, self.conn
        deadline = clock()
        while not self.closing:
            while conn.poll():
                self.handle(conn.recv())
            if self.closing:
                break
            wait_until(deadline, 5e-4)  # spin the last 0.5 ms: wake-ups run late under load
            now = clock()
            self.tick(now, now > deadline + 0.5 * period)
            self.send_pending()
            deadline += period
            if clock() > deadline + period:  # far behind: resynchronise, never burst
                deadline = clock()

    def serve_hd_paced(self) -> None:
        """Real devices: the HD scheduler's thread calls the tick; this thread only handles
        messages (it waits in the pipe's poll, without the interpreter lock)."""
        clock, period = time.perf_counter, self.period

        def hd_tick(_t: float) -> None:
            now = clock()
            self.tick(now, self.last_start is not None and now - self.last_start > 1.5 * period)

        self.rig.start(hd_tick)
        try:
            while not self.closing:
                if self.conn.poll(0.002):
                    self.handle(self.conn.recv())
                self.send_pending()
        finally:
            self.rig.stop()


def _child(conn, shm_name: str, recipes, hand_names, rate: float, time_scale: float, miss_streak: int, suspend_s: float):
    """The servo process: opens the devices once, then serves runs until told to close."""
    import gc
    import signal
    import sys

    # Ctrl-C in the terminal reaches the whole process group: the session's process handles it
    # and closes this one (zero force, devices closed), so no traceback from here
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    shm = shared_memory.SharedMemory(name=shm_name)
    runner = None
    try:
        board = np.ndarray((GLOBAL + SLOT * len(recipes),), dtype=np.float64, buffer=shm.buf)
        try:
            runner = _Runner(conn, board, recipes, hand_names, rate, time_scale, miss_streak, suspend_s)
        except Exception as exc:  # reported to the parent as a clean error
            conn.send(("error", str(exc)))
            return
        priority = _realtime_priority()
        sys.setswitchinterval(2e-4)  # the HD thread and the message thread share the interpreter lock
        conn.send(("ready", priority))
        gc.disable()  # a full collection is a multi-millisecond pause; the loop allocates little
        if runner.rig is not None:
            runner.serve_hd_paced()
        else:
            runner.serve_self_paced()
        gc.enable()
        runner.send_pending()
    finally:
        if runner is not None:
            for h in runner.hands:
                try:
                    h.device.write_force((0.0, 0.0, 0.0))
                    h.device.close()
                except Exception:
                    pass
            if runner.rig is not None:
                runner.rig.close()
        shm.close()


def device_recipes(scene, library: str | None = None) -> list[tuple]:
    """Picklable descriptions of the scene's devices, opened in the servo process."""
    out = []
    rig_index = 0
    for i, h in enumerate(scene.spec.hands):
        if h.device == "simulated":
            out.append(("simulated", scene.script(i), f"{h.name} (simulated)"))
        elif h.device == "replay":
            out.append(("replay", str(h.trace), h.trace_hand or h.name))
        elif h.device == "mouse":
            out.append(("mouse", i, f"{h.name} (mouse)", scene.script(i).start))
        else:
            out.append(("openhaptics", None, scene.device_name(i), scene.device_frame(i), rig_index, library))
            rig_index += 1
    return out


class ServoProcess:
    """Parent side of the servo process: start it (devices open once), then serve runs: mirror
    its hands, send contacts and laws, collect each run's log. Close it when done."""

    def __init__(self, scene, time_scale: float = 1.0, miss_streak: int = 3, suspend_s: float = 0.1):
        from sim.errors import DeviceError

        self.closed = False
        recipes = device_recipes(scene)
        self.n = len(recipes)
        self.rate = scene.spec.servo_rate_hz
        self.time_scale = time_scale
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
            args=(child_conn, self.shm.name, recipes, [h.name for h in scene.spec.hands], self.rate, time_scale, miss_streak, suspend_s),
            daemon=True,
        )
        self.proc.start()
        kind, payload = self.conn.recv() if self.conn.poll(120) else ("error", "the servo process did not start within 120 s")
        if kind == "error":
            self.close()
            raise DeviceError(payload)
        self.priority = payload
        self.hands = [Hand(index=i, name=h.name, device=None) for i, h in enumerate(scene.spec.hands)]
        self._grasp_seen = [0] * self.n
        self.read_t = 0.0  # when the devices were read for the state last synced
        self.notices: list[str] = []  # from the devices (calibration, warm motors), for the experimenter
        self._done = None
        self.run_seq = 0

    def ticks(self) -> int:
        return int(self.board[TICKS])

    def started(self) -> bool:
        return bool(self.board[STARTED])

    def _receive(self) -> None:
        while self.conn.poll():
            kind, payload = self.conn.recv()
            if kind == "done":
                self._done = payload
            elif kind == "notice":
                self.notices.append(payload)

    def sync(self) -> None:
        """Copy the child's latest hand state into the mirrors (and new grasp requests)."""
        self._receive()
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

    def latest(self) -> tuple[list[tuple], list[tuple], float]:
        """The hands' newest positions and forces, and when the servo read the devices for them:
        the view's late latch, read just before a frame is drawn (the mirrors do not change)."""
        b = self.board
        read_t = float(b[READ_T])  # written after the hands: the positions are at least this new

        def slot(i, k):
            return tuple(float(x) for x in b[GLOBAL + SLOT * i + k : GLOBAL + SLOT * i + k + 3])

        return [slot(i, P) for i in range(self.n)], [slot(i, F) for i in range(self.n)], read_t

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

    def send_contact(self, hand: int, contact, t: float, model, events: list) -> None:
        """A new grasp's law to the servo; one that cannot be made or sent is a model fault: logged, the grasp dropped."""
        law, fault = servo_law(model, contact)
        if fault is not None:
            events.append(Event(t, hand, "model_fault", f"model_fault: law: {fault}"))
            self.hands[hand].contact = None
            return
        self.send("contact", hand, contact.point, law, t)

    def send_laws(self, model, events: list | None = None) -> None:
        held = [h for h in self.hands if h.contact is not None]
        # a model's own laws are refreshed each frame (a ModelForce went once, at the grasp)
        laws = {h.index: h.contact.law for h in held if h.contact.law is not None}
        p, unstable, fault = servo_state(model, [h.contact for h in held])
        pair = (held[0].index, held[1].index, p) if p is not None else None
        if fault is not None and events is not None and not any(e.detail.startswith("model_fault: laws") for e in events):
            events.append(Event(self.ticks() / self.rate, -1, "model_fault", f"model_fault: laws: {fault}"))  # logged once
        self.send("laws", laws, pair, unstable)

    def run(self, scene, visual, n_ticks: int, visual_rate: float, frame=None, wait: bool = False,
            frame_rate: float = 60.0) -> tuple[dict, list]:
        """One run: this process runs the visual step at `visual_rate` and, between steps, calls
        `frame(sp, visual)` (the participant view: pointer, drawing, keys) up to `frame_rate`
        times a second: the instruments move at the view's rate, not the deformation's. `frame`
        may return "start" (start a waiting run's clock) or "stop". Returns (the run's servo
        log, events)."""
        import os

        self._done = None
        for h in self.hands:
            h.contact, h.grasp_request = None, None
        self.run_seq += 1
        self.send("run", self.run_seq, n_ticks, wait, device_recipes(scene))
        deadline = time.perf_counter() + 10.0
        while self.board[RUN_SEQ] != self.run_seq and self.proc.is_alive() and time.perf_counter() < deadline:
            time.sleep(0.0005)  # the first frame shows this run's devices, not the last run's
        visual.hands = self.hands  # the visual step works on the mirrors
        own = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
        if len(own) > 1:  # leave the servo's core to the servo: every thread of this process
            _set_all_threads_affinity(set(own[:-1]))
        period = 1.0 / (visual_rate * self.time_scale)
        frame_period = 1.0 / max(frame_rate, 1.0)
        clock = time.perf_counter
        try:
            next_step = next_frame = clock()
            while self.proc.is_alive() and self._done is None:
                now = clock()
                wake = next_step if frame is None else min(next_step, next_frame)
                if wake > now:
                    time.sleep(wake - now)
                if clock() >= next_step:
                    self.sync()
                    if self._done is not None:
                        break
                    before = {h.index: h.contact for h in self.hands}
                    visual(self.ticks() / self.rate)
                    for h in self.hands:  # new contacts go to the servo
                        if h.contact is not None and before[h.index] is not h.contact:
                            self.send_contact(h.index, h.contact, h.contact_t, visual.model, visual.events)
                    self.send_laws(visual.model, visual.events)
                    if getattr(visual, "finished", False):  # every hand has held its target
                        break
                    next_step += period
                    if clock() > next_step + period:
                        next_step = clock()
                if frame is not None and clock() >= next_frame:
                    next_frame = clock() + frame_period
                    command = frame(self, visual)
                    if command == "stop":
                        break
                    if command == "start":
                        self.send("start")
            if self._done is None:
                self.send("stop")
                deadline = time.perf_counter() + 30.0
                while self._done is None and self.proc.is_alive() and time.perf_counter() < deadline:
                    if self.conn.poll(0.05):
                        self._receive()
        finally:
            if len(own) > 1:
                _set_all_threads_affinity(set(own))
        out = self._done or {"rows": np.zeros((0, 3)), "events": [], "starts": np.zeros(0), "misses": 0, "wall": math.nan,
                             "started_by": None, "waited_s": 0.0, "pacer": None}
        # the visual side's events (grasps, misses, model faults) of this run's clock
        seen = [e for e in visual.events if e.t >= 0.0]
        events = sorted(list(out["events"]) + seen, key=lambda e: e.t)
        return out, events

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.send("close")
        self.proc.join(timeout=10)
        if self.proc.is_alive():
            self.proc.terminate()
        self.shm.close()
        self.shm.unlink()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


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


__all__ = ["ServoProcess", "Event"]
