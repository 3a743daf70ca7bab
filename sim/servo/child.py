"""The servo process's side (sim/servo/process.py starts it with "spawn"): it opens the
devices once, then serves run after run, the servo tick at its rate, the board in shared memory
written every tick, the pipe polled once per tick. This module and what it imports are all the
spawned interpreter loads, so it stays light."""

from __future__ import annotations

import gc
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from multiprocessing import shared_memory

import numpy as np

from sim.devices.mouse import MouseDevice
from sim.devices.openhaptics import OpenHapticsDevice, OpenHapticsRig
from sim.devices.replay import ReplayDevice
from sim.devices.simulated import SimulatedOmni
from sim.laws import Constant
from sim.servo.loop import Event, Hand, ServoLoop, wait_until
from sim.servo.messages import (
    BeginRun,
    Close,
    DeviceRecipe,
    LawUpdate,
    MouseRecipe,
    NewContact,
    Notice,
    OpenHapticsRecipe,
    PairLaw,
    Pulse,
    Ready,
    ReplayRecipe,
    RunDone,
    RunLog,
    SimulatedRecipe,
    StartClock,
    StartFailed,
    StopRun,
    ToServo,
)

# per-hand slots in shared memory (float64); IN_P/IN_BUTTON are written by the parent (the
# view's pointer, for mouse devices), the rest by the servo (V: the hand's velocity estimate)
P, BUTTON, F, GRASP_SEQ, GRASP_AT, FAULT, HELD, IN_P, IN_BUTTON, V = 0, 3, 4, 7, 8, 11, 12, 13, 16, 17
SLOT = 20
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

    uses_time = False  # per run, the servo's `timed` says (BeginRun); each law declares its own

    def __init__(self) -> None:
        self.unstable = False
        self.pair: PairLaw | None = None

    def force(self, contact, d):
        return contact.law.force(d)

    def forces(self, contacts, disps, velocities=None, t=None):
        pair = self.pair
        if pair is not None and len(contacts) == 2 and (contacts[0].hand, contacts[1].hand) == (pair.a, pair.b):
            return pair.table.forces(disps[0], disps[1])
        if velocities is None:
            return [c.law.force(d) for c, d in zip(contacts, disps)]
        # a run of a model that uses time: its laws take the velocity and the time (a device
        # check's constant pulse does not); `sim.models.api.law_force_at`'s rule, written here
        # because the servo process keeps sim.models.api out (tests/test_servo_messages.py)
        return [c.law.force(d, v, t) if getattr(c.law, "uses_time", False) else c.law.force(d)
                for c, d, v in zip(contacts, disps, velocities)]


@dataclass(slots=True)
class RunState:
    """The current run, updated every tick (misses, streak)."""

    n: int  # ticks to run once the clock has started
    k0: int  # the process's tick at which the run's clock starts (the run's begin until then)
    starts: np.ndarray  # each tick's start (perf_counter)
    begin: float  # perf_counter when the run began, for its wall time
    started: bool = False
    started_by: str | None = None  # "clock", "grasp" or "key"
    misses: int = 0
    streak: int = 0  # consecutive missed deadlines
    waited_s: float = 0.0  # from the run's begin to its clock's start


def _open_device(r: DeviceRecipe, board, rig):
    if isinstance(r, SimulatedRecipe):
        return SimulatedOmni(r.script, name=r.name)
    if isinstance(r, ReplayRecipe):
        return ReplayDevice(r.trace, r.trace_hand)
    if isinstance(r, MouseRecipe):
        base = GLOBAL + SLOT * r.hand

        def source(base=base):
            return (board[base + IN_P], board[base + IN_P + 1], board[base + IN_P + 2]), board[base + IN_BUTTON] > 0.5

        return MouseDevice(source, r.start, name=r.name)

    return OpenHapticsDevice(rig, r.rig_index, frame=r.frame)


def _open_devices(recipes, board=None):
    """The devices of `recipes`; real ones share one rig (opened here, started by the runner)."""
    rig = None
    real = [r for r in recipes if isinstance(r, OpenHapticsRecipe)]
    if real:
        rig = OpenHapticsRig([r.name for r in real], library=real[0].library)
    try:
        return [_open_device(r, board, rig) for r in recipes], rig
    except Exception:
        if rig is not None:
            rig.close()
        raise


def _realtime_priority() -> str:
    """Ask the OS to run this process first: SCHED_FIFO where allowed (root or CAP_SYS_NICE),
    else a higher nice level, else nothing. Returns what was granted."""
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
        self.run: RunState | None = None  # None between runs
        self.done: RunLog | None = None  # a finished run's log, sent by the pacer's thread
        self.closing = False
        self.last_start = None

    # -- messages ------------------------------------------------------------------------------
    def handle(self, msg: ToServo) -> None:
        with self.lock:
            hands, run = self.hands, self.run
            match msg:
                case NewContact(hand=i) if run is not None and hands[i].button:
                    hands[i].contact_t = msg.t
                    hands[i].contact = RemoteContact(i, msg.point, msg.law)
                case LawUpdate():
                    for i, law in msg.laws.items():
                        c = hands[i].contact
                        if c is not None:
                            c.law = law
                    self.model.pair, self.model.unstable = msg.pair, msg.unstable
                case Pulse(hand=i) if run is not None:  # the device check: a short, gentle force
                    hands[i].contact_t = (self.k - run.k0) / self.rate
                    hands[i].contact = RemoteContact(i, hands[i].position, Constant(tuple(msg.force)))
                    self.pulse_end[i] = self.k + int(msg.seconds * self.rate)
                case BeginRun():
                    self.run_seq = msg.seq
                    self._begin(msg.n_ticks, msg.wait, msg.recipes, msg.timed)
                case StartClock() if run is not None and not run.started:  # the experimenter's key
                    self._start("key", keep_last=False)
                case StopRun() if run is not None:
                    self._finish()
                case Close():
                    if run is not None:
                        self._finish()
                    self.closing = True

    def _begin(self, n_ticks: int, wait: bool, recipes, timed: bool = False) -> None:
        """A new run. Scripted and replayed devices are re-made from the run's recipes; mouse and
        real devices are kept (a rig is opened once per servo process). `timed`: the run's model
        uses time (its laws are told the hands' velocities and the tick's time)."""
        self.servo.timed = timed
        for h in self.hands:
            h.estimate.reset()
            h.velocity = (0.0, 0.0, 0.0)
        for i, r in enumerate(recipes):
            if isinstance(r, (SimulatedRecipe, ReplayRecipe)):  # a script or recording plays from its start each run
                self.devices[i] = self.hands[i].device = _open_device(r, self.board, self.rig)
                self.hands[i].ticks = 0
        self._drop_contacts()
        self.run = RunState(n=n_ticks, k0=self.k, starts=np.empty(n_ticks), begin=time.perf_counter())
        self.k_device = self.k  # the run begins: scripted devices start their script, waiting is counted from here
        self.board[TICKS], self.board[STARTED] = 0, 0.0
        if not wait:
            self._start("clock", keep_last=False)

    def _start(self, by: str, keep_last: bool) -> None:
        """The run's clock starts at tick `self.k`: the one running now (a grasp, kept) or the next
        (a key, or a run that does not wait)."""
        run = self.run
        run.started, run.started_by, run.k0 = True, by, self.k
        run.misses, run.streak, run.waited_s = 0, 0, (self.k - self.k_device) / self.rate
        self.servo.restart(keep_last=keep_last)
        if keep_last:
            run.starts[0] = self.last_start
        self.board[STARTED] = 1.0

    def _finish(self) -> None:
        run = self.run
        n = self.k - run.k0 if run.started else 0
        rows = self.servo.rows.array() if run.started else np.zeros((0, self.servo.rows.width))
        if (line := self.servo.budget_line()) is not None and run.started:
            self.servo.events.append(Event(n / self.rate, -1, "over_budget", line))
        self.done = RunLog(rows=rows, events=tuple(self.servo.events) if run.started else (), starts=run.starts[:n],
                           misses=run.misses, wall=time.perf_counter() - run.begin, started_by=run.started_by,
                           waited_s=run.waited_s, pacer="hd-scheduler" if self.rig is not None else "process")
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
            started = run is not None and run.started
            if run is not None:
                if started:
                    run.starts[self.k - run.k0] = now
                if late:
                    run.misses += 1
                    run.streak += 1
                    if run.streak >= self.miss_streak:  # the loop cannot keep time: no force for a while
                        servo.suspend((self.k - run.k0) / self.rate, self.suspend_s, "deadline_streak")
                else:
                    run.streak = 0
            for i, end in list(self.pulse_end.items()):
                if self.k >= end:
                    hands[i].contact = None
                    del self.pulse_end[i]
            t = (self.k - run.k0) / self.rate if run is not None else 0.0
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
                board[base + V : base + V + 3] = h.velocity
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
            if run is not None and run.started:
                board[TICKS] = self.k - run.k0
                if self.k - run.k0 >= run.n:
                    self._finish()

    def send_pending(self) -> None:
        done, self.done = self.done, None
        if done is not None:
            self.conn.send(RunDone(done))
        if self.rig is not None:
            for notice in self.rig.take_notices():  # calibration guidance, warm motors
                self.conn.send(Notice(notice))

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


def child_main(conn, shm_name: str, recipes, hand_names, rate: float, time_scale: float, miss_streak: int, suspend_s: float):
    """The servo process: opens the devices once, then serves runs until told to close."""
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
            conn.send(StartFailed(str(exc)))
            return
        priority = _realtime_priority()
        sys.setswitchinterval(2e-4)  # the HD thread and the message thread share the interpreter lock
        conn.send(Ready(priority))
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


__all__ = ["child_main", "GLOBAL", "SLOT"]
