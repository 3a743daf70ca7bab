"""The tissue-model API, version 1: what a model gives the platform and what the platform asks.

A model is a class registered under the entry-point group ``brainsim.models`` (name -> class,
`sim.models.registry`) or named in a scene as ``"package.module:Class"``. Subclass
`TissueModel`; the platform calls nothing that this class does not declare. Everything a model
needs is imported from here: `TissueModel`, `option`, `Contact`, the laws (`Linearised`,
`RadialTable`, `TensorTable`, `Coupling`, `Constant`, and `PairTable` for ``pair_law``), `BUDGETS`,
`MAX_PULL_M`.

Declared by the class (read when a scene or protocol names the model, before anything builds):

| attribute          | meaning                                                                    |
|--------------------|----------------------------------------------------------------------------|
| ``api_version``    | the API it was written for; a model of another version does not load       |
| ``description``    | one line for `studyctl model list`                                         |
| ``Options``        | a frozen dataclass: one field per scene option, declared with `option()`   |
| ``material_keys``  | the scene's material keys a study condition may change (``young``, ...)    |
| ``scales_stiffness`` | True when ``with_stiffness`` is given (the discrimination task needs it) |
| ``uses_time``      | True when the force depends on time or the hand's velocity (below)         |
| ``build(mesh, options, scene)`` | the running model (default: ``cls(mesh, options, scene)``)    |

Asked of a running model (three calls at three rates, budgets in `BUDGETS`). A model writes
``grasp`` and ``deformation``; it writes ``force`` unless every contact it gives carries a
``law``, which the inherited ``force`` evaluates. Every return value is checked where it is used
(`contact_checked`, `surface_checked` in `sim.models.base`, the servo's three numbers): a wrong one is
zero force and a ``model_fault`` event.

| call                                      | when                          | returns                          |
|-------------------------------------------|-------------------------------|----------------------------------|
| ``grasp(point, hand) -> Contact``         | a hand closes on the tissue   | the contact (`Contact`, here)    |
| ``force(contact, displacement)``          | every servo tick (1 kHz)      | force on the hand, N, 3 floats   |
| ``deformation(contacts, displacements)``  | every visual frame            | (n_vertices, 3) surface motion   |

Optional capabilities, each with its default here (override what the model has):
``reset()`` back to rest before each run (no-op); ``diagnostics()`` a dict for the run's JSON
(empty); ``frame_flops`` counted work of the last frame (NaN: not counted); ``unstable`` the
model's state blew up, the servo renders zero force (False); ``forces(contacts, displacements)``
several contacts at once, for coupled contacts (one `force` each); ``pair_law(contacts)`` the
law of two coupled contacts for a servo in another process (None); ``tick_laws(contacts)``
the laws whose ``force(d)`` are the model's forces now, which a lockstep servo may evaluate
compiled (`sim/servo/lockstep.py`; the contacts' laws when ``force`` and ``forces`` are the defaults
here, else None); ``with_stiffness(scale)``
the same model with every force times `scale`, for the discrimination task (declare
``scales_stiffness = True``); ``surface`` a surface of its own that `deformation` moves
(None: the scene's mesh).

**Time.** A model that declares ``uses_time = True`` is also told the time and each hand's
velocity: ``force(contact, displacement, velocity=v, t=t)``, ``forces(contacts, displacements,
velocities=vs, t=t)`` and ``deformation(contacts, displacements, velocities=vs, t=t)``, with `t`
the run's time in seconds (the servo tick's, or the visual frame's) and `v` the hand's velocity
in m/s as the servo estimates it from the positions it reads (`sim.servo.velocity`: CHAI3D's
15 ms window; an Omni's 55 um position steps make it move in steps of 3.7 mm/s, and it lags a
change of speed by 7.5 ms). Its contact laws, if it gives them, declare ``uses_time = True``
and take ``force(d, v, t)`` (a servo in another process calls them so). Every
tick of such a model runs in Python (the compiled lockstep ticks know only laws of `d`). A model
that does not declare it is called as above, without them.

**The per-tick law.** A servo in another process (a person's session) cannot call the model:
it evaluates ``contact.law.force(d)``, a small picklable object from `sim.laws` (or the model's
own, with ``force(d)`` and ``update(**state)``), sent at the grasp and again after every frame.
A model that only writes ``force`` and leaves ``contact.law`` as None gets `ModelForce`: a copy
of the model, as it was at the grasp, pickled to the servo with everything it holds, the scene's
mesh included, at each grasp (what that costs: docs/models.md); a model whose force changes
between frames, or that holds much, gives a law and updates it in ``deformation``.
"""

from __future__ import annotations

import dataclasses
import math
import pickle
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from sim.errors import SimError
from sim.laws import Constant, Coupling, Linearised, PairTable, RadialTable, TensorTable
from sim.models.base import BUDGETS, MAX_PULL_M, Contact, Vec3
from sim.tomltable import REQUIRED

# everything a model's author imports, from this one module (docs/models.md)
__all__ = ["API_VERSION", "BUDGETS", "MAX_PULL_M", "CapabilityError", "Constant", "Contact", "Coupling", "Linearised", "NoOptions",
           "PairTable", "RadialTable", "TensorTable", "TissueModel", "Vec3", "default_options", "option", "read_options"]

API_VERSION = 1



class CapabilityError(SimError):
    """A model asked for a capability it does not declare."""


def option(default: Any = dataclasses.MISSING, *, unit: str = "", lo: float | None = None, hi: float | None = None,
           lo_open: bool = False, hi_open: bool = False, choices: tuple | None = None, doc: str = "") -> Any:
    """A field of a model's ``Options``: its default, unit, bounds (closed unless ``lo_open`` /
    ``hi_open``) or choices, and a line of help. The scene reader checks every value against
    these, naming FILE:LINE and the allowed range."""
    meta = {"unit": unit, "lo": lo, "hi": hi, "lo_open": lo_open, "hi_open": hi_open, "choices": choices, "doc": doc}
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class NoOptions:
    """A model without options."""


@dataclass(frozen=True)
class OptionInfo:
    """One declared option, as `studyctl model describe` prints it."""

    name: str
    kind: str  # number | integer | string | path | table
    default: Any
    unit: str
    allowed: str
    doc: str


KINDS = {"float": "number", "int": "integer", "str": "string", "bool": "boolean", "Path": "path"}  # declared type -> kind


def option_kind(f) -> str:
    """The kind of option field `f` from its declared type (`float`, `int`, `str`, `bool`,
    `Path`, each optionally `| None`); "other" for any other type (a class with its own
    `read_options` may declare those)."""
    t = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
    parts = [p.strip() for p in t.split("|") if p.strip() != "None"]
    return KINDS.get(parts[0], "other") if len(parts) == 1 else "other"


def declaration_problem(cls) -> str | None:
    """Why `cls` does not declare its options as the API asks, or None."""
    if not (isinstance(cls.Options, type) and dataclasses.is_dataclass(cls.Options)):
        return "Options is not a dataclass"
    if "read_options" in vars(cls):  # the class reads its own options
        return None
    bad = [f"{f.name} ({f.type})" for f in dataclasses.fields(cls.Options) if option_kind(f) == "other"]
    if bad:
        return f"option{'s' if len(bad) > 1 else ''} {', '.join(bad)} of a type the scene reader does not know; allowed: {', '.join(KINDS)} (or None with them)"
    return None


def _default_outside(default, meta: dict, kind: str) -> bool:
    """Whether `default` lies outside the bounds or choices its own declaration gives."""
    if meta.get("choices"):
        return default not in meta["choices"]
    if kind not in ("number", "integer"):
        return False
    if isinstance(default, bool) or not isinstance(default, (int, float)) or (kind == "integer" and not isinstance(default, int)):
        return True
    if not math.isfinite(default):
        return True
    lo, hi = meta.get("lo"), meta.get("hi")
    below = lo is not None and (default < lo or (meta.get("lo_open") and default == lo))
    above = hi is not None and (default > hi or (meta.get("hi_open") and default == hi))
    return bool(below or above)


def default_problem(cls) -> str | None:
    """Why the defaults `cls` declares cannot run (a default outside its own bounds or choices, or
    defaults its ``Options`` refuses together), or None. Read when the model loads, so a bad
    declaration is one line in `model list`, not a fault found later by a scene or a check."""
    fields = dataclasses.fields(cls.Options)
    for f in fields:
        if f.default is dataclasses.MISSING or f.default is None:
            continue
        kind = option_kind(f)
        if _default_outside(f.default, dict(f.metadata), kind):
            return f"option {f.name}: its default {f.default!r} is outside its own declaration; allowed: {_allowed(dict(f.metadata), kind)}"
    if all(f.default is not dataclasses.MISSING for f in fields):
        try:
            cls.Options()
        except (ValueError, TypeError) as exc:
            return f"options: the declared defaults are refused by Options itself: {exc}"
    return None


def _allowed(meta: dict, kind: str) -> str:
    if meta.get("choices"):
        return ", ".join(map(str, meta["choices"]))
    lo, hi = meta.get("lo"), meta.get("hi")
    if lo is None and hi is None:
        return "any" if kind != "path" else "a file"
    if kind == "integer":
        return f"{lo if lo is not None else '-inf'}..{hi if hi is not None else 'inf'}"
    left, right = "(" if meta.get("lo_open") or lo is None else "[", ")" if meta.get("hi_open") or hi is None else "]"
    return f"{left}{lo if lo is not None else -math.inf:g}, {hi if hi is not None else math.inf:g}{right}"


def options_of(cls) -> list[OptionInfo]:
    """The options `cls` declares, in order."""
    out = []
    for f in dataclasses.fields(cls.Options):
        kind = option_kind(f)
        default = None if f.default is dataclasses.MISSING else f.default
        out.append(OptionInfo(f.name, kind, default, f.metadata.get("unit", ""), _allowed(dict(f.metadata), kind), f.metadata.get("doc", "")))
    return out


def read_options(cls, table) -> dict | None:
    """The options of model class `cls` from a scene's table (a `sim.tomltable.TableReader`):
    unknown keys, types and bounds checked from the declaration, then the class's own checks
    (``Options.__post_init__`` raising ValueError "key: message"). Problems are recorded on
    `table`; returns the values as a dict (every option, defaults filled) or None."""
    fields = dataclasses.fields(cls.Options)
    table.keys(tuple(f.name for f in fields))
    values, ok = {}, True
    for f in fields:
        m = f.metadata
        kind = option_kind(f)
        default = f.default if f.default is not dataclasses.MISSING else REQUIRED
        if kind == "number":
            v = table.number(f.name, default=default, lo=-math.inf if m.get("lo") is None else m["lo"],
                             hi=math.inf if m.get("hi") is None else m["hi"], lo_open=m.get("lo_open", False), hi_open=m.get("hi_open", False))
        elif kind == "integer":
            v = table.integer(f.name, default=default, lo=-(1 << 62) if m.get("lo") is None else m["lo"], hi=(1 << 62) if m.get("hi") is None else m["hi"])
        elif kind == "string":
            v = table.string(f.name, default=default, choices=m.get("choices"))
        elif kind == "path":
            v = table.path_value(f.name) if f.name in table.data else (None if default is None else default)
            if v is not None and f.name in table.data and not Path(v).is_file():
                table.error(f.name, f"{v}: no such file")
                v = None
        elif kind == "boolean":
            v = table.data.get(f.name, default)
            if v is REQUIRED:
                table.error(f.name, "missing")
                v = None
            elif not isinstance(v, bool) and v is not None:
                v = table.error(f.name, f"{v!r} is not true or false")
        else:  # a class with its own read_options reads these
            v = table.data.get(f.name, None if default is REQUIRED else default)
        if v is not None and m.get("choices") and kind != "string" and v not in m["choices"]:
            v = table.error(f.name, f"{v!r} is not one of {', '.join(map(str, m['choices']))}")
        if v is None and not (f.default is None and f.name not in table.data):
            ok = False
        values[f.name] = v
    if not ok:
        return None
    try:
        return _as_dict(cls.Options(**values))
    except (ValueError, TypeError) as exc:
        key, sep, rest = str(exc).partition(": ")
        if sep and key in values:
            table.error(key, rest)
        else:
            table.error("", str(exc))
        return None


def default_options(cls) -> dict:
    """Every option of model class `cls` at its declared default (what a scene that does not
    configure the model runs). Raises ValueError naming an option without a default."""
    missing = [f.name for f in dataclasses.fields(cls.Options) if f.default is dataclasses.MISSING]
    if missing:
        raise ValueError(f"model {cls.__name__}: option{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                         f"{'have' if len(missing) > 1 else 'has'} no default; configure the model in the scene")
    return _as_dict(cls.Options())


def _as_dict(options) -> dict:
    """The options' values, shallow (a nested dataclass such as parameters stays itself)."""
    return {f.name: getattr(options, f.name) for f in dataclasses.fields(options)}


class TissueModel:
    """Base of every tissue model: the declaration (class attributes) and the optional
    capabilities' defaults. See the module's docstring for the contract."""

    api_version: ClassVar[int] = API_VERSION
    description: ClassVar[str] = ""
    Options: ClassVar[type] = NoOptions
    material_keys: ClassVar[tuple[str, ...]] = ()
    scales_stiffness: ClassVar[bool] = False
    uses_time: ClassVar[bool] = False

    name: str = ""
    mesh: Any = None  # the scene's surface mesh (sim.geometry.mesh.Mesh)
    surface: Any = None  # a surface of the model's own that `deformation` moves (None: `mesh`)
    frame_flops: float = math.nan
    unstable: bool = False

    @classmethod
    def build(cls, mesh, options: dict, scene) -> TissueModel:
        """The running model on the scene's `mesh` with the scene's `options` (every declared
        option, as `read_options` gives them; `scene`: `sim.scene.Scene`, for its material,
        clamp and rates)."""
        return cls(mesh, options, scene)

    @classmethod
    def read_options(cls, table) -> dict | None:
        """The options from a scene's table, checked against ``Options`` (`read_options`)."""
        return read_options(cls, table)

    @classmethod
    def configuration(cls, options: dict) -> dict:
        """What a study stores (and hashes) of a condition of this model: its options. A model
        whose options hold files or parameter sets may say more."""
        return {"options": options}

    # -- the contract --------------------------------------------------------------------------
    def grasp(self, point: Sequence[float], hand: int = 0) -> Contact:
        raise NotImplementedError(f"{type(self).__name__}.grasp")

    def force(self, contact: Contact, displacement: Sequence[float], velocity: Sequence[float] | None = None,
              t: float | None = None) -> Vec3:
        if velocity is None:
            return contact.law.force(displacement)
        return law_force_at(contact.law, displacement, velocity, t)  # a law of d alone is asked as one

    def deformation(self, contacts: Sequence[Contact], displacements) -> np.ndarray:
        raise NotImplementedError(f"{type(self).__name__}.deformation")

    # -- optional capabilities -----------------------------------------------------------------
    def reset(self) -> None:
        """Back to rest (every run starts from undeformed tissue)."""

    def diagnostics(self) -> dict:
        return {}

    def forces(self, contacts: Sequence[Contact], displacements, velocities=None, t: float | None = None) -> list[Vec3]:
        force = self.force
        if velocities is None:
            return [force(c, d) for c, d in zip(contacts, displacements)]
        return [force(c, d, velocity=v, t=t) for c, d, v in zip(contacts, displacements, velocities)]

    def pair_law(self, contacts: Sequence[Contact]):
        return None

    def tick_laws(self, contacts: Sequence[Contact]) -> list | None:
        """The laws whose ``force(d)`` are ``forces(contacts, d)`` now (a servo may evaluate
        them itself: the compiled lockstep ticks, sim/servo/lockstep.py), or None where the model
        computes its forces otherwise. A model overriding ``force`` or ``forces`` says so here."""
        if self.uses_time:  # a law of d alone cannot be one of time
            return None
        if type(self).force is TissueModel.force and type(self).forces is TissueModel.forces and all(c.law is not None for c in contacts):
            return [c.law for c in contacts]
        return None

    def with_stiffness(self, scale: float) -> TissueModel:
        raise CapabilityError(f"model {self.name!r} does not scale its stiffness (the discrimination task needs it)")

    def surface_mesh(self):
        """The surface `deformation` moves."""
        return self.surface if self.surface is not None else self.mesh

    def law(self, contact: Contact):
        """What a servo in another process evaluates for `contact`: its law, else `ModelForce`."""
        return contact.law if contact.law is not None else ModelForce(self, dataclasses.replace(contact, law=None))


@dataclass
class ModelForce:
    """The law of a model that only writes ``force``: the model itself (a copy, as it was at
    the grasp) called with the contact."""

    model: Any
    contact: Contact

    @property
    def uses_time(self) -> bool:
        """The model's own declaration: a servo tells this law the velocity and the time."""
        return bool(self.model.uses_time)

    def force(self, d, v=None, t=None) -> Vec3:
        if v is None:
            return self.model.force(self.contact, d)
        return self.model.force(self.contact, d, velocity=v, t=t)

    def update(self, **_) -> None:  # the copy is the model at the grasp
        pass


REST = (0.0, 0.0, 0.0)


def force_at(model: TissueModel, contact: Contact, displacement, velocity=REST, t: float = 0.0) -> Vec3:
    """`model`'s force as a servo asks for it: told the hand's velocity (m/s) and the time (s)
    when the model uses time, without them when not (the checks and benches call this)."""
    if model.uses_time:
        return model.force(contact, displacement, velocity=velocity, t=t)
    return model.force(contact, displacement)


def law_force_at(law, displacement, velocity=REST, t: float = 0.0) -> Vec3:
    """A per-tick law's force as a servo in another process asks for it (`force_at`'s rule)."""
    return law.force(displacement, velocity, t) if getattr(law, "uses_time", False) else law.force(displacement)


def deformation_at(model: TissueModel, contacts, displacements, velocities=None, t: float = 0.0):
    """`model`'s deformation as a visual frame asks for it (`force_at`'s rule; hands at rest
    where `velocities` is None)."""
    if model.uses_time:
        return model.deformation(contacts, displacements, velocities=velocities or [REST] * len(contacts), t=t)
    return model.deformation(contacts, displacements)


def servo_law(model: TissueModel, contact: Contact) -> tuple[Any, str | None]:
    """(the law a servo in another process gets for `contact`, checked to pickle; or None and
    why it cannot have one: the model's `law` raised, or its copy does not pickle)."""
    try:
        law = model.law(contact)
        pickle.dumps(law)
    except Exception as exc:  # a lab's model may fail in any way: a fault, never a crash
        return None, f"{type(exc).__name__}: {exc}"
    return law, None


def servo_laws(model: TissueModel, contacts: Sequence[Contact]) -> list | None:
    """`model.tick_laws(contacts)`, None where it raises (the Python tick then logs the fault)."""
    try:
        laws = model.tick_laws(contacts)
    except Exception:
        return None
    return list(laws) if laws is not None and len(laws) == len(contacts) else None


def servo_state(model: TissueModel, contacts: Sequence[Contact]) -> tuple[Any, bool, str | None]:
    """(the pair law of two coupled contacts or None, whether the model is unstable, the fault
    or None): what a servo in another process needs after a frame; a model that raises here is
    taken as unstable (zero force)."""
    try:
        # a pair table is a law of the two displacements alone: a model that uses time has none
        pair = model.pair_law(contacts) if len(contacts) == 2 and not model.uses_time else None
        return pair, bool(model.unstable), None
    except Exception as exc:
        return None, True, f"{type(exc).__name__}: {exc}"
