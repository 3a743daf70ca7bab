"""The three built-in models as the API declares a model (`sim.models.api`): their options,
material keys and capabilities, in a module light enough for every scene reader. Each running
class (`PlateSpringModel`, `FemModel`, `MassSpringModel`) subclasses its declaration here, and
`build` imports it only when a scene runs the model. Registered in pyproject.toml like a plugin."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim.devices.base import OmniSpec
from sim.models.api import TissueModel, option, read_options
from sim.patch import GRASP_RADIUS
from sim.tomltable import REQUIRED

PLATE_SPRING_VARIANTS = ("paper", "continuous", "located")  # "located": the continuous stack with a stiffness field
FEM_FORMULATIONS = ("linear", "corotational")
MASS_SPRING_INTEGRATORS = ("explicit", "implicit", "local-global")
MASS_SPRING_ACCELERATIONS = ("none", "chebyshev", "anderson", "newton")  # of local-global; newton: sim/models/newton.py
OMNI_MAX_STIFFNESS = OmniSpec().max_stiffness_n_per_m  # 700 N/m: stable closed-loop stiffness at 1 kHz


# -- plate-spring --------------------------------------------------------------------------------

@dataclass(frozen=True)
class PlateSpringOptions:
    variant: str = option("continuous", choices=PLATE_SPRING_VARIANTS, doc="the paper's stack, the continuous one, or located (with a stiffness field)")
    params: Any = option(None, doc="the stack's parameters: a TOML file or an inline table (sim/models/plate_spring.py)")
    field: Path | None = option(None, doc="stiffness field (`studyctl calibrate field`); located only; default: the shipped one")


class PlateSpringBase(TissueModel):
    description = "the paper's plate-spring stack over a geodesic disc (Eqs. 1-18)"
    Options = PlateSpringOptions
    material_keys = ()  # the stack's E is its own (in `params`), not the tissue's
    scales_stiffness = True

    @classmethod
    def read_options(cls, table) -> dict | None:
        """The declared options, with `params` a file or an inline table checked by the stack's
        own bounds (problems named by that file's lines)."""
        raw = table.data.get("params", REQUIRED)
        fields = {k: v for k, v in table.data.items() if k != "params"}
        own = type(table)(table.path, fields, table.prefix, table.loc, table.problems, table.refused)
        values = read_options(cls, own)
        params = None
        if isinstance(raw, str):
            params = _params_file(table, table.path_value("params"))
        elif isinstance(raw, dict):
            params = _plate_spring_params(table.table("params"))
        elif raw is REQUIRED:
            table.error("params", "missing: a parameter file (a path) or an inline table")
        else:
            table.error("params", f"{raw!r} is neither a parameter file (a path) nor a table")
        if values is None or params is None:
            return None
        return values | {"params": params}

    @classmethod
    def build(cls, mesh, options: dict, scene):
        from sim.models.plate_spring import PlateSpringModel

        field = None
        if options["variant"] == "located":
            from sim.field import FIELD_FILE, load_field

            field = load_field(options["field"] or FIELD_FILE, mesh)
        return PlateSpringModel(mesh, options["params"], options["variant"], field)

    @classmethod
    def configuration(cls, options: dict) -> dict:
        out = {"options": {"field": options["field"]} if options["field"] is not None else {},
               "variant": options["variant"], "plate_spring": options["params"]}
        if options["variant"] == "located" and options["field"] is None:  # the shipped stiffness field it loads
            from sim.field import FIELD_FILE

            out["field"] = Path(FIELD_FILE) if Path(FIELD_FILE).exists() else None
        return out


def _params_file(table, path: Path | None):
    """The plate-spring parameter file a scene names, its problems named by that file's lines."""
    from sim.tomlfile import TomlFileError, read_toml

    if path is None:
        return None
    if not path.is_file():
        return table.error("params", f"{path} does not exist" if not path.exists() else f"{path} is not a file")
    try:
        data, loc = read_toml(path)
    except TomlFileError as exc:
        table.problems.append((path, 0, str(exc)))
        return None
    return _plate_spring_params(type(table)(path, data, "", loc, table.problems))


def _plate_spring_params(r):
    """PlateSpringParams from a table (a parameter file or an inline table): unknown, missing
    and non-numeric keys are all reported; then the first value out of range (the checks of
    PlateSpringParams, some of which relate several keys)."""
    import dataclasses

    from sim.errors import ParameterError
    from sim.models.plate_spring import PlateSpringParams

    keys = tuple(f.name for f in dataclasses.fields(PlateSpringParams))
    r.keys(keys)
    values, missing = {}, [key for key in keys if key not in r.data]
    if missing:
        r.error("", f"missing key{'s' if len(missing) > 1 else ''} {', '.join(missing)}; required: {', '.join(keys)}")
    ok = not missing
    for key in keys:
        v = values[key] = r.data.get(key, REQUIRED)
        if v is REQUIRED:
            continue
        if key == "layers" and (isinstance(v, bool) or not isinstance(v, int)):
            r.error(key, f"{v!r} is not an integer")
        elif key != "layers" and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
            r.error(key, f"{v!r} is not a finite number")
        else:
            continue
        ok = False
    if not ok:
        return None
    try:
        return PlateSpringParams.from_mapping(values, source="")
    except ParameterError as exc:
        message = str(exc).removeprefix(": ")
        key, sep, rest = message.partition(": ")
        if sep and key in keys:
            r.error(key, rest)
        else:
            r.error("", message)
        return None


# -- FEM -----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FemOptions:
    # the defaults: P2 on the shipped 8 mm body-fitted mesh; the corotational update runs on P1 only
    resolution: float = option(0.008, unit="m", lo=0.003, hi=0.008, doc="target edge length of the body-fitted tetrahedra")
    formulation: str = option("linear", choices=FEM_FORMULATIONS, doc="small-strain linear, or stiffness-warped corotational")
    grasp_radius: float = option(GRASP_RADIUS, unit="m", lo=0.0, hi=0.02, doc="radius of the grasped patch")
    order: int | None = option(None, lo=1, hi=2, doc="element order; default 2 (quadratic) for linear, 1 for corotational")

    def __post_init__(self) -> None:
        if self.order is None:
            object.__setattr__(self, "order", 1 if self.formulation == "corotational" else 2)
        elif self.order == 2 and self.formulation == "corotational":
            raise ValueError("order: quadratic tetrahedra (order 2) run the linear formulation only")


class FemBase(TissueModel):
    description = "finite elements on the body-fitted tetrahedra, linear or corotational, P1 or P2"
    Options = FemOptions
    material_keys = ("young", "poisson")
    scales_stiffness = True

    @classmethod
    def build(cls, mesh, options: dict, scene):
        from sim.models.fem.model import build

        return build(mesh, options, scene)


# -- mass-spring ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class MassSpringOptions:
    resolution: float = option(0.008, unit="m", lo=0.003, hi=0.008, doc="target edge length of the tetrahedra whose edges are springs")
    integrator: str = option("local-global", choices=MASS_SPRING_INTEGRATORS, doc="time integration")
    dt: float = option(1 / 60, unit="s", lo=1e-5, hi=0.05, doc="time step")
    damping: float = option(5.0, unit="1/s", lo=0.0, hi=1e4, doc="mass-proportional damping")
    coupling: float = option(300.0, unit="N/m", lo=0.0, hi=OMNI_MAX_STIFFNESS, lo_open=True, doc="the hand's virtual-coupling spring (at most the Omni's stable stiffness)")
    grasp_radius: float = option(GRASP_RADIUS, unit="m", lo=0.0, hi=0.02, doc="radius of the grasped patch")
    iterations: int = option(10, lo=1, hi=1000, doc="local/global iterations per step")
    acceleration: str = option("none", choices=MASS_SPRING_ACCELERATIONS, doc="of the local/global iterations")


class MassSpringBase(TissueModel):
    description = "springs along the tetrahedra's edges; explicit, implicit or local/global integration"
    Options = MassSpringOptions
    material_keys = ("young",)  # the springs follow E alone
    scales_stiffness = True

    @classmethod
    def build(cls, mesh, options: dict, scene):
        from sim.models.mass_spring import build

        return build(mesh, options, scene)
