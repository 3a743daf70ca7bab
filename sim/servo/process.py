"""The servo loop in its own process, so rendering and deformation cannot delay it.

Threads of one Python process share an interpreter lock: a frame drawn in the visual thread
holds it long enough to starve a servo thread beside it (docs/scenes.md). So in real-time runs the devices and the servo tick live
in a child process (started with "spawn": a clean interpreter that imports only the servo's
modules), and the two sides talk through

- shared memory, written by the child every tick and read by the parent each frame: per hand
  the position, button, force sent, fault, and a grasp request (position + counter); the
  pointer's target for mouse devices (written by the parent); the run's clock and state;
- a pipe from the parent: a new run and its device recipes, contacts (their force laws,
  sim/laws.py) when grasped, law updates after every frame, start, stop, pulse, close; and from
  the child: each run's tick log and events when it ends, and the devices' notices (the
  messages' classes are in sim/servo/messages.py).

The child opens its devices once and serves run after run (a session's training and trials)
until closed; between runs it keeps reading the devices and sends no force. Simulated devices
tick on the child's own clock; real ones on the HD library's scheduler thread. The child polls
the pipe once per tick (a microsecond or two when nothing is waiting).

This module is the parent's side (`ServoProcess`); the child's, with the board's layout, is
sim/servo/child.py.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
import time
from multiprocessing import shared_memory

import numpy as np

from sim.errors import DeviceError
from sim.models.api import servo_law, servo_state
from sim.servo.child import (
    BUTTON,
    GLOBAL,
    GRASP_AT,
    GRASP_SEQ,
    HELD,
    IN_BUTTON,
    IN_P,
    READ_T,
    RUN_SEQ,
    SLOT,
    STARTED,
    TICKS,
    F,
    P,
    V,
    child_main,
)
from sim.servo.loop import Event, Hand
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
    ReplayRecipe,
    RunDone,
    RunLog,
    SimulatedRecipe,
    StartClock,
    StartFailed,
    StopRun,
    ToServo,
)


def device_recipes(scene, library: str | None = None) -> tuple[DeviceRecipe, ...]:
    """Picklable descriptions of the scene's devices, opened in the servo process."""
    out: list[DeviceRecipe] = []
    rig_index = 0
    for i, h in enumerate(scene.spec.hands):
        if h.device == "simulated":
            out.append(SimulatedRecipe(script=scene.script(i), name=f"{h.name} (simulated)"))
        elif h.device == "replay":
            out.append(ReplayRecipe(trace=str(h.trace), trace_hand=h.trace_hand or h.name))
        elif h.device == "mouse":
            out.append(MouseRecipe(hand=i, name=f"{h.name} (mouse)", start=scene.script(i).start))
        else:
            out.append(OpenHapticsRecipe(name=scene.device_name(i), frame=scene.device_frame(i), rig_index=rig_index,
                                         library=library))
            rig_index += 1
    return tuple(out)


class ServoProcess:
    """Parent side of the servo process: start it (devices open once), then serve runs: mirror
    its hands, send contacts and laws, collect each run's log. Close it when done."""

    def __init__(self, scene, time_scale: float = 1.0, miss_streak: int = 3, suspend_s: float = 0.1):
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
            if isinstance(r, MouseRecipe):
                self.board[GLOBAL + SLOT * i + IN_P : GLOBAL + SLOT * i + IN_P + 3] = r.start
        ctx = mp.get_context("spawn")
        self.conn, child_conn = ctx.Pipe()
        self.proc = ctx.Process(
            target=child_main,
            args=(child_conn, self.shm.name, recipes, [h.name for h in scene.spec.hands], self.rate, time_scale, miss_streak, suspend_s),
            daemon=True,
        )
        self.proc.start()
        msg = self.conn.recv() if self.conn.poll(120) else StartFailed("the servo process did not start within 120 s")
        if isinstance(msg, StartFailed):
            self.close()
            raise DeviceError(msg.reason)
        self.priority = msg.priority
        self.hands = [Hand(index=i, name=h.name, device=None) for i, h in enumerate(scene.spec.hands)]
        self._grasp_seen = [0] * self.n
        self.read_t = 0.0  # when the devices were read for the state last synced
        self.notices: list[str] = []  # from the devices (calibration, warm motors), for the experimenter
        self._done: RunLog | None = None
        self.run_seq = 0

    def ticks(self) -> int:
        return int(self.board[TICKS])

    def started(self) -> bool:
        return bool(self.board[STARTED])

    def _receive(self) -> None:
        while self.conn.poll():
            msg = self.conn.recv()
            if isinstance(msg, RunDone):
                self._done = msg.result
            elif isinstance(msg, Notice):
                self.notices.append(msg.text)

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
            h.velocity = tuple(float(x) for x in b[base + V : base + V + 3])
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

    def send(self, msg: ToServo) -> None:
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
        self.send(NewContact(hand=hand, point=contact.point, law=law, t=t))

    def send_laws(self, model, events: list | None = None) -> None:
        held = [h for h in self.hands if h.contact is not None]
        # a model's own laws are refreshed each frame (a ModelForce went once, at the grasp)
        laws = {h.index: h.contact.law for h in held if h.contact.law is not None}
        p, unstable, fault = servo_state(model, [h.contact for h in held])
        pair = PairLaw(held[0].index, held[1].index, p) if p is not None else None
        if fault is not None and events is not None and not any(e.detail.startswith("model_fault: laws") for e in events):
            events.append(Event(self.ticks() / self.rate, -1, "model_fault", f"model_fault: laws: {fault}"))  # logged once
        self.send(LawUpdate(laws=laws, pair=pair, unstable=unstable))

    def run(self, scene, visual, n_ticks: int, visual_rate: float, frame=None, wait: bool = False,
            frame_rate: float = 60.0) -> tuple[RunLog, list]:
        """One run: this process runs the visual step at `visual_rate` and, between steps, calls
        `frame(sp, visual)` (the participant view: pointer, drawing, keys) up to `frame_rate`
        times a second: the instruments move at the view's rate, not the deformation's. `frame`
        may return "start" (start a waiting run's clock) or "stop". Returns (the run's servo
        log, events)."""
        self._done = None
        for h in self.hands:
            h.contact, h.grasp_request = None, None
        self.run_seq += 1
        self.send(BeginRun(seq=self.run_seq, n_ticks=n_ticks, wait=wait, recipes=device_recipes(scene),
                           timed=bool(scene.model.uses_time)))
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
                        self.send(StartClock())
            if self._done is None:
                self.send(StopRun())
                deadline = time.perf_counter() + 30.0
                while self._done is None and self.proc.is_alive() and time.perf_counter() < deadline:
                    if self.conn.poll(0.05):
                        self._receive()
        finally:
            if len(own) > 1:
                _set_all_threads_affinity(set(own))
        out = self._done or RunLog(rows=np.zeros((0, 3)), events=(), starts=np.zeros(0), misses=0, wall=math.nan,
                                   started_by=None, waited_s=0.0, pacer=None)
        # the visual side's events (grasps, misses, model faults) of this run's clock
        seen = [e for e in visual.events if e.t >= 0.0]
        events = sorted([*out.events, *seen], key=lambda e: e.t)
        return out, events

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.send(Close())
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
