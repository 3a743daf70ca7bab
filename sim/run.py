"""Run a scene: the servo loop at its rate, the visual step at its rate, statistics, outputs.

Two clocks, one path each:

- real time (``time_scale > 0``): the servo loop runs in its own process
  (sim/servo/process.py) for every device: simulated, mouse and replay devices paced by
  sleep-then-spin on the wall clock (scaled by `time_scale`), real OpenHaptics devices by the
  HD library's scheduler thread in that process. A session keeps one servo process (and its
  devices) for all its runs (`servo=`). The visual step (grasps, deformation, snapshots)
  and the participant view (`Pacing`: drawing, pointer, keys, on-screen text) run in the
  calling process and cannot delay the servo. A paced run can wait for the first grasp (or a
  start key) before its clock starts, and a stop key ends it early. Tick intervals are
  wall-clock intervals.
- lockstep (``time_scale == 0``): one thread, simulated time only, as fast as the machine
  allows; deterministic for the same scene. Used by tests, replays and synthetic studies.

`--frames` pictures are rendered after the run from the snapshots.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim.errors import ParameterError, SceneError
from sim.geometry.mesh import point_tree
from sim.geometry.patch import GRASP_REACH_M
from sim.models.api import deformation_at
from sim.models.base import BUDGETS, contact_checked, surface_checked
from sim.scene import MAX_DURATION_S
from sim.servo.loop import Event, Hand, ServoLoop, too_many_slow_calls
from sim.servo.process import ServoProcess
from sim.targets import TargetTracker
from sim.view.hands import hand_states

FAULT_KINDS = ("model_fault", "nan_force")  # the events whose line says why the model's force was zeroed


@dataclass
class Pacing:
    """A real-time run with a person: what it shows, when its clock starts, what ends it."""

    view: object | None = None  # a sim.view.window.ParticipantView, drawn every frame
    wait_for_grasp: bool = False  # the clock starts at the first grasp, or a start key
    start_keys: tuple[str, ...] = ("space", "enter")
    stop_keys: tuple[str, ...] = ()
    caption: Callable[[str, float], dict] | None = None  # (phase "waiting"/"running", seconds left) -> view text
    keys: Callable[[], list[str]] | None = None  # another key source (the experimenter's terminal)
    notify: Callable[[str], None] | None = None  # the devices' notices (calibration, warm motors) for the experimenter
    on_frame: Callable[[object], None] | None = None  # called with the ServoProcess each frame (e.g. a device check's pulse)


@dataclass
class Snapshot:
    t: float
    displacement: np.ndarray  # (n_vertices, 3) float32
    hand_positions: list[tuple]
    forces: list[tuple]
    grasped: list[bool]


_REST_TREES: dict = {}  # id(surface mesh) -> (mesh, its vertices' tree): a grasp at rest (every trial's first) builds none
REST_TREES_KEPT = 8


def _rest_tree(mesh):
    """The closest-point tree of `mesh` at rest, one per mesh (the mesh is held with it, so its
    id cannot be reused while the entry lives)."""
    hit = _REST_TREES.get(id(mesh))
    if hit is None or hit[0] is not mesh:
        while len(_REST_TREES) >= REST_TREES_KEPT:
            _REST_TREES.pop(next(iter(_REST_TREES)))
        hit = _REST_TREES[id(mesh)] = (mesh, point_tree(mesh.vertices))
    return hit[1]


@dataclass
class VisualStep:
    """Grasps requested by the servo, the deformation of the surface, snapshots for pictures."""

    model: object
    hands: list[Hand]
    events: list[Event]
    snapshot_period: float | None = None  # simulated seconds between pictures; None: none
    deformation_s: list[float] = field(default_factory=list)
    # the model's own count of the floating-point work of each frame (`frame_flops`): a cost
    # that, unlike the measured time, does not change with the machine's load
    frame_flops: list[float] = field(default_factory=list)
    grasp_s: list[float] = field(default_factory=list)
    snapshots: list[Snapshot] = field(default_factory=list)
    last: np.ndarray | None = None
    targets: object = None  # a sim.targets.TargetTracker: the hands' targets, followed every frame
    end_on_targets: bool = False  # the run ends once every hand has held its target
    # the run ends once every hand has grasped and let go (lockstep): what a synthetic interval
    # needs, since its judgement reads each hand's first hold only (studyctl/synthetic/observer.py)
    end_on_release: bool = False
    grasp_reach: float = GRASP_REACH_M
    _next_snapshot: float = 0.0
    _tree: object = None
    _grasped: set = field(default_factory=set)  # hands that have held the tissue in this run
    _last_fault: str | None = None

    def _surface_tree(self):
        """Closest-point structure of the surface as it is now (rebuilt at most once a frame,
        and only when a grasp needs it)."""
        if self._tree is None:
            mesh = self.model_mesh()
            if self.last is None or not self.last.any():  # the surface at rest: its tree is the mesh's, built once
                self._tree = _rest_tree(mesh)
            else:
                self._tree = point_tree(mesh.vertices + self.last)
        return self._tree

    @property
    def finished(self) -> bool:
        """The run's task is done (`finished_why` says how)."""
        return self.finished_why is not None

    @property
    def finished_why(self) -> str | None:
        """"targets held": every hand has held its target (with `end_on_targets`); "released":
        every hand has grasped and let go (with `end_on_release`); None: the run goes on."""
        if self.end_on_targets and self.targets is not None and self.targets.all_held:
            return "targets held"
        if (self.end_on_release and self.hands and len(self._grasped) == len(self.hands)
                and not any(h.button or h.contact is not None for h in self.hands)):
            return "released"
        return None

    def model_mesh(self):
        return self.model.surface_mesh()

    def _fault(self, t: float, detail: str) -> None:
        """The model failed in a frame: its grasps dropped (zero force from the next tick), one
        `model_fault` event while it keeps failing the same way (not one a frame)."""
        for h in self.hands:
            h.contact = None
        detail = f"model_fault: {detail}"
        if detail != self._last_fault:
            self.events.append(Event(t, -1, "model_fault", detail))
        self._last_fault = detail

    def __call__(self, t: float) -> None:
        self._tree = None  # the surface moved since the last frame
        for h in self.hands:
            request = h.grasp_request
            if request is not None and h.contact is None:
                start = time.perf_counter()
                h.grasp_request = None
                # collide with the deformed surface; the model grasps that vertex at rest
                dist, vertex = self._surface_tree().query(request)
                if dist > self.grasp_reach:
                    self.events.append(Event(t, h.index, "grasp_missed", f"surface {dist * 1e3:.1f} mm away"))
                    continue
                try:
                    contact = contact_checked(self.model.grasp(self.model_mesh().vertices[vertex], h.index))
                except Exception as exc:  # e.g. a singular system: no grasp, never a crash
                    self.events.append(Event(t, h.index, "model_fault", f"model_fault: grasp: {exc}"))
                    continue
                self.grasp_s.append(time.perf_counter() - start)
                if h.button:  # still held: publish (time first, so the ramp starts right)
                    h.contact_t = t
                    h.contact = contact
                    if self.targets is not None:  # the target counts from where the button was pressed, as the metrics do
                        self.targets.grasped(h.index, request)
                    self.events.append(Event(t, h.index, "grasp", f"vertex {contact.vertex}"))
                    self._grasped.add(h.index)
        contacts, displacements = [], []
        for h in self.hands:
            c = h.contact
            if c is not None:
                p = h.position
                contacts.append(c)
                displacements.append((p[0] - c.point[0], p[1] - c.point[1], p[2] - c.point[2]))
        start = time.perf_counter()
        flops = math.nan
        try:
            velocities = [h.velocity for h in self.hands if h.contact is not None]
            u = surface_checked(deformation_at(self.model, contacts, displacements, velocities, t), self.model_mesh())
            flops = float(self.model.frame_flops)
        except Exception as exc:  # the model failed: drop the grasps (zero force), keep running
            self._fault(t, f"deformation: {exc}")
            u = np.zeros_like(self.model_mesh().vertices)
        self.deformation_s.append(time.perf_counter() - start)
        self.frame_flops.append(flops)  # a failed frame: no count (never the last frame's)
        self.last = u  # the latest surface displacement, for live drawing and a grasp's collision
        if self.targets is not None:
            self.targets.update(t, self.hands)
        if self.snapshot_period is not None and t + 1e-9 >= self._next_snapshot:
            self._next_snapshot += self.snapshot_period
            self.snapshots.append(
                Snapshot(
                    t=t,
                    displacement=u.astype(np.float32),
                    hand_positions=[h.position for h in self.hands],
                    forces=[h.force for h in self.hands],
                    grasped=[h.contact is not None for h in self.hands],
                )
            )


@dataclass
class RunResult:
    scene_name: str
    model: str
    mode: str
    time_scale: float
    duration: float
    rate_hz: float  # nominal servo rate
    hand_names: list[str]
    times: np.ndarray  # (ticks,) simulated s
    positions: np.ndarray  # (ticks, hands, 3)
    forces: np.ndarray  # (ticks, hands, 3)
    buttons: np.ndarray  # (ticks, hands) bool
    compute_s: np.ndarray  # (ticks,)
    io_latency_s: np.ndarray  # (ticks,) device read to force out, worst hand
    intervals_s: np.ndarray  # (ticks - 1,) wall clock between tick starts
    deadline_misses: int
    wall_s: float
    deformation_s: np.ndarray
    grasp_s: np.ndarray
    events: list[Event]
    snapshots: list[Snapshot]
    model_diagnostics: dict = field(default_factory=dict)
    started_by: str = "clock"  # a paced run: "grasp" or "key"
    waited_s: float = 0.0  # a paced run: seconds before its clock started
    ended_early: str | None = None  # what ended it early: a paced run's key (or "window closed"), "targets held" or "released"
    targets_held: list | None = None  # per hand, whether it held its target (None: no hand has one)
    view: dict | None = None  # the participant view's statistics
    pacer: str | None = None  # real time: "process" (its own clock) or "hd-scheduler" (real devices)
    frame_flops: np.ndarray = field(default_factory=lambda: np.zeros(0))  # per visual frame, the model's count
    over_budget: list[str] = field(default_factory=list)  # one line per call whose 99th percentile passed its budget

    def faults(self) -> list[dict]:
        """Every `model_fault` and `nan_force` event with its line: why the model's force was
        zeroed (the counts in `events` alone do not say)."""
        out = []
        for e in self.events:
            if e.kind in FAULT_KINDS:
                hand = self.hand_names[e.hand] if 0 <= e.hand < len(self.hand_names) else None
                detail = e.detail or f"{e.kind}: the model's force was not finite (NaN or infinite); zero force sent"
                out.append({"t": e.t, "hand": hand, "kind": e.kind, "detail": detail})
        return out

    def stats(self) -> dict:
        """The summary `studyctl sim run --json` prints."""
        fmag = np.linalg.norm(self.forces, axis=2) if len(self.forces) else np.zeros((0, len(self.hand_names)))
        ticks = len(self.times)
        return {
            "scene": self.scene_name,
            "model": self.model,
            "mode": self.mode,
            "time_scale": self.time_scale,
            "duration_s": self.duration,
            "ticks": ticks,
            "rate_hz": ticks / self.wall_s if self.wall_s > 0 else math.nan,
            # lockstep runs as fast as it can: wall-clock intervals there measure nothing
            "tick_interval_us": _percentiles(self.intervals_s * 1e6 if self.mode != "lockstep" else np.zeros(0), (50, 99, 99.9), with_max=True),
            "tick_compute_us": _percentiles(self.compute_s * 1e6, (50, 99), with_max=True),
            "read_to_force_us": _percentiles(self.io_latency_s * 1e6, (50, 99), with_max=True),
            "deadline_misses": self.deadline_misses,
            "max_force_n": float(fmag.max()) if fmag.size else 0.0,
            "max_force_per_hand_n": {n: float(fmag[:, i].max()) if ticks else 0.0 for i, n in enumerate(self.hand_names)},
            "deformation_ms": _percentiles(self.deformation_s * 1e3, (50, 99), with_max=True),
            "grasp_ms": _percentiles(self.grasp_s * 1e3, (50,), with_max=True),
            "visual_frames": len(self.deformation_s),
            "frames": 0,
            "events": dict(Counter(e.kind for e in self.events)),
            "model_diagnostics": self.model_diagnostics,
            "started_by": self.started_by,
            "pacer": self.pacer,
            "ended_early": self.ended_early,
            "over_budget": self.over_budget,
            "faults": self.faults(),
            **({"view": self.view} if self.view is not None else {}),
        }


def _percentiles(values: np.ndarray, qs, with_max=False) -> dict:
    if len(values) == 0:
        out = {f"p{q}": None for q in qs}
        if with_max:
            out["max"] = None
        return out
    out = {f"p{q}": float(np.percentile(values, q)) for q in qs}
    if with_max:
        out["max"] = float(np.max(values))
    return out


def run_scene(scene, duration: float | None = None, time_scale: float = 1.0, snapshots: bool = False,
              pacing: Pacing | None = None, servo=None, end_on_targets: bool = False, end_on_release: bool = False) -> RunResult:
    """Run `scene` (a `sim.scene.Scene`) for `duration` simulated seconds, or, with
    `end_on_targets`, until every hand has held its target (`[hands.target]`), whichever is first;
    with `end_on_release` (lockstep only), until every hand has grasped and let go.

    In real time (`time_scale > 0`) the servo runs in its own process: `servo`, a
    `sim.servo.process.ServoProcess` kept open across runs (a session's), or one opened for
    this run; `pacing` adds the participant view, waiting for a grasp and stop keys.
    `time_scale == 0` is lockstep (not for real devices).
    """
    spec = scene.spec
    duration = spec.duration if duration is None else duration
    rate = spec.servo_rate_hz
    model = scene.model
    if not (math.isfinite(duration) and 0 < duration <= MAX_DURATION_S):
        raise ParameterError(f"duration: {duration!r} is out of range; allowed: (0, {MAX_DURATION_S:g}] s")
    if not (math.isfinite(time_scale) and 0 <= time_scale <= 1000):
        raise ParameterError(f"time scale: {time_scale!r} is out of range; allowed: 0 (lockstep) or (0, 1000]")
    if end_on_release and time_scale > 0:
        raise ParameterError("end_on_release: a lockstep run's option (time scale 0)")
    if time_scale <= 0 and pacing is not None:
        raise ParameterError("the participant view and paced trials need real time (time scale > 0)")
    try:
        model.reset()  # every run starts from undeformed tissue
    except Exception as exc:  # a lab's model may fail in any way: one line naming it, as a failed build is
        raise SceneError(f"model {scene.model_spec.name!r}: reset raised {type(exc).__name__}: {exc}") from None
    if time_scale > 0:
        return _run_process(scene, model, duration, rate, time_scale, snapshots, pacing, servo, end_on_targets)
    person = [h.device for h in spec.hands if h.device in ("openhaptics", "mouse")]
    if person:
        raise ParameterError(f"device {person[0]}: a person's device runs in real time only (time scale > 0)")
    devices = scene.open_devices()
    hands = [Hand(index=i, name=h.name, device=d) for i, (h, d) in enumerate(zip(spec.hands, devices))]
    servo_loop = ServoLoop.for_devices(model, hands, rate)
    snapshot_period = 1.0 / spec.renderer.fps if snapshots else None
    # every frame computes the surface a person's view would draw, pictures or not: the
    # deformation time measures a participant's frame
    visual = VisualStep(model=model, hands=hands, events=servo_loop.events, snapshot_period=snapshot_period,
                        targets=_tracker(scene), end_on_targets=end_on_targets, end_on_release=end_on_release)
    n_ticks = int(round(duration * rate))
    try:
        starts, misses, wall = _run_lockstep(servo_loop, visual, n_ticks, rate, spec.visual_rate_hz)
    finally:
        for d in devices:
            d.close()
    result = _result(scene, model, "lockstep", time_scale, duration, rate, [h.name for h in hands], servo_loop.rows.array(), starts, misses,
                     wall, visual, servo_loop.events)
    # wall-clock judgements, kept out of the events: a lockstep run's events are the same on every machine
    result.over_budget = [line for line in (servo_loop.budget_line(),) if line is not None] + visual_budget_lines(visual)
    return _ended(visual, result)


def visual_budget_lines(visual: VisualStep) -> list[str]:
    """One line per visual-side call of this run that passed its budget (sim.models.api.BUDGETS,
    99th percentiles): a frame's deformation when `sim.servo.loop.too_many_slow_calls` says so of the frames
    that took longer; a grasp likewise (more than 1% of them and at least `SLOW_CALLS_MIN`: one slow
    grasp is not a model's cost)."""
    out = []
    frames = np.asarray(visual.deformation_s) * 1e3
    budget = BUDGETS["deformation_ms_p99"]
    if too_many_slow_calls(over := int((frames > budget).sum()), len(frames)):
        out.append(f"over_budget: deformation: {over} of {len(frames)} frames took over {budget:g} ms (worst {frames.max():.1f} ms); "
                   f"budget: {budget:g} ms at the 99th percentile (docs/models.md)")
    grasps = np.asarray(visual.grasp_s) * 1e3
    budget = BUDGETS["grasp_ms_p99"]
    if too_many_slow_calls(over := int((grasps > budget).sum()), len(grasps)):
        out.append(f"over_budget: grasp: {over} of {len(grasps)} grasps took over {budget:g} ms (worst {grasps.max():.0f} ms); "
                   f"budget: {budget:g} ms (docs/models.md)")
    return out


def _tracker(scene):
    """The hands' targets to follow during a run (None: no hand has one)."""
    tracker = TargetTracker(scene.targets(), [scene.script(i).start for i in range(len(scene.spec.hands))])
    return tracker if tracker.any else None


def _ended(visual: VisualStep, result: RunResult) -> RunResult:
    """The result, with the targets' outcome (which hands held theirs) and what ended it early."""
    if visual.targets is not None:
        result.targets_held = [s is not None and s.held for s in visual.targets.states]
    if visual.finished and result.ended_early is None:
        result.ended_early = visual.finished_why
    return result


def _run_process(scene, model, duration, rate, time_scale, snapshots, pacing, servo, end_on_targets=False) -> RunResult:
    spec = scene.spec
    n_ticks = int(round(duration * rate))
    snapshot_period = 1.0 / spec.renderer.fps if snapshots else None
    visual = VisualStep(model=model, hands=[], events=[], snapshot_period=snapshot_period, targets=_tracker(scene),
                        end_on_targets=end_on_targets)
    state: dict = {"ended_early": None}
    frame = _paced_frame(pacing, duration, rate, state) if pacing is not None else None
    if pacing is not None and pacing.view is not None:
        pacing.view.reset_stats()
    own = servo is None
    sp = ServoProcess(scene, time_scale) if own else servo
    try:
        out, events = sp.run(scene, visual, n_ticks, spec.visual_rate_hz, frame, wait=bool(pacing and pacing.wait_for_grasp),
                             frame_rate=getattr(pacing.view, "max_fps", 60.0) if pacing is not None else 60.0)
    finally:
        if own:
            sp.close()
    names = [h.name for h in spec.hands]
    result = _result(scene, model, "realtime-process", time_scale, duration, rate, names, out.rows, out.starts, out.misses, out.wall,
                     visual, events)
    lines = visual_budget_lines(visual)
    result.events = sorted([*result.events, *(Event(duration, -1, "over_budget", line) for line in lines)], key=lambda e: e.t)
    result.over_budget = [e.detail for e in result.events if e.kind == "over_budget"]
    result.started_by = out.started_by or "clock"
    result.waited_s = float(out.waited_s)
    result.pacer = out.pacer
    result.ended_early = state["ended_early"]
    _ended(visual, result)
    if pacing is not None and pacing.view is not None:
        result.view = pacing.view.stats()
    return result


def _paced_frame(pacing: Pacing, duration: float, rate: float, state: dict):
    """Called for every frame of a paced run (up to the view's `max_fps` a second, between visual
    steps): pointer to the mouse devices, caption, drawing (the hands late-latched), keys.
    Returns "start", "stop" or None."""

    def frame(sp, visual):
        if pacing.on_frame is not None:
            pacing.on_frame(sp)
        view = pacing.view
        keys = []
        if view is not None:
            for i, (target, pressed) in view.pointer_inputs().items():
                sp.set_input(i, target, pressed)
            keys += view.take_keys()
        if pacing.keys is not None:
            keys += pacing.keys()
        started = sp.started()
        while sp.notices:  # e.g. "Right Device needs calibration: put the stylus in its inkwell"
            state["notice"] = sp.notices.pop(0)
            if pacing.notify is not None:
                pacing.notify(state["notice"])
        if view is not None:
            view.set_text(notice=state.get("notice", ""))
            if pacing.caption is not None:
                left = duration - sp.ticks() / rate if started else duration
                view.set_text(**pacing.caption("running" if started else "waiting", max(left, 0.0)))
            view.draw(visual.last, hand_states(visual.hands, visual.targets), sp.read_t, latch=sp.latest)
            if view.closed:
                state["ended_early"] = "window closed"
                return "stop"
        stop = [k for k in keys if k in pacing.stop_keys]
        if stop:
            state["ended_early"] = stop[0]
            return "stop"
        if not started and any(k in pacing.start_keys for k in keys):
            return "start"
        return None

    return frame


def _result(scene, model, mode, time_scale, duration, rate, names, rows, starts, misses, wall, visual, events) -> RunResult:
    rows = np.asarray(rows, dtype=np.float64).reshape(len(rows), -1)
    nh = len(names)
    per_hand = rows[:, 3:].reshape(len(rows), nh, 7) if len(rows) else np.zeros((0, nh, 7))
    return RunResult(
        scene_name=scene.spec.name,
        model=scene.model_spec.name,
        mode=mode,
        time_scale=time_scale,
        duration=duration,
        rate_hz=rate,
        hand_names=names,
        times=rows[:, 0] if len(rows) else np.zeros(0),
        positions=per_hand[:, :, :3],
        forces=per_hand[:, :, 3:6],
        buttons=per_hand[:, :, 6] > 0.5,
        compute_s=rows[:, 1] if len(rows) else np.zeros(0),
        io_latency_s=rows[:, 2] if len(rows) else np.zeros(0),
        intervals_s=np.diff(starts),
        deadline_misses=misses,
        wall_s=wall,
        deformation_s=np.asarray(visual.deformation_s),
        frame_flops=np.asarray(visual.frame_flops, dtype=np.float64),
        grasp_s=np.asarray(visual.grasp_s),
        events=events,
        snapshots=visual.snapshots,
        model_diagnostics=_diagnostics(model, events),
    )


def _diagnostics(model, events: list) -> dict:
    """The model's `diagnostics()` for the run's JSON; one that raises or gives no dict is a
    `model_fault` event and none."""
    try:
        out = model.diagnostics()
        if not isinstance(out, dict):
            raise ValueError(f"returned {type(out).__name__}; allowed: a dict")
        return out
    except Exception as exc:
        events.append(Event(events[-1].t if events else 0.0, -1, "model_fault", f"model_fault: diagnostics: {exc}"))
        return {}


def _run_lockstep(servo: ServoLoop, visual: VisualStep, n_ticks: int, rate: float, visual_rate: float):
    """Every tick, and a visual step after the tick that reaches each frame's time. The quiet
    ticks between frames run compiled where the run allows it (sim/servo/lockstep.py: the same bits),
    the others in Python."""
    try:  # here, not at the top: numba's import cost only where a lockstep run needs it; without numba every tick in Python
        from sim.servo.lockstep import CompiledTicks  # lazy: numba, only for a compiled lockstep run
    except ImportError:
        CompiledTicks = None

    starts = np.empty(n_ticks)
    clock = time.perf_counter
    begin = clock()
    next_visual = 0.0
    frame = 1.0 / visual_rate
    compiled = CompiledTicks.for_loop(servo) if CompiledTicks is not None else None
    k = 0
    while k < n_ticks:
        t = k / rate
        starts[k] = clock()
        if compiled is not None and not compiled.idle and not t + 1e-9 >= next_visual:
            end = k + 1  # the ticks before the one that reaches the next frame
            while end < n_ticks and not end / rate + 1e-9 >= next_visual:
                end += 1
            done = compiled.run(k, end, rate)
            if done:
                starts[k + 1 : k + done] = starts[k]
                k += done
                continue
        servo.tick(t)
        if t + 1e-9 >= next_visual:
            visual(t)
            next_visual += frame
            if compiled is not None:
                compiled.frame()
            if visual.finished:
                return starts[: k + 1], 0, clock() - begin
        k += 1
    return starts, 0, clock() - begin


def write_outputs(result: RunResult, scene, out_dir: Path, progress: Callable[[int, int], None] | None = None) -> int:
    """Pictures (one PNG per snapshot), the force-time plot and the trace CSV. Returns frames written."""
    from sim.run_plots import force_plot, write_trace  # lazy: matplotlib, only when outputs are written

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_trace(result, out_dir / "trace.csv")
    force_plot(result, out_dir / "force.png")
    written = 0
    if scene.spec.renderer.kind == "offscreen" and result.snapshots:
        from sim.view.pictures import render_snapshots  # lazy: offscreen OpenGL and matplotlib, only for snapshots

        written = render_snapshots(result, scene, out_dir, progress=progress)
    return written
