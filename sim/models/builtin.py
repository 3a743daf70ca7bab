"""The three built-in models as the API declares a model (`sim.models.api`): their options,
material keys and capabilities, in a module light enough for every scene reader. Each running
class (`PlateSpringModel`, `FemModel`, `MassSpringModel`) subclasses its declaration here, and
`build` imports it only when a scene runs the model. Registered in pyproject.toml like a plugin."""

from __future__ import annotations

from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

from sim.devices.base import OmniSpec
from sim.geometry.patch import GRASP_RADIUS
from sim.models.api import TissueModel, option, read_options
from sim.models.registry import GROUP
from sim.stiffness_field import FIELD_FILE
from sim.tomltable import REQUIRED

PLATE_SPRING_VARIANTS = ("paper", "continuous", "located")  # "located": the continuous stack with a stiffness field
FEM_FORMULATIONS = ("linear", "corotational")
MASS_SPRING_INTEGRATORS = ("explicit", "implicit", "local-global")
MASS_SPRING_ACCELERATIONS = ("none", "chebyshev", "anderson", "newton")  # of local-global; newton: sim/models/newton_krylov.py
OMNI_MAX_STIFFNESS = OmniSpec().max_stiffness_n_per_m  # 700 N/m: stable closed-loop stiffness at 1 kHz


def implementation(target: str):
    """The function `target` ("module:name") of a model's running code, loaded on first use as an
    entry point is (as the registry loads a model): this module, read by every scene reader,
    imports none of the three implementations, and each of them subclasses its declaration here
    (an import of it here, even inside a function, would close a cycle)."""
    return metadata.EntryPoint(target, target, GROUP).load()


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
            params = implementation("sim.models.plate_spring:params_file")(table, table.path_value("params"))
        elif isinstance(raw, dict):
            params = implementation("sim.models.plate_spring:params_table")(table.table("params"))
        elif raw is REQUIRED:
            table.error("params", "missing: a parameter file (a path) or an inline table")
        else:
            table.error("params", f"{raw!r} is neither a parameter file (a path) nor a table")
        if values is None or params is None:
            return None
        return values | {"params": params}

    @classmethod
    def build(cls, mesh, options: dict, scene):
        return implementation("sim.models.plate_spring:build")(mesh, options, scene)

    @classmethod
    def configuration(cls, options: dict) -> dict:
        out = {"options": {"field": options["field"]} if options["field"] is not None else {},
               "variant": options["variant"], "plate_spring": options["params"]}
        if options["variant"] == "located" and options["field"] is None:  # the shipped stiffness field it loads
            out["field"] = Path(FIELD_FILE) if Path(FIELD_FILE).exists() else None
        return out


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
        return implementation("sim.models.fem.model:build")(mesh, options, scene)


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
        return implementation("sim.models.mass_spring:build")(mesh, options, scene)
