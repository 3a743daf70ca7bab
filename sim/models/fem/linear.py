"""Small-strain isotropic linear elasticity on P1 or P2 tetrahedra: vectorised assembly, the
Dirichlet clamp, one sparse Cholesky factorisation (CHOLMOD, `sim.linalg.Factor`) reused for
every solve. Degrees of freedom are node-major: dof ``3 i + c`` is component c of node i."""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from sim.errors import ParameterError
from sim.linalg import Factor
from sim.models.base import POISSON_MAX, POISSON_MIN
from sim.models.fem import p1, p2
from sim.models.fem.space import TetSpace

# Locking follows the element. Linear tetrahedra are already far too stiff at the brain's
# Poisson 0.45 (docs/fem.md): the P1 error grows like 1/(1 - 2 nu), so P1 is flagged from 0.4
# on; quadratic tetrahedra only close to incompressibility.
LOCKING_POISSON = {1: 0.4, 2: 0.49}
ASSEMBLIES = [0]  # stiffness assemblies in this process (tests: a scene without FEM makes none)


def lame(young: float, poisson: float) -> tuple[float, float]:
    lam = young * poisson / ((1 + poisson) * (1 - 2 * poisson))
    mu = young / (2 * (1 + poisson))
    return lam, mu


def check_material(young: float, poisson: float) -> None:
    if not (math.isfinite(young) and young > 0):
        raise ParameterError(f"young: {young!r} is out of range; allowed: a finite number > 0 Pa")
    if not (math.isfinite(poisson) and POISSON_MIN <= poisson < POISSON_MAX):
        raise ParameterError(f"poisson: {poisson!r} is out of range; allowed: [{POISSON_MIN:g}, {POISSON_MAX:g})")


def element_dofs(elements: np.ndarray) -> np.ndarray:
    # int32 halves the memory traffic of assembly (dof counts stay far below 2**31)
    k = elements.shape[1]
    return (3 * elements[:, :, None].astype(np.int32) + np.arange(3, dtype=np.int32)).reshape(len(elements), 3 * k)


def assemble(element_matrices: np.ndarray, elements: np.ndarray, n_nodes: int, free: np.ndarray | None = None) -> sp.csr_matrix:
    """The global stiffness (3n, 3n); with `free` (global dof ids), only those rows and columns,
    in that order: clamped entries are dropped before the sort (on the brain most nodes are
    clamped, so this beats assembling everything and slicing: docs/fem.md)."""
    ASSEMBLIES[0] += 1
    dofs = element_dofs(elements)
    size = 3 * n_nodes
    values = element_matrices.reshape(len(dofs), -1)
    if free is not None:
        where = np.full(size, -1, dtype=np.int32)
        where[free] = np.arange(len(free), dtype=np.int32)
        dofs, size = where[dofs], len(free)
        moving = (dofs >= 0).any(axis=1)  # elements with a free dof
        dofs, values = dofs[moving], values[moving]
    k = dofs.shape[1]
    rows = np.repeat(dofs, k, axis=1).ravel()
    cols = np.tile(dofs, (1, k)).ravel()
    values = values.ravel()
    if free is not None:
        keep = (rows >= 0) & (cols >= 0)
        rows, cols, values = rows[keep], cols[keep], values[keep]
    return sp.coo_matrix((values, (rows, cols)), shape=(size, size)).tocsr()


@dataclass
class Timings:
    assembly_s: float = 0.0
    factorisation_s: float = 0.0


class LinearFem(TetSpace):
    """Linear elasticity on linear (order 1) or quadratic (order 2) tetrahedra with nodes
    `fixed` clamped.

    ``LinearFem(nodes, tets, young, poisson, fixed).solve(forces)`` returns the static corner
    displacements (n, 3) for corner forces (n, 3). With ``order=2`` the quadratic elements are
    built from the corner mesh: `elements` (m, 10) index `all_nodes`, the corners then the
    mid-edge nodes (a mid-edge node is clamped when both its corners are).
    """

    def __init__(self, nodes, tets, young: float, poisson: float, fixed, order: int = 1):
        start = time.perf_counter()
        super().__init__(nodes, tets, fixed, order)
        check_material(young, poisson)
        self.young, self.poisson = float(young), float(poisson)
        self.lam, self.mu = lame(young, poisson)
        self.timings = Timings()
        if order == 1:
            self.element_matrices = p1.element_stiffness(self.grads, self.volumes, self.lam, self.mu)  # kept for the corotational update
            matrices = self.element_matrices
        else:
            matrices = p2.element_stiffness(self.grads, self.volumes, self.lam, self.mu)
        self.reduced = assemble(matrices, self.elements, self.n_all, self.free)
        self.timings.assembly_s = time.perf_counter() - start
        self._stiffness: sp.csr_matrix | None = None
        self._factor: Factor | None = None
        # what a solver on this mesh keeps between frames, by name (the corotational solver: the
        # active elements' arrays and their warp map, sim.models.fem.corotational)
        self.solver_cache: dict = {}

    @property
    def stiffness(self) -> sp.csr_matrix:
        """The unclamped global stiffness (3 n_all, 3 n_all), assembled when first asked for
        (the corotational update and the tests; the haptic model needs only `reduced`)."""
        if self._stiffness is None:
            matrices = self.element_matrices if self.order == 1 else p2.element_stiffness(self.grads, self.volumes, self.lam, self.mu)
            self._stiffness = assemble(matrices, self.elements, self.n_all)
        return self._stiffness

    @property
    def locking(self) -> bool:
        """The element locks (is too stiff) at this Poisson ratio (see LOCKING_POISSON)."""
        return self.poisson >= LOCKING_POISSON[self.order]

    @property
    def factor(self) -> Factor:
        if self._factor is None:
            start = time.perf_counter()
            self._factor = Factor(self.reduced)
            self.timings.factorisation_s = time.perf_counter() - start
        return self._factor

    def scaled(self, ratio: float) -> LinearFem:
        """This system with Young's modulus times `ratio`: every stiffness is linear in E, so
        the matrices scale and the factor is reused (`Factor.scaled`), exact to rounding and
        without assembling or factorising again (the discrimination task's stimuli)."""
        r = float(ratio)
        out = copy.copy(self)
        out.young, out.lam, out.mu = self.young * r, self.lam * r, self.mu * r
        out.reduced = self.reduced * r
        if self.order == 1:
            out.element_matrices = self.element_matrices * r
        out._stiffness = None if self._stiffness is None else self._stiffness * r
        out._factor = self.factor.scaled(r)
        out.solver_cache = {}  # its own: a solver's arrays of this system are not the copy's
        out.timings = Timings()
        return out

    def solve_free(self, b: np.ndarray) -> np.ndarray:
        return self.factor.solve(b)

    def solve(self, forces) -> np.ndarray:
        f = np.asarray(forces, dtype=np.float64).reshape(-1)
        if f.shape != (3 * len(self.nodes),):
            raise ParameterError(f"forces: must be ({len(self.nodes)}, 3)")
        full = np.zeros(3 * self.n_all)
        full[: len(f)] = f  # loads on the corners; mid-edge nodes carry none
        u = np.zeros(3 * self.n_all)
        u[self.free] = self.solve_free(full[self.free])
        return u[: 3 * len(self.nodes)].reshape(-1, 3)
