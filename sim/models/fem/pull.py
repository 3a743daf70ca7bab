"""One static pull on the scene's brain: the `studyctl model fem` command."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from sim.errors import ParameterError
from sim.geometry.patch import GRASP_RADIUS, grasp_problem
from sim.geometry.tetmesh import body_volume
from sim.geometry.volume import describe
from sim.models.base import pull_problem
from sim.models.fem.corotational import corotational_solve
from sim.models.fem.finite_strain import FiniteStrain, support
from sim.models.fem.model import DEFAULT_ORDER, DEFAULT_RESOLUTION, FemModel, fixed_nodes
from sim.models.fem.newton import NewtonReport, hold
from sim.models.fem.nodal_pressure import NodalPressure
from sim.scene import AXES

FORMULATIONS = ("linear", "corotational", "finite-strain", "nodal-pressure")
TICKS = 20000  # servo-tick force calls timed


@dataclass(frozen=True)
class SolveReport:
    """A nonlinear pull's solve (the Newton or corotational solver's report): whether it converged,
    its load steps and iterations, each step's final residual, the smallest det F, and how far it
    got when it stopped (`completed_steps`, `completed_fraction`, `reason`); `support`: the
    finite-strain state's support (`finite_strain.support`) where it was asked for."""

    converged: bool
    load_steps: int
    iterations: tuple[int, ...]
    final_residuals: tuple[float | None, ...]
    min_jacobian: float
    inverted_elements: bool
    tangent_updates: int
    completed_steps: int
    completed_fraction: float | None
    reason: str
    support: dict | None = None


@dataclass(frozen=True)
class StaticPull:
    """One static pull (`static_pull`): the meshes (`volume`: nodes, tets, resolution_mm; `part`:
    the grasped hemisphere's nodes, tets, free_dofs), the grasp, the force on the hand, the largest
    displacement, each phase's time (ms) and, for a nonlinear formulation, its solve (None: linear,
    which converges by construction). `as_dict()` is `model fem --json`'s object."""

    formulation: str
    order: int
    resolution_mm: float
    volume: dict
    part: dict
    grasp_vertex: int
    grasp_point: tuple[float, float, float]
    displacement: tuple[float, float, float]
    locking: bool
    solve: SolveReport | None
    force_n: tuple[float, float, float]
    force_magnitude_n: float
    max_displacement_m: float
    times_ms: dict

    @property
    def converged(self) -> bool:
        return self.solve is None or self.solve.converged

    def as_dict(self) -> dict:
        """The JSON object, the solve's fields in place of `solve` (as `model fem --json` has always
        printed them: lists for tuples, `support` only where computed)."""
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name != "solve":
                out[f.name] = list(v) if isinstance(v, tuple) else v
            elif v is None:
                out["converged"] = True
            else:
                out |= {g.name: list(x) if isinstance(x, tuple) else x for g in dataclasses.fields(v)
                        if (x := getattr(v, g.name)) is not None or g.name != "support"}
        return out


def _options(scene, formulation: str, displacement, resolution: float | None, order: int | None) -> tuple:
    """(displacement (3,), resolution, order, grasp radius), checked."""
    if formulation not in FORMULATIONS:
        raise ParameterError(f"formulation: {formulation!r} is not one of {', '.join(FORMULATIONS)}")
    if (problem := pull_problem(displacement)) is not None:
        raise ParameterError(f"displacement: {problem}")
    spec = scene.model_spec.options if scene.model_spec.name == "fem" else {}
    resolution = float(spec.get("resolution", DEFAULT_RESOLUTION)) if resolution is None else resolution
    if not 0.003 <= resolution <= 0.008:
        raise ParameterError(f"resolution: {resolution * 1e3:g} mm is out of range; allowed: 3..8 mm")
    linear_only = formulation in ("corotational", "nodal-pressure")
    if order is None:  # the scene's, except that the corotational update and the nodal pressure run on linear tetrahedra only
        order = 1 if linear_only else int(spec.get("order", DEFAULT_ORDER))
    if order == 2 and linear_only:
        raise ParameterError(f"order: the {formulation} formulation runs on linear tetrahedra (order 1) only")
    return np.asarray(displacement, dtype=np.float64), resolution, order, spec.get("grasp_radius", GRASP_RADIUS)


def _time_ticks(model, contact, d: tuple) -> float:
    t0 = time.perf_counter()
    for _ in range(TICKS):
        model.force(contact, d)
    return (time.perf_counter() - t0) / TICKS


def _solve(model, contact, d: np.ndarray, formulation: str, steps: int, law=None, stretch_range=None) -> tuple:
    """(force holding the grasp (3,), every node's displacement, the solver's report (None for the
    linear formulation); with `stretch_range`, a finite-strain state's support: `finite_strain.support`)."""
    if formulation == "linear":
        return np.asarray(model.grasp_forces([contact], [d])), model.nodal_displacement([contact], [d]), None
    part = model.parts[contact.data.part]
    if formulation in ("finite-strain", "nodal-pressure"):  # the scene's law on the model's mesh and element

        system = FiniteStrain(part, law, mean_dilatation=False) if formulation == "finite-strain" else NodalPressure(part, law)
        want = stretch_range is not None and formulation == "finite-strain"
        held = hold(system, contact.data.W, d, first_step=1.0 / steps, sensitivity=want)
        u_part, force, rep = held.u.reshape(-1, 3), held.multipliers, held.report
        sup = support(system, held.u, stretch_range, held.sensitivities[-1] if held.sensitivities else None) if want else None
        report = _report(rep, float(held.fraction_done), sup)
    else:
        u_part, force, rep = corotational_solve(part, contact.data.W, contact.data.U, d, steps=steps)
        report = _report(rep)
    u = np.zeros((model.n_model_nodes, 3))
    start = model.offsets[contact.data.part]
    u[start : start + len(u_part)] = u_part
    return np.asarray(force), u, report


def static_pull(scene, grasp, displacement, resolution: float | None = None, formulation: str = "linear", steps: int = 5,
                order: int | None = None, stretch_range: tuple[float, float] | None = None) -> StaticPull:
    """Grasp the scene's brain at `grasp` and hold the grasp point at `displacement` (m).

    Returns the force on the hand, the largest displacement, the phase times, and for the
    nonlinear formulations the convergence history; for the finite-strain one with
    `stretch_range` (the principal stretches the law's data cover), the state's support.
    """
    d, resolution, order, radius = _options(scene, formulation, displacement, resolution, order)
    if (problem := grasp_problem(scene.mesh, grasp)) is not None:
        raise ParameterError(f"grasp: {problem}")
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    mesh = scene.mesh
    volume = body_volume(mesh, resolution)
    times["mesh_s"] = time.perf_counter() - t0
    material = scene.spec.material
    fixed = fixed_nodes(volume, mesh, scene.fixed_mask, AXES[scene.spec.fixed.axis])
    model = FemModel(mesh, volume, material.young, material.poisson, fixed, grasp_radius=radius, order=order)
    times.update(model.timings)
    t0 = time.perf_counter()
    contact = model.grasp(grasp, 0)
    times["grasp_s"] = time.perf_counter() - t0
    times["tick_s"] = _time_ticks(model, contact, tuple(float(x) for x in d))
    t0 = time.perf_counter()
    model.deformation([contact], [d])
    times["frame_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    force, u, report = _solve(model, contact, d, formulation, steps, material.law, stretch_range)
    if formulation != "linear":
        times["solve_s"] = time.perf_counter() - t0
    part = model.parts[contact.data.part]
    return StaticPull(formulation=formulation, order=order, resolution_mm=resolution * 1e3, volume=describe(volume),
                      part={"nodes": int(part.n_all), "tets": int(len(part.tets)), "free_dofs": int(len(part.free))},
                      grasp_vertex=contact.vertex, grasp_point=tuple(contact.point), displacement=tuple(d.tolist()), locking=model.locking,
                      solve=report,
                      force_n=tuple((-force).tolist()),  # the hand feels minus the force that holds the tissue at d
                      force_magnitude_n=float(np.linalg.norm(force)), max_displacement_m=float(np.linalg.norm(u, axis=1).max()),
                      times_ms={k.removesuffix("_s"): v * 1e3 for k, v in times.items()})


def _report(rep: NewtonReport, completed_fraction: float | None = None, support_: dict | None = None) -> SolveReport:
    """The solver's report; `completed_fraction` (default: all of it when converged, unknown
    otherwise) and the state's support where the solve computed them."""
    return SolveReport(
        converged=rep.converged, load_steps=rep.load_steps, iterations=tuple(rep.iterations),
        final_residuals=tuple(r[-1] if r else None for r in rep.residuals), min_jacobian=rep.min_jacobian,
        inverted_elements=rep.min_jacobian <= 0, tangent_updates=rep.tangent_updates,
        # a solve that stopped early returns the state of its last solved load step
        completed_steps=rep.completed_steps,
        completed_fraction=completed_fraction if completed_fraction is not None else (1.0 if rep.converged else None),
        reason=rep.reason, support=support_)
