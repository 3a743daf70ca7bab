"""Scene files (TOML) -> frozen specs -> a Scene that builds only what it asks for.

A scene names a mesh, a material, the fixed region, the tissue models it can run (one is the
default), one or two hands with their device backend and scripted pull, the servo and visual
rates, and a renderer (``none`` or ``offscreen``). See docs/scenes.md.
"""

from __future__ import annotations

import copy
import dataclasses
import filecmp
import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from brainsim_assets import path as _asset
from sim.devices import BACKENDS, backend_module
from sim.devices.base import DeviceFrame, OmniSpec, view_rotation
from sim.devices.simulated import PullScript
from sim.errors import SceneError, SimError
from sim.geometry.mesh import BRAIN_MESH, load_mesh
from sim.geometry.patch import GRASP_RADIUS
from sim.material import YOUNG_RANGE, MaterialSpec, material_spec
from sim.models.api import TissueModel, default_options, option_kind
from sim.models.base import POISSON_MAX, POISSON_MIN, Vec3
from sim.models.registry import ModelLoadError, canonical, model_class
from sim.models.registry import names as registry_names
from sim.targets import SAFE_FORCE_N, HandTarget, TargetSpec
from sim.tomlfile import Locator, TomlFileError, read_toml
from sim.tomltable import REQUIRED, SHIPPED, TableReader

RENDERERS = ("none", "offscreen")
DEFAULT_SCENE = _asset("protocols/scenes/brain_pull.toml")
# a run keeps every tick in memory (about 110 bytes per tick for two hands): one hour is
# 0.4 GB, where 1e12 s would have asked for petabytes
MAX_DURATION_S = 3600.0
# Where a scene's points may lie: the brain (0.17 m long) lies within 0.1 m of the scene's origin,
# so a hand's start or a device's origin beyond a metre is a slip of units (mm for m), refused
# before a mesh is searched with it
REACH_M = 1.0
DIRECTION_MAX = 1e3  # a pull, a view's front and up: only their sense counts; larger overflows their norms
AXES = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class FixedSpec:
    """Vertices within `from_bottom` metres of the mesh's lowest point along `axis` are clamped."""

    axis: str
    from_bottom: float


@dataclass(frozen=True)
class ModelSpec:
    """A model as a scene configures it: its name (registered, or "package.module:Class") and
    every option its class declares (`sim.models.api`), defaults filled."""

    name: str
    options: dict = field(default_factory=dict, compare=False)
    # why the model does not load (sim.models.registry), else None: the scene's other models still
    # run, and this one is refused, in one line, when it is asked for
    problem: str | None = field(default=None, compare=False)


@dataclass(frozen=True)
class HandSpec:
    name: str
    device: str
    start: Vec3  # grasp target, snapped to the nearest surface vertex
    pull: Vec3  # pull direction, projected on the surface's tangent plane
    distance: float  # m
    grasp_at: float
    pull_start: float
    pull_time: float
    release_at: float
    device_name: str | None = None  # OpenHaptics device name, e.g. "Default Device" or the configured one
    device_scale: float = 1.0  # scene metres per device metre (the Omni's 160 x 120 x 70 mm workspace)
    device_origin: Vec3 | None = None  # where the device's origin lies in the scene (default: the grasp target)
    trace: Path | None = None  # replay: a recorded run's trace.csv
    trace_hand: str | None = None  # replay: the recorded hand to follow (default: this name)
    target: TargetSpec | None = None  # [hands.target]: pull by a distance along the pull and hold (sim/targets.py)

    def script(self, mesh):
        """The scripted pull on `mesh`: start on the surface, pull along the tangent plane."""
        v = mesh.nearest_vertex(self.start)
        p = mesh.vertices[v]
        n = mesh.vertex_normals[v]
        d = np.asarray(self.pull, dtype=np.float64)
        d = d - np.dot(d, n) * n
        norm = np.linalg.norm(d)
        if norm < 1e-9:
            raise SceneError(f"hands.{self.name}.pull: direction is normal to the surface at the grasp point")
        d = d / norm * self.distance
        return PullScript(
            start=tuple(float(c) for c in p),
            pull=tuple(float(c) for c in d),
            grasp_at=self.grasp_at,
            pull_start=self.pull_start,
            pull_time=self.pull_time,
            release_at=self.release_at,
        )


@dataclass(frozen=True)
class ViewSpec:
    """The participant's camera: it looks along -front with `up` at the brain's centre; real
    devices are aligned with it (device right/up/toward the user = screen right/up/out)."""

    front: Vec3 = (0.0, -0.42, 0.91)  # from above and behind, like the surgeon's view
    up: Vec3 = (0.0, 0.0, 1.0)
    zoom: float = 1.0  # 1: the brain at rest fills the view's height (sim/view/camera.py); 2: twice as large


@dataclass(frozen=True)
class RendererSpec:
    kind: str = "none"
    width: int = 640
    height: int = 480
    fps: float = 10.0  # frames written per simulated second


@dataclass(frozen=True)
class SceneSpec:
    path: Path
    name: str
    description: str
    mesh_path: Path
    material: MaterialSpec
    fixed: FixedSpec
    model: str  # the default model
    models: dict[str, ModelSpec]
    hands: tuple[HandSpec, ...]
    servo_rate_hz: float
    visual_rate_hz: float
    duration: float
    renderer: RendererSpec
    view: ViewSpec = ViewSpec()

    def options_of(self, name: str) -> dict:
        """Model `name`'s options on this scene: its [models.NAME], else the model's declared
        defaults. Raises SceneError naming an option without a default (and ModelLoadError)."""
        name = canonical(name)
        if name in self.models:
            return dict(self.model_spec(name).options)
        try:
            return default_options(model_class(name))
        except ValueError as exc:
            raise SceneError(f"{exc} ({self.path})") from None

    def model_spec(self, name: str | None = None) -> ModelSpec:
        typed = name or self.model
        name = canonical(typed)
        if name not in self.models:  # said as typed: plate--spring, not the plate__spring it was keyed as
            configured = ", ".join(sorted(self.models))
            raise SceneError(f"{self.path}: models.{typed}: not configured in this scene; configured: {configured}")
        if self.models[name].problem is not None:
            raise SceneError(f"{self.path}: models.{name}: {self.models[name].problem}")
        return self.models[name]


# -- parsing -------------------------------------------------------------------------------

SECTIONS = ("scene", "mesh", "material", "fixed", "model", "models", "servo", "visual", "renderer", "view", "hands")
SECTION_KEYS = {  # the sections read as one table, in reading order: (required, allowed keys)
    "scene": (False, ("name", "description", "duration")),
    "mesh": (True, ("path",)),
    "material": (True, ("file", "law", "mu", "mu1", "mu2", "alpha", "bulk_ratio", "young", "poisson", "density", "white_matter", "pia_arachnoid")),
    "fixed": (True, ("axis", "from_bottom")),
    "model": (True, ("name",)),
    "servo": (False, ("rate_hz",)),
    "visual": (False, ("rate_hz",)),
    "renderer": (False, ("kind", "width", "height", "fps")),
    "view": (False, ("front", "up", "zoom")),
}
HAND_KEYS = ("name", "device", "start", "pull", "distance", "grasp_at", "pull_start", "pull_time", "release_at",
             "device_name", "device_scale", "device_origin", "trace", "trace_hand", "target")
TARGET_KEYS = ("distance", "tolerance", "hold", "safe_force")



def load_scene(path: str | Path) -> SceneSpec:
    """Read and validate a scene file (and the parameter files it names). Raises one SceneError
    whose `problems` are every problem found, each 'FILE:LINE: field: message'."""
    path = Path(path)
    try:
        data, loc = read_toml(path)
    except TomlFileError as exc:
        raise SceneError(str(exc)) from None
    problems: list = []
    root = TableReader(path, data, "", loc, problems)
    for key, value in data.items():
        if key not in SECTIONS:
            what = "section" if isinstance(value, (dict, list)) else "key"
            root.error(key, f"unknown {what}; allowed: {', '.join(SECTIONS)}")
    tables = {name: root.table(name, required=required, allowed=allowed) for name, (required, allowed) in SECTION_KEYS.items()}
    models, default_model = _models(root, tables["model"])
    hands = _hands(root)
    spec = _scene_spec(path, tables, models, default_model, hands)
    _raise_problems(problems, path)
    if any(h.target is not None for h in spec.hands):  # needs the mesh: only when the rest is sound
        _check_targets(spec, root, problems)
        _raise_problems(problems, path)
    return spec


def _check_targets(spec: SceneSpec, root: TableReader, problems: list) -> None:
    """Each target within its hand's device workspace: the Omni's 160 x 120 x 70 mm box (times
    `device_scale`) around the device's origin, as a person's device is aligned with the view,
    and as the simulated device's box lies along the scene's axes."""
    scene = Scene(spec)
    half = np.asarray(OmniSpec().workspace_m) / 2.0
    for i, h in enumerate(spec.hands):
        if h.target is None:
            continue
        try:
            target = scene.targets()[i]
        except SceneError as exc:
            root.error(f"hands[{i}].pull", str(exc).split(": ", 1)[-1])
            continue
        point = np.asarray(target.point(scene.script(i).start))
        frame = scene.device_frame(i)
        rel = point - np.asarray(frame.origin)
        in_device = np.asarray(frame.rotation).T @ rel / frame.scale  # R is orthonormal
        box = half * frame.scale
        if np.any(np.abs(in_device) > half + 1e-12) or np.any(np.abs(rel) > box + 1e-12):
            reach = ", ".join(f"{2e3 * b:g}" for b in box)
            root.error(f"hands[{i}].target.distance",
                       f"{h.target.distance:g} m puts the target at {np.round(point * 1e3, 1).tolist()} mm, outside the device's "
                       f"workspace ({reach} mm around {np.round(np.asarray(frame.origin) * 1e3, 1).tolist()} mm); "
                       f"allowed: a target within it (a shorter distance, or a larger device_scale)")


def _models(root: TableReader, model: TableReader) -> tuple[dict[str, ModelSpec], str | None]:
    """The [models.NAME] sections, and the default model [model] names."""
    models_table = root.table("models")
    models: dict[str, ModelSpec] = {}
    spelt: dict[str, str] = {}  # canonical name -> the first spelling of it in the file
    for name in models_table.data:
        first = spelt.setdefault(canonical(name), name)
        if first != name:  # plate-spring and plate_spring are one model: two tables would merge, the last silently winning
            models_table.error(name, f"the same model as [models.{first}] (- and _ spell names alike); configure it once")
            continue
        spec = _model_spec(models_table, name)
        if spec is not None:
            models[canonical(name)] = dataclasses.replace(spec, name=canonical(name))
    if not models_table.data and isinstance(root.data.get("models"), dict):
        models_table.error("", "no model configured")
    default_model = canonical(model.string("name"))
    if default_model is not None and models_table.data and default_model not in {canonical(k) for k in models_table.data}:
        model.error("name", f"{default_model!r} has no [models.{default_model}] section")
    return models, default_model


def _hands(root: TableReader) -> list[HandSpec]:
    """The one or two [[hands]] tables, with distinct names."""
    hands_data = root.data.get("hands", REQUIRED)
    hands: list[HandSpec] = []
    if hands_data is REQUIRED:
        root.error("hands", "missing: a scene needs one or two [[hands]]")
    elif not isinstance(hands_data, list) or not hands_data:
        root.error("hands", "a scene needs one or two [[hands]] tables")
    else:
        if len(hands_data) > 2:
            root.error("hands[2]", f"a scene needs one or two [[hands]] tables, not {len(hands_data)}")
        for k, h in enumerate(hands_data):
            if not isinstance(h, dict):
                root.error(f"hands[{k}]", "must be a table")
                continue
            hand = TableReader(root.path, h, f"hands[{k}].", root.loc, root.problems)
            hands.append(_hand_spec(hand))
            earlier = [j for j, other in enumerate(hands[:-1]) if hands[-1].name is not None and other.name == hands[-1].name]
            if earlier:
                hand.error("name", f"{hands[-1].name!r} is also the name of hands[{earlier[0]}]; hand names must be distinct")
    return hands


def _scene_spec(path: Path, t: dict[str, TableReader], models: dict[str, ModelSpec], default_model: str | None,
                hands: list[HandSpec]) -> SceneSpec:
    """The spec from the scene's sections `t` (a value refused is None; its problem recorded)."""
    scene, mesh, material, fixed, renderer = t["scene"], t["mesh"], t["material"], t["fixed"], t["renderer"]
    mesh_path = mesh.path_value("path")
    if mesh_path is not None and not mesh_path.exists():
        mesh.error("path", f"{mesh_path} does not exist")
    tissue = material_spec(material)
    if tissue.white_matter is not None and mesh_path is not None and mesh_path.is_file() and not filecmp.cmp(mesh_path, BRAIN_MESH, shallow=False):
        # the white surfaces are fsaverage5's: inside another brain they would mark the wrong points
        material.error("white_matter", f"needs the shipped brain surface, whose white surfaces it uses; [mesh] path is {mesh_path.name}; "
                                       "allowed: no white_matter on another surface, or the mesh data/brain_fsaverage5.npz")
    return SceneSpec(
        path=path,
        name=scene.string("name", default=path.stem),
        description=scene.string("description", default=""),
        mesh_path=mesh_path,
        material=tissue,
        fixed=FixedSpec(axis=fixed.string("axis", choices=tuple(AXES)), from_bottom=fixed.number("from_bottom", lo=0.0, hi=REACH_M, unit="m")),
        model=default_model,
        models=models,
        hands=tuple(hands),
        servo_rate_hz=t["servo"].number("rate_hz", default=1000.0, lo=100.0, hi=10000.0),
        visual_rate_hz=t["visual"].number("rate_hz", default=30.0, lo=1.0, hi=240.0),
        duration=scene.number("duration", default=3.0, lo=0.0, lo_open=True, hi=MAX_DURATION_S, unit="s"),
        view=_view_spec(t["view"]),
        renderer=RendererSpec(
            kind=renderer.string("kind", default="none", choices=RENDERERS),
            width=renderer.integer("width", default=640, lo=16, hi=4096),
            height=renderer.integer("height", default=480, lo=16, hi=4096),
            fps=renderer.number("fps", default=10.0, lo=0.0, hi=240.0, lo_open=True),
        ),
    )


def _raise_problems(problems: list, path: Path) -> None:
    """One SceneError of every problem, if any: those of the file `path` in line order, then
    those of the files it names."""
    if problems:
        problems.sort(key=lambda p: (p[0] != path, str(p[0]), p[1]))
        raise SceneError([text for _, _, text in problems])


def _view_spec(view: TableReader) -> ViewSpec:
    d = ViewSpec()
    front = view.vector("front", default=list(d.front), bound=DIRECTION_MAX, unit="", nonzero=True)
    up = view.vector("up", default=list(d.up), bound=DIRECTION_MAX, unit="", nonzero=True)
    if front is not None and up is not None and (
        np.linalg.norm(front) < 1e-9 or np.linalg.norm(np.cross(front, up)) < 1e-6 * np.linalg.norm(front) * max(np.linalg.norm(up), 1e-9)
    ):
        view.error("up", f"{list(up)} must not be zero or parallel to front {list(front)}")
    return ViewSpec(front=front, up=up, zoom=view.number("zoom", default=d.zoom, lo=0.05, hi=5.0))


def _model_spec(models: TableReader, name: str) -> ModelSpec | None:
    try:
        cls = model_class(name)
    except ModelLoadError as exc:
        if canonical(name) in registry_names():  # an installed model that does not load: kept for the line it
            return ModelSpec(canonical(name), {}, problem=str(exc))  # gives when asked for; the scene's other models run
        models.error(name, str(exc))  # a name nothing registers, or a class that does not load: the scene's own mistake
        return None
    return _model_options(models.table(name), name, cls)


def configure(spec: SceneSpec, table: dict, path: Path, loc: Locator, prefix: str) -> SceneSpec:
    """The scene with a study condition's model as the condition configures it: the scene's
    [models.MODEL] (or, where the scene has none, the model's declared defaults) with the condition's `table` (a protocol's [conditions.NAME]: `model` and the
    keys to change) on top, and `young` / `poisson` on the material. Every key is checked as the
    scene's own are, its problems named with the protocol's `path` and lines (`prefix`:
    "conditions.NAME."); raises one SceneError with all of them."""
    model = canonical(table["model"])
    cls = model_class(model)  # the protocol's checker loaded it already
    option_keys = tuple(f.name for f in dataclasses.fields(cls.Options))
    overrides = {k: v for k, v in table.items() if k != "model"}
    problems: list = []
    reader = TableReader(path, overrides, prefix, loc, problems)
    reader.keys(("model",) + option_keys + cls.material_keys)
    data, _ = read_toml(spec.path)
    scene_tables = {canonical(k): v for k, v in data.get("models", {}).items()}
    base = dict(scene_tables[model]) if model in spec.models else {}  # not in the scene: the model's declared defaults
    for f in dataclasses.fields(cls.Options):  # the scene's relative paths stay relative to the scene
        key = f.name
        if isinstance(base.get(key), str) and _file_option(f) and not Path(base[key]).is_absolute() and not base[key].startswith(SHIPPED):
            base[key] = str((spec.path.parent / base[key]).resolve())
    merged_problems: list = []
    merged = TableReader(path, base | {k: v for k, v in overrides.items() if k in option_keys}, prefix, loc, merged_problems)
    model_spec = _model_options(merged, model, cls)
    for file, line, text in merged_problems:  # a key the condition left to the scene: say so
        key = text.split(": ")[1].rsplit(".", 1)[-1] if text.count(": ") >= 2 else ""
        if key in base and key not in overrides:
            text += f" (the scene's {key} = {base[key]!r}, with this condition's options)"
        problems.append((file, line, text))
    material = spec.material
    young = reader.number("young", default=material.young, lo=YOUNG_RANGE[0], hi=YOUNG_RANGE[1], unit="Pa")
    poisson = reader.number("poisson", default=material.poisson, lo=POISSON_MIN, hi=POISSON_MAX, hi_open=True)
    _raise_problems(problems, path)
    material = dataclasses.replace(material, young=young, poisson=poisson)
    return dataclasses.replace(spec, material=material, model=model, models={**spec.models, model: model_spec})


def _file_option(f) -> bool:
    """An option whose string value may name a file relative to the scene (a path, or a table
    that may be given as a file, like the plate-spring's `params`)."""
    return option_kind(f) in ("path", "other")


def _model_options(table: TableReader, name: str, cls) -> ModelSpec | None:
    options = cls.read_options(table)
    return None if options is None else ModelSpec(name=name, options=options)


def _hand_spec(h: TableReader) -> HandSpec:
    h.keys(HAND_KEYS)
    name = h.string("name")
    most = MAX_DURATION_S  # a hand's times lie within the longest run
    grasp_at = h.number("grasp_at", default=0.2, lo=0.0, hi=most, unit="s")
    after_grasp = 0.0 if grasp_at is None else grasp_at  # bound of the later times (grasp_at refused: 0)
    pull_start = h.number("pull_start", default=None if grasp_at is None else grasp_at + 0.2, lo=after_grasp, hi=most, unit="s")
    pull_time = h.number("pull_time", default=1.0, lo=0.0, lo_open=True, hi=most, unit="s")
    release_default = None if pull_start is None or pull_time is None else pull_start + pull_time + 0.5
    release_at = h.number("release_at", default=release_default, lo=after_grasp, lo_open=True, hi=most, unit="s")
    return HandSpec(
        name=name,
        device=h.string("device", default="simulated", choices=tuple(BACKENDS)),
        start=h.vector("start", bound=REACH_M),
        pull=h.vector("pull", bound=DIRECTION_MAX, unit="", nonzero=True),
        distance=h.number("distance", lo=0.0, hi=0.2),
        grasp_at=grasp_at,
        pull_start=pull_start,
        pull_time=pull_time,
        release_at=release_at,
        device_name=h.string("device_name", default=None) if "device_name" in h.data else None,
        device_scale=h.number("device_scale", default=1.0, lo=0.1, hi=10.0),
        device_origin=h.vector("device_origin", bound=REACH_M) if "device_origin" in h.data else None,
        trace=h.path_value("trace") if "trace" in h.data else None,
        trace_hand=h.string("trace_hand") if "trace_hand" in h.data else None,
        target=_target_spec(h.table("target", allowed=TARGET_KEYS)) if "target" in h.data else None,
    )


def _target_spec(t: TableReader) -> TargetSpec | None:
    spec = TargetSpec(
        distance=t.number("distance", lo=0.0, hi=0.2, lo_open=True),
        tolerance=t.number("tolerance", default=0.002, lo=0.0, hi=0.05, lo_open=True),
        hold=t.number("hold", default=0.5, lo=0.0, hi=60.0),
        safe_force=t.number("safe_force", default=SAFE_FORCE_N, lo=0.0, hi=3.3, lo_open=True),
    )
    if spec.distance is not None and spec.tolerance is not None and spec.tolerance >= spec.distance:
        t.error("tolerance", f"{spec.tolerance:g} m is not below the distance {spec.distance:g} m; allowed: (0, distance)")
    return spec


# -- the runtime scene ---------------------------------------------------------------------


class Scene:
    """What a scene file asks for, built on demand: mesh, one model, one device per hand."""

    def __init__(self, spec: SceneSpec, model: str | None = None):
        self.spec = spec
        self.model_spec = spec.model_spec(model)
        self.operators = None  # optional PullScripts replacing the scripted hands (simulated devices)
        self.device_names: list[str] | None = None  # OpenHaptics names given on the command line

    def with_device(self, device: str | None) -> Scene:
        """Every hand on `device` (this scene, changed in place; None keeps the file's)."""
        if device is not None and any(h.device != device for h in self.spec.hands):
            if device not in BACKENDS:
                raise SceneError(f"device: {device!r} is not one of simulated, mouse, openhaptics, replay")
            hands = tuple(dataclasses.replace(h, device=device) for h in self.spec.hands)
            self.spec = dataclasses.replace(self.spec, hands=hands)
        return self

    def with_stiffness(self, scale: float) -> Scene:
        """This scene with its tissue model's stiffness times `scale` (the model's
        `with_stiffness`: Young's modulus for the FEM and the mass-spring, the plates' E for
        the plate-spring); the spec, mesh and devices' settings shared."""
        out = copy.copy(self)
        out.model = self.model.with_stiffness(scale)  # the cached_property's slot: this scene's own model
        return out

    def device_name(self, i: int) -> str:
        """The OpenHaptics device name of hand i: set with `devices` (the CLI's --devices), the
        scene's `device_name`, else "Default Device" for a one-hand scene or the names the
        vendor's configuration tool suggests for two ("Left Device", "Right Device")."""
        if self.device_names is not None:
            return self.device_names[i]
        h = self.spec.hands[i]
        if h.device_name:
            return h.device_name
        return "Default Device" if len(self.spec.hands) == 1 else ("Left Device", "Right Device")[i]

    def device_frame(self, i: int):
        """Hand i's real device in the scene: aligned with the view, scaled, its origin at the
        hand's `device_origin` (default: its grasp target on the surface)."""
        h = self.spec.hands[i]
        origin = h.device_origin if h.device_origin is not None else self.script(i).start
        return DeviceFrame(rotation=view_rotation(self.spec.view.front, self.spec.view.up), scale=h.device_scale, origin=tuple(origin))

    def targets(self) -> list[HandTarget | None]:
        """Each hand's target on this scene's mesh (None: the free pull), its direction the
        scene's pull projected on the surface's tangent plane at the grasp point."""
        out = []
        for h in self.spec.hands:
            if h.target is None:
                out.append(None)
                continue
            pull = np.asarray(h.script(self.mesh).pull, dtype=np.float64)
            out.append(HandTarget(spec=h.target, direction=tuple(float(c) for c in pull / np.linalg.norm(pull))))
        return out

    def script(self, i: int):
        """The scripted operator of hand i: the scene's, or the one set in `operators`."""
        if self.operators is not None:
            return self.operators[i]
        return self.spec.hands[i].script(self.mesh)

    @cached_property
    def mesh(self):
        return load_mesh(self.spec.mesh_path)

    @cached_property
    def fixed_mask(self) -> np.ndarray:
        axis = AXES[self.spec.fixed.axis]
        z = self.mesh.vertices[:, axis]
        return z <= z.min() + self.spec.fixed.from_bottom

    @cached_property
    def model(self):
        try:
            cls = model_class(self.model_spec.name)
        except ModelLoadError as exc:
            raise SceneError(str(exc)) from None
        try:
            model = cls.build(self.mesh, self.model_spec.options, self)
        except SimError:
            raise
        except Exception as exc:  # a lab's model may fail in any way: one line naming it
            raise SceneError(f"model {self.model_spec.name!r}: build raised {type(exc).__name__}: {exc}") from None
        if not isinstance(model, TissueModel):
            raise SceneError(f"model {self.model_spec.name!r}: build gave a {type(model).__name__}, not a sim.models.api.TissueModel")
        # the surface's search structures now, whatever the model did: a model that queries the
        # surface only in `grasp` would pay SciPy's graph import and the edge graph in a run's first grasp
        self.mesh.prepare_queries()
        return model

    def open_devices(self) -> list:
        """One device per hand; hands on the same backend open together (one OpenHaptics rig)."""
        devices: list = [None] * len(self.spec.hands)
        for backend in dict.fromkeys(h.device for h in self.spec.hands):
            idx = [i for i, h in enumerate(self.spec.hands) if h.device == backend]
            hands = [self.spec.hands[i] for i in idx]
            if backend == "simulated":
                opened = backend_module(backend).open_devices(hands, self.mesh, [self.script(i) for i in idx])
            else:
                opened = backend_module(backend).open_devices(hands, self.mesh)
            for i, d in zip(idx, opened):
                devices[i] = d
        return devices


def build_scene(path: str | Path, model: str | None = None) -> Scene:
    return Scene(load_scene(path), model)


def clamp_limit(scene) -> tuple[int, float]:
    """(axis, height): the scene's clamp, as `sim.models.fem.fixed_nodes` applies it to a
    volume: nodes at or below the highest surface vertex of the scene's fixed region."""
    axis = AXES[scene.spec.fixed.axis]
    mask = scene.fixed_mask
    return axis, (float(scene.mesh.vertices[mask, axis].max()) if mask.any() else -math.inf)


def grasp_radius(scene) -> float:
    """The grasp patch's radius the scene's FEM uses (the default where it names none): also
    the reference's, the stiffness field's and the observer truth's, so all hold the same patch."""

    fem = scene.spec.models.get("fem")
    return float(fem.options.get("grasp_radius", GRASP_RADIUS)) if fem else GRASP_RADIUS
