"""Mass-spring tissue model: springs along the volume mesh's edges, three integrators.

- explicit symplectic Euler (stable only for ``dt <= critical_dt() = 2 / omega_max``);
- implicit Euler (Baraff and Witkin 1998: one Newton step, one sparse solve per step);
- local/global (Liu, Bargteil, O'Brien and Kavan 2013, "Fast simulation of mass-spring
  systems"): per step, alternate a local projection of every spring to its rest length with a
  global solve of a constant matrix ``M + h^2 L``, factorised once per step size (local_global.py).

Damping is mass-proportional: ``f = -damping * m * v`` (damping in 1/s). An energy monitor
flags blow-up; an unstable model renders zero force. See docs/mass_spring.md.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import eigsh
from scipy.spatial import cKDTree

from sim.devices.base import OmniSpec
from sim.errors import ParameterError, SimError
from sim.geometry.patch import GRASP_RADIUS
from sim.geometry.tetmesh import body_volume
from sim.geometry.volume import embed, tet_volumes
from sim.laws import Coupling
from sim.linalg import Factor
from sim.models import spring_kernels
from sim.models.base import Contact
from sim.models.builtin import MASS_SPRING_ACCELERATIONS as ACCELERATIONS
from sim.models.builtin import MASS_SPRING_INTEGRATORS as INTEGRATORS
from sim.models.builtin import MassSpringBase
from sim.models.fem import fixed_nodes
from sim.models.local_global import ANDERSON_DEPTH, RHO_ITERATIONS, LocalGlobal  # noqa: F401 (re-exported)
from sim.models.newton_krylov import NewtonKrylov
from sim.scene import AXES

OMNI_MAX_STIFFNESS = OmniSpec().max_stiffness_n_per_m  # 700 N/m: stable closed-loop stiffness at 1 kHz
SUBSTEP_FRACTION = 0.5  # explicit sub-steps are this fraction of critical_dt()
MAX_SUBSTEPS = 2000  # more explicit sub-steps per step than this cannot serve a visual frame


def _spring_rhs():
    """The compiled local step (`spring_kernels`); the tests replace it with None for the NumPy path."""
    return spring_kernels.spring_rhs


def _explicit_kernel():
    """The compiled explicit sub-steps (`spring_kernels`); None in tests: the NumPy loop."""
    return spring_kernels.explicit_substeps


class StabilityError(SimError):
    """An explicit step larger than the critical step was asked for."""


def _per_item(value, n: int, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise ParameterError(f"{name}: must be a scalar or an array of {n} values")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ParameterError(f"{name}: values must be finite and > 0")
    return arr


@dataclass
class StepReport:
    dt: float
    substeps: int
    integrator: str
    energy: float
    unstable: bool


class MassSpring(LocalGlobal, NewtonKrylov):
    """``MassSpring(positions, springs, stiffness, masses, fixed=None, damping=0.0)``."""

    def __init__(self, positions, springs, stiffness, masses, fixed=None, damping: float = 0.0, acceleration: str = "none"):
        if acceleration not in ACCELERATIONS:
            raise ParameterError(f"acceleration: {acceleration!r} is not one of {', '.join(ACCELERATIONS)}")
        self.acceleration = acceleration
        x = np.asarray(positions, dtype=np.float64)
        e = np.asarray(springs, dtype=np.int64)
        if x.ndim != 2 or x.shape[1] != 3:
            raise ParameterError("positions: must be (n, 3)")
        if e.ndim != 2 or e.shape[1] != 2 or len(e) == 0 or e.min() < 0 or e.max() >= len(x):
            raise ParameterError(f"springs: must be (e, 2) node indices in 0..{len(x) - 1}")
        self.n = len(x)
        self.rest_positions = x.copy()
        self.x = x.copy()
        self.v = np.zeros_like(x)
        self.springs = e
        self.k = _per_item(stiffness, len(e), "stiffness")
        self.m = _per_item(masses, self.n, "masses")
        self.fixed = np.zeros(self.n, bool) if fixed is None else np.asarray(fixed, dtype=bool)
        if self.fixed.shape != (self.n,):
            raise ParameterError(f"fixed: must be a boolean mask over the {self.n} nodes")
        if not (math.isfinite(damping) and damping >= 0):
            raise ParameterError(f"damping: {damping!r} is out of range; allowed: >= 0 (1/s)")
        self.damping = float(damping)
        self.rest = np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1)
        if np.any(self.rest <= 0):
            raise ParameterError("springs: a spring joins two nodes at the same position")
        self.free = np.flatnonzero(~self.fixed)
        self._moving = np.flatnonzero(~(self.fixed[e[:, 0]] & self.fixed[e[:, 1]]))  # springs that can stretch
        self.external = np.zeros_like(x)  # forces from outside, applied explicitly
        # anchors: springs (stiffness k) pulling the mean of some nodes towards a target; treated
        # implicitly by the implicit and local/global integrators (a hand's coupling spring)
        self.anchors: list[tuple[np.ndarray, float, np.ndarray]] = []
        self.t = 0.0
        self.unstable = False
        self.unstable_at: float | None = None
        self.energy_peak = 0.0
        self._critical: float | None = None
        self._critical_key: tuple = ()
        self._lg_cache: dict[float, object] = {}
        self._flops_cache: dict[str, tuple] = {}
        # A: signed incidence (e, n); L = A^T diag(k) A is the graph Laplacian of the springs
        rows = np.repeat(np.arange(len(e)), 2)
        self._A = sp.csr_matrix((np.tile([1.0, -1.0], len(e)), (rows, e.ravel())), shape=(len(e), self.n))

    @staticmethod
    def _local_kernel():
        """The compiled local step or None: `_spring_rhs` of this module (the NumPy path where it is swapped)."""
        return _spring_rhs()

    # -- forces and energy ------------------------------------------------------------------
    def state(self) -> tuple:
        return self.x.copy(), self.v.copy(), self.t

    def set_state(self, state: tuple) -> None:
        x, v, t = state
        self.x, self.v, self.t = x.copy(), v.copy(), t
        self.unstable, self.unstable_at = False, None

    def set_anchors(self, anchors) -> None:
        """[(nodes, k, target (3,))]: energy k/2 |mean(x[nodes]) - target|^2 each."""
        self.anchors = [(np.asarray(n, dtype=np.int64), float(k), np.asarray(t, dtype=np.float64)) for n, k, t in anchors]

    def anchor_forces(self, x: np.ndarray) -> np.ndarray:
        f = np.zeros_like(x)
        for nodes, k, target in self.anchors:
            f[nodes] -= k * (x[nodes].mean(axis=0) - target) / len(nodes)
        return f

    def spring_forces(self, x: np.ndarray) -> np.ndarray:
        e = self.springs
        d = x[e[:, 0]] - x[e[:, 1]]
        length = np.linalg.norm(d, axis=1)
        mag = self.k * (length - self.rest) / np.where(length > 0, length, 1.0)
        fij = -mag[:, None] * d  # force on node i, minus it on node j
        # A^T fij sums each spring's force into its two nodes (a sparse product, not np.add.at)
        return self._A.T @ fij

    def energy(self) -> float:
        return self._spring_energy(self.x) + 0.5 * float(np.sum(self.m[:, None] * self.v**2))

    def _spring_energy(self, x: np.ndarray) -> float:
        """sum k/2 (|x_i - x_j| - rest)^2 over the springs that can stretch (between two clamped
        nodes they keep their rest length): one compiled pass (the
        monitor runs it every step, Anderson every iteration)."""
        return spring_kernels.spring_energy(x, *self._moving_springs())

    def _moving_springs(self) -> tuple:
        """(i, j, k, rest) of the springs that can stretch, contiguous, for the compiled passes
        (a spring between two clamped nodes moves neither)."""
        if not hasattr(self, "_moving_arrays"):
            a = self._moving
            self._moving_arrays = (np.ascontiguousarray(self.springs[a, 0]), np.ascontiguousarray(self.springs[a, 1]),
                                   np.ascontiguousarray(self.k[a]), np.ascontiguousarray(self.rest[a]))
        return self._moving_arrays

    # -- stability ----------------------------------------------------------------------------
    def stiffness_at_rest(self) -> sp.csr_matrix:
        """K linearised at rest (3n x 3n): sum_s k_s (n n^T) on the spring's two nodes."""
        e = self.springs
        d = self.rest_positions[e[:, 0]] - self.rest_positions[e[:, 1]]
        nn = d / self.rest[:, None]
        return self._spring_matrix(self.k[:, None, None] * nn[:, :, None] * nn[:, None, :])

    def _spring_matrix(self, blocks: np.ndarray) -> sp.csr_matrix:
        """Assemble one 3x3 block per spring (e, 3, 3) as [[B, -B], [-B, B]] on its two nodes."""
        e = self.springs
        i3 = (3 * e[:, :, None] + np.arange(3)).reshape(len(e), 6)
        B = np.zeros((len(e), 6, 6))
        B[:, :3, :3] = blocks
        B[:, 3:, 3:] = blocks
        B[:, :3, 3:] = -blocks
        B[:, 3:, :3] = -blocks
        rows = np.repeat(i3, 6, axis=1).ravel()
        cols = np.tile(i3, (1, 6)).ravel()
        return sp.coo_matrix((B.ravel(), (rows, cols)), shape=(3 * self.n, 3 * self.n)).tocsr()

    def _anchor_matrix(self) -> sp.csr_matrix:
        """The anchors' stiffness (3n x 3n): k w w^T per component, w = 1/|nodes| on the nodes."""
        rows, cols, vals = [], [], []
        for nodes, k, _ in self.anchors:
            w = k / len(nodes) ** 2
            for c in range(3):
                ii = 3 * nodes + c
                rows.append(np.repeat(ii, len(ii)))
                cols.append(np.tile(ii, len(ii)))
                vals.append(np.full(len(ii) ** 2, w))
        if not rows:
            return sp.csr_matrix((3 * self.n, 3 * self.n))
        return sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * self.n, 3 * self.n)).tocsr()

    def critical_dt(self) -> float:
        """2 / omega_max, omega_max^2 the largest eigenvalue of M^-1 K at rest (fixed removed;
        anchors included: a stiff coupling on a light patch can dominate)."""
        key = tuple((len(n), k) for n, k, _ in self.anchors)
        if self._critical is not None and self._critical_key != key:
            self._critical = None
        self._critical_key = key
        if self._critical is None:
            free3 = (3 * self.free[:, None] + np.arange(3)).ravel()
            K = (self.stiffness_at_rest() + self._anchor_matrix())[free3][:, free3]
            s = sp.diags(1.0 / np.sqrt(np.repeat(self.m[self.free], 3)))
            S = (s @ K @ s).tocsr()  # similar to M^-1 K, symmetric
            if S.shape[0] <= 200:
                lam = float(np.linalg.eigvalsh(S.toarray()).max())
            else:
                # a fixed start vector: ARPACK's own random one gave a different last few digits
                # on every call, so an explicit run's sub-step count and bits could differ
                v0 = np.random.default_rng(0).uniform(0.5, 1.5, S.shape[0])
                lam = float(eigsh(S, k=1, which="LA", return_eigenvectors=False, tol=1e-6, v0=v0)[0])
            self._critical = 2.0 / math.sqrt(lam) if lam > 0 else math.inf
        return self._critical

    # -- stepping -----------------------------------------------------------------------------
    def step(self, dt: float, integrator: str = "explicit", substep: bool = False, iterations: int = 10) -> StepReport:
        """Advance by `dt` seconds. Explicit steps above `critical_dt()` are refused, or split
        into stable substeps when `substep` is true."""
        if integrator not in INTEGRATORS:
            raise ParameterError(f"integrator: {integrator!r} is not one of {', '.join(INTEGRATORS)}")
        if not (math.isfinite(dt) and dt > 0):
            raise ParameterError(f"dt: {dt!r} is out of range; allowed: > 0 s")
        n_sub = 1
        if integrator == "explicit":
            crit = self.critical_dt()
            if dt > crit:
                if not substep:
                    raise StabilityError(
                        f"dt: {dt:.4g} s is above the critical step {crit:.4g} s of explicit integration "
                        f"(2 / omega_max); use dt <= {crit:.4g} s, sub-stepping, or an implicit integrator"
                    )
                # half the critical step: it is the rest linearisation's, and stretched springs
                # (a hand pulling a light patch) raise omega_max above it
                n_sub = math.ceil(dt / (SUBSTEP_FRACTION * crit))
                if n_sub > MAX_SUBSTEPS:
                    raise StabilityError(
                        f"dt: explicit integration would need {n_sub} sub-steps per {dt:.4g} s step (critical step "
                        f"{crit:.3g} s); at most {MAX_SUBSTEPS}: use the implicit or local-global integrator"
                    )
        if self.unstable:
            return StepReport(dt, 0, integrator, math.nan, True)
        h = dt / n_sub
        if integrator == "explicit" and (kernel := _explicit_kernel()) is not None:
            self._explicit_compiled(kernel, h, n_sub)
            for _ in range(n_sub):
                self.t += h
        else:
            for _ in range(n_sub):
                if integrator == "explicit":
                    self._explicit(h)
                elif integrator == "implicit":
                    self._implicit(h)
                else:
                    self._local_global(h, iterations)
                self.t += h
        energy = self._monitor()
        return StepReport(dt, n_sub, integrator, energy, self.unstable)

    def step_flops(self, dt: float, integrator: str, iterations: int = 10) -> float:
        """The floating-point work of `step(dt, integrator)` counted from the system's sizes:
        a deterministic cost (studyctl/synthetic/observer.py turns it into a latency). Counts the
        dominant kernels: per-spring work, sparse products (2 flops per entry and column),
        triangular solves (4 per factor entry and column) and, for the implicit integrator, the
        factorisation (sum of squared column counts of L)."""
        n, e = self.n, len(self.springs)
        if integrator == "explicit":
            crit = self.critical_dt()
            n_sub = math.ceil(dt / (SUBSTEP_FRACTION * crit)) if dt > crit else 1
            return float(n_sub * (30 * e + 20 * n))
        if integrator == "implicit":
            if "implicit" not in self._flops_cache:  # sizes recorded by the first implicit step (the pattern is fixed)
                return math.nan
            nnz_L, fac, nnz_J = self._flops_cache["implicit"]
            return float(100 * e + 6 * nnz_J + fac + 4 * nnz_L + 20 * n)
        return self._lg_flops(dt, iterations)

    def _accel(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        f = self.spring_forces(x) + self.anchor_forces(x) + self.external - self.damping * self.m[:, None] * v
        return f / self.m[:, None]

    def _explicit_compiled(self, kernel, h: float, n_sub: int) -> None:
        """`n_sub` steps of `_explicit` in one compiled loop over the springs that can stretch
        (those between two clamped nodes push only nodes that do not move)."""
        a = self.anchors
        nodes = np.concatenate([n for n, _, _ in a]) if a else np.zeros(0, dtype=np.int64)
        ptr = np.concatenate([[0], np.cumsum([len(n) for n, _, _ in a])]).astype(np.int64)
        ks = np.array([k for _, k, _ in a], dtype=np.float64)
        targets = np.array([t for _, _, t in a], dtype=np.float64).reshape(-1, 3)
        kernel(self.x, self.v, self.m, self.fixed, *self._moving_springs(), nodes, ptr, ks, targets,
               self.external, self.damping, h, n_sub)

    def _explicit(self, h: float) -> None:
        a = self._accel(self.x, self.v)
        a[self.fixed] = 0.0
        self.v += h * a  # symplectic Euler: velocity first, then position with the new velocity
        self.v[self.fixed] = 0.0
        self.x += h * self.v

    def _spring_jacobian(self, x: np.ndarray) -> sp.csr_matrix:
        """d f / d x (3n x 3n), with the transverse term clamped at zero so it stays definite."""
        e = self.springs
        d = x[e[:, 0]] - x[e[:, 1]]
        length = np.linalg.norm(d, axis=1)
        nn = d / length[:, None]
        outer = nn[:, :, None] * nn[:, None, :]
        trans = np.clip(1.0 - self.rest / length, 0.0, None)
        blocks = self.k[:, None, None] * (outer + trans[:, None, None] * (np.eye(3) - outer))
        return -self._spring_matrix(blocks)

    def _implicit(self, h: float) -> None:
        """(M - h^2 df/dx + h c M) dv = h (f + h df/dx v): one linearised backward-Euler step."""
        free3 = (3 * self.free[:, None] + np.arange(3)).ravel()
        J = (self._spring_jacobian(self.x) - self._anchor_matrix())[free3][:, free3]
        mass = np.repeat(self.m[self.free], 3)
        A = sp.diags(mass * (1.0 + h * self.damping)) - h * h * J
        f = (self.spring_forces(self.x) + self.anchor_forces(self.x) + self.external - self.damping * self.m[:, None] * self.v).ravel()[free3]
        rhs = h * (f + h * (J @ self.v.ravel()[free3]))
        factor = Factor(A.tocsr())
        dv = factor.solve(rhs)
        if "implicit" not in self._flops_cache:  # the sizes `step_flops` counts with: the same pattern every step
            self._flops_cache["implicit"] = (factor.nnz_L, factor.factor_flops, J.nnz)
        v = self.v.ravel().copy()
        v[free3] += dv
        self.v = v.reshape(-1, 3)
        self.x += h * self.v

    def _monitor(self) -> float:
        """Energy monitor: NaN, runaway velocities or an energy jump of 1000x flag blow-up."""
        energy = self.energy()
        for nodes, k, target in self.anchors:
            energy += 0.5 * k * float(np.sum((self.x[nodes].mean(axis=0) - target) ** 2))
        finite = math.isfinite(energy) and np.all(np.isfinite(self.x))
        runaway = finite and float(np.abs(self.v).max(initial=0.0)) > 100.0  # m/s: no tissue moves so
        jump = finite and self.energy_peak > 1e-12 and energy > 1e3 * self.energy_peak and energy > 1e-3
        if not finite or runaway or jump:
            if not self.unstable:
                self.unstable = True
                self.unstable_at = self.t
        else:
            self.energy_peak = max(self.energy_peak, energy)
        return energy


# -- construction from a volume mesh --------------------------------------------------------


def from_tets(nodes: np.ndarray, tets: np.ndarray, young: float, density: float, fixed=None, damping: float = 0.0) -> MassSpring:
    """Springs on the tetrahedra's edges with ``k = 6 E V_e / L_e^2``, where ``V_e`` is the
    volume assigned to the edge (each tetrahedron gives a sixth of its volume to each of its six
    edges), and lumped masses ``rho V / 4`` per tetrahedron node.

    Why 6: a central-force lattice has the elasticity tensor ``C_ijkl = sum k L^2 n_i n_j n_k
    n_l / V``; with spring directions spread evenly, ``<n_x^4> = 1/5`` and ``<n_x^2 n_y^2> =
    1/15`` give ``lambda = mu = c E / 15``, a Young's modulus ``c E / 6`` and Poisson's ratio
    1/4 (a spring lattice cannot have another). ``c = 6`` makes the lattice's modulus E."""
    vol = np.abs(tet_volumes(nodes, tets))
    e6 = np.stack([tets[:, [0, 0, 0, 1, 1, 2]].ravel(), tets[:, [1, 2, 3, 2, 3, 3]].ravel()], axis=1)
    e6.sort(axis=1)
    edges, inverse = np.unique(e6, axis=0, return_inverse=True)
    edge_volume = np.bincount(inverse.ravel(), weights=np.repeat(vol / 6.0, 6), minlength=len(edges))
    length = np.linalg.norm(nodes[edges[:, 0]] - nodes[edges[:, 1]], axis=1)
    k = 6.0 * young * edge_volume / length**2
    masses = np.bincount(tets.ravel(), weights=np.repeat(density * vol / 4.0, 4), minlength=len(nodes))
    return MassSpring(nodes, edges, k, masses, fixed=fixed, damping=damping)


# -- the tissue model ------------------------------------------------------------------------


@dataclass
class _Grasp:
    nodes: np.ndarray  # volume nodes held (the patch)
    anchor: np.ndarray  # their mean rest position


class MassSpringModel(MassSpringBase):
    """The mass-spring model under the tissue-model contract.

    A grasp attaches a virtual-coupling spring (stiffness `coupling`, at most the Omni's
    700 N/m) between the hand and the mean position of the volume nodes within `grasp_radius`
    of the grasp point. The servo reads the coupling force at 1 kHz from the patch position the
    simulation last published; the visual step advances the system at its own rate with the
    chosen integrator (as many steps of `dt` as a visual frame lasts), applying the coupling
    force to the patch.
    """

    name = "mass_spring"

    def __init__(self, surface, volume, system: MassSpring, integrator: str = "local-global", dt: float = 1 / 60,
                 coupling: float = 300.0, grasp_radius: float = GRASP_RADIUS, substep: bool = True, iterations: int = 10,
                 frame_dt: float | None = None):
        if not 0 < coupling <= OMNI_MAX_STIFFNESS:
            raise ParameterError(f"coupling: {coupling!r} N/m is out of range; allowed: (0, {OMNI_MAX_STIFFNESS:g}] N/m (Omni's stable stiffness at 1 kHz)")
        if integrator not in INTEGRATORS:
            raise ParameterError(f"integrator: {integrator!r} is not one of {', '.join(INTEGRATORS)}")
        self.surface, self.volume, self.system = surface, volume, system
        self.integrator, self.dt, self.coupling = integrator, dt, coupling
        self.grasp_radius, self.substep, self.iterations = grasp_radius, substep, iterations
        # a frame advances the tissue by the frame's simulated time, in steps of dt
        self.steps_per_frame = max(1, round((frame_dt or dt) / dt))
        self.embedding = embed(volume, surface.vertices, surface.labels)
        surface.prepare_queries()
        self._tree = cKDTree(volume.nodes)
        self._out = np.zeros_like(surface.vertices)
        self.step_s: list[float] = []
        self.frame_flops = math.nan  # the last frame's counted work (MassSpring.step_flops)
        if integrator in ("local-global", "explicit") and _spring_rhs() is not None:
            spring_kernels.warm_up()  # compiled now, not in the first frame of a trial
        self._check_explicit()

    def _check_explicit(self) -> None:
        """Refuse now what the first frame of an explicit model would refuse."""
        if self.integrator != "explicit":
            return
        dt, substep, crit = self.dt, self.substep, self.system.critical_dt()
        if not substep and dt > crit:
            raise StabilityError(f"dt: {dt:.4g} s is above the critical step {crit:.4g} s; enable substep or lower dt")
        if substep and dt > crit and math.ceil(dt / (SUBSTEP_FRACTION * crit)) > MAX_SUBSTEPS:
            raise StabilityError(f"dt: explicit integration would need {math.ceil(dt / (SUBSTEP_FRACTION * crit))} sub-steps "
                                 f"per {dt:.4g} s step (critical step {crit:.3g} s); at most {MAX_SUBSTEPS}: use the implicit or local-global integrator")

    @property
    def unstable(self) -> bool:
        return self.system.unstable

    def reset(self) -> None:
        """Back to rest (a new trial starts from undeformed tissue)."""
        s = self.system
        s.set_state((s.rest_positions, np.zeros_like(s.rest_positions), 0.0))
        s.set_anchors([])
        s.energy_peak = 0.0
        self.step_s = []

    def with_stiffness(self, scale: float) -> MassSpringModel:
        """This model with Young's modulus times `scale` (the discrimination task's stimulus):
        every spring's stiffness is linear in E (`from_tets`), the masses are not, so the
        springs are scaled and the system built again (its local/global factor depends on them).
        The surface's embedding and the node tree depend on the geometry alone: shared (most of
        a stimulus's build cost: docs/mass_spring.md)."""
        s = self.system
        out = copy.copy(self)
        out.system = MassSpring(s.rest_positions, s.springs, s.k * float(scale), s.m, fixed=s.fixed, damping=s.damping, acceleration=s.acceleration)
        out._out, out.step_s, out.frame_flops = np.zeros_like(self._out), [], math.nan
        out._check_explicit()
        return out

    def grasp(self, point, hand: int = 0):
        v = self.surface.nearest_vertex(point)
        p = self.surface.vertices[v]
        nodes = np.asarray(self._tree.query_ball_point(p, max(self.grasp_radius, self.volume.resolution)), dtype=np.int64)
        comp = self.volume.component[self._tree.query(p)[1]]
        nodes = nodes[(self.volume.component[nodes] == comp) & ~self.system.fixed[nodes]]
        if len(nodes) == 0:
            nodes = np.array([self._tree.query(p)[1]])
        g = _Grasp(nodes=nodes, anchor=self.system.rest_positions[nodes].mean(axis=0))
        # the contact point is the surface vertex; the coupling acts on the patch's displacement
        point = tuple(float(c) for c in p)
        patch = tuple(float(c) for c in p + (self.system.x[nodes].mean(axis=0) - g.anchor))
        # gain 1 until the first frame measures how the patch follows the hand: the force starts
        # from zero and rises as the tissue resists (with gain 0 the coupling spring alone, far
        # stiffer than the tissue, rendered every motion before that frame as a bump: docs/mass_spring.md)
        law = Coupling(k=self.coupling, anchor=point, patch=patch, gain=1.0)
        return Contact(hand=hand, vertex=int(v), point=point, normal=tuple(float(c) for c in self.surface.vertex_normals[v]), data=g, law=law)

    def force(self, contact, displacement):
        if self.system.unstable:
            return (0.0, 0.0, 0.0)  # the servo never sees a blown-up model's force
        # hand at anchor + d, patch (mapped to the surface point) where the simulation left it
        return contact.law.force(displacement)

    def tick_laws(self, contacts):
        """Each contact's coupling, unless the system blew up (`force`) or a subclass computes its
        forces otherwise."""
        if type(self).force is not MassSpringModel.force or type(self).forces is not MassSpringModel.forces:
            return None
        return None if self.system.unstable else [c.law for c in contacts]

    def deformation(self, contacts, displacements) -> np.ndarray:
        self.advance(contacts, displacements)
        return self.surface_displacement()

    def advance(self, contacts, displacements) -> None:
        """Steps the system and publishes the patches; the surface (the embedding of the nodes'
        displacement) waits for `surface_displacement`."""
        sysm = self.system
        # the coupling spring pulls the patch's mean towards where the hand puts it
        sysm.set_anchors([(c.data.nodes, self.coupling, c.data.anchor + np.asarray(d, dtype=np.float64)) for c, d in zip(contacts, displacements)])
        start = time.perf_counter()
        for _ in range(self.steps_per_frame):
            if sysm.unstable:
                break
            sysm.step(self.dt, self.integrator, substep=self.substep, iterations=self.iterations)
        self.step_s.append(time.perf_counter() - start)
        self.frame_flops = self.steps_per_frame * sysm.step_flops(self.dt, self.integrator, self.iterations) + 6 * self.embedding.matrix.nnz
        for c, d in zip(contacts, displacements):  # publish the patch for the servo, and how it follows the hand
            g = c.data
            patch = np.asarray(c.point) + sysm.x[g.nodes].mean(axis=0) - g.anchor
            d = np.asarray(d, dtype=np.float64)
            step = d - np.asarray(c.law.d_frame)
            moved = float(step @ step)
            gain = c.law.gain
            if moved > 1e-12:  # the hand moved since the last frame: the patch's share of that motion
                gain = min(1.0, max(0.0, float((patch - np.asarray(c.law.patch)) @ step) / moved))
            c.law.update(patch=tuple(float(x) for x in patch), d_frame=tuple(float(x) for x in d), gain=gain)

    def surface_displacement(self) -> np.ndarray:
        sysm = self.system
        u = sysm.x - sysm.rest_positions
        if not np.all(np.isfinite(u)):
            u = np.zeros_like(u)
        self._out[:] = self.embedding.matrix @ u
        return self._out

    def diagnostics(self) -> dict:
        s = self.system
        return {
            "integrator": self.integrator,
            "dt": self.dt,
            "critical_dt": s.critical_dt(),
            "unstable": s.unstable,
            "unstable_at": s.unstable_at,
            "step_ms_p50": float(np.median(self.step_s) * 1e3) if self.step_s else None,
        }


def build(mesh, o: dict, scene) -> MassSpringModel:
    """Construct from a scene's mass-spring options (`sim.models.builtin.MassSpringOptions`, as a dict)."""
    volume = body_volume(mesh, o["resolution"])
    material = scene.spec.material
    fixed = fixed_nodes(volume, mesh, scene.fixed_mask, AXES[scene.spec.fixed.axis])
    system = from_tets(volume.nodes, volume.tets, material.young, material.density, fixed=fixed, damping=o["damping"])
    system.acceleration = o.get("acceleration", "none")
    return MassSpringModel(mesh, volume, system, integrator=o["integrator"], dt=o["dt"], coupling=o["coupling"],
                           grasp_radius=o["grasp_radius"], substep=True, iterations=o["iterations"],
                           frame_dt=1.0 / scene.spec.visual_rate_hz)
