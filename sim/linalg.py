"""Sparse symmetric positive definite systems: every factorisation in the simulator goes through
`Factor` (CHOLMOD's supernodal Cholesky, via scikit-sparse).

- `Factor(A)`: factorise A once (fill-reducing ordering chosen by CHOLMOD), then `.solve(b)`
  for as many right-hand sides as needed (b of shape (n,) or (n, k)).
- `shifted_factor(K)`: for a tangent that may be indefinite (the neo-Hookean Newton solver):
  K, or K + shift * I with a growing shift.

A matrix that is not positive definite (indefinite, singular, NaN) raises
`SingularSystemError`, never an exception of scikit-sparse's. Only the lower triangle of A is
read: A must be symmetric.
"""

from __future__ import annotations

import copy

import numpy as np
import scipy.linalg  # noqa: F401 - scipy's own OpenBLAS, loaded before the pin so that the pin reaches it
import scipy.sparse as sp
import scipy.sparse.linalg  # noqa: F401
import sksparse.cholmod
from threadpoolctl import ThreadpoolController

from sim.errors import SimError


class SingularSystemError(SimError):
    """The stiffness cannot be factorised (no Dirichlet condition, or not positive definite)."""


_CHOLMOD = None


def _cholmod():
    """scikit-sparse's CHOLMOD module, its thread pools pinned on first use (`one_thread_pools`;
    only the FEM and the mass-spring import this module)."""
    global _CHOLMOD
    if _CHOLMOD is None:
        one_thread_pools()
        _CHOLMOD = sksparse.cholmod
    return _CHOLMOD


def one_thread_pools() -> None:
    """Every OpenBLAS pool loaded by then, and the system's OpenMP (CHOLMOD's) in the calling
    thread, on one thread: a case gives the same bits in every process on one machine, and two
    pools do not spin against each other. Why and what it costs: docs/accuracy.md."""
    for lib in ThreadpoolController().lib_controllers:
        # open3d and others ship OpenMP runtimes of their own: only the system's is CHOLMOD's
        if lib.internal_api == "openblas" or (lib.user_api == "openmp" and "site-packages" not in lib.filepath):
            lib.set_num_threads(1)


def _csc(A) -> sp.csc_matrix:
    A = sp.csc_matrix(A, dtype=np.float64)
    if A.ndim != 2 or A.shape[0] != A.shape[1]:
        raise SingularSystemError(f"matrix to factorise is {A.shape[0]} x {A.shape[1]}, not square")
    # CHOLMOD takes 32-bit indices (64-bit ones would switch it to its long interface)
    A.indptr = A.indptr.astype(np.int32, copy=False)
    A.indices = A.indices.astype(np.int32, copy=False)
    A.sort_indices()
    return A


def _factorise(A: sp.csc_matrix, shifts=(0.0,), simplicial: bool = False, analysis=None):
    """CHOLMOD's factor of A + s I for the first s in `shifts` that is positive definite, with s;
    (None, message) when none is. One symbolic analysis serves every shift (`analysis`, when
    given: one made for A's pattern, kept by the caller)."""
    cholmod = _cholmod()
    CholmodError, CholmodNotPositiveDefiniteError = cholmod.CholmodError, cholmod.CholmodNotPositiveDefiniteError
    problem = "empty matrix"
    try:
        # supernodal: always L L^T, so CHOLMOD itself reports a matrix that is not positive
        # definite (its simplicial mode computes L D L^T, which accepts indefinite ones: D is
        # checked below instead)
        factor = cholmod.analyze(A, mode="simplicial" if simplicial else "supernodal") if analysis is None else analysis.copy()
    except CholmodError as exc:
        return None, f"CHOLMOD analysis failed: {exc}"
    for shift in shifts:
        try:
            factor.cholesky_inplace(A, beta=shift)
            if simplicial:
                d = factor.D()
                if not np.all(d > 0):
                    problem = f"pivot {int(np.flatnonzero(~(d > 0))[0])} of {A.shape[0]} is not positive"
                    continue
            return factor, shift
        except CholmodNotPositiveDefiniteError as exc:
            problem = f"pivot {exc.column} of {A.shape[0]} is not positive"
        except CholmodError as exc:
            problem = f"CHOLMOD failed: {exc}"
    # the exception (which holds the failed factor) is gone once its except block is left:
    # the caller raises a fresh one that keeps no reference to gigabytes of factor
    del factor
    return None, problem


class Factor:
    """A Cholesky factor of a sparse SPD matrix (CHOLMOD), with checks that it worked."""

    def __init__(self, A, *, simplicial: bool = False, _factor=None, _shift: float = 0.0):
        """`simplicial`: CHOLMOD's simplicial L D L^T, for small systems solved many times (the
        mass-spring's local/global step, where it solves faster than a supernodal one:
        docs/mass_spring.md); positive definiteness is then checked on D."""
        A = _csc(A)
        self.n = A.shape[0]
        self.shift = _shift  # the factor is of A + shift * I (see `shifted_factor`)
        self._ratio = 1.0  # the factor stands for ratio * A (`scaled`): solves are divided by it
        if _factor is None:
            _factor, problem = _factorise(A, simplicial=simplicial)
            if _factor is None:
                raise SingularSystemError(f"stiffness is singular or not positive definite: {problem}")
        self._solver = _factor
        # CHOLMOD accepts NaN entries, and a nearly singular matrix can pass: check one solve
        probe = np.ones(self.n)
        x = self.solve(probe)
        residual = A @ x + _shift * x - probe
        if not np.all(np.isfinite(x)) or np.linalg.norm(residual) > 1e-6 * np.linalg.norm(probe):
            del self._solver  # free the failed factor now, not when the exception dies
            raise SingularSystemError("stiffness is singular or not positive definite (check solve failed)")

    def with_values(self, A) -> Factor:
        """The factor of A, a matrix with this one's pattern (or part of it), reusing this
        factor's ordering and symbolic analysis: only the numeric factorisation is done (the
        corotational FEM's warped stiffness, refactorised while the hand moves)."""
        A = _csc(A)
        cholmod = _cholmod()
        factor, problem = None, ""
        try:
            factor = self._solver.cholesky(A)
        except cholmod.CholmodNotPositiveDefiniteError as exc:
            problem = f"pivot {exc.column} of {A.shape[0]} is not positive"
        except cholmod.CholmodError as exc:
            problem = f"CHOLMOD failed: {exc}"
        if factor is None:  # raised here, not in the except block: nothing holds the failed factor
            raise SingularSystemError(f"stiffness is singular or not positive definite: {problem}")
        return Factor(A, _factor=factor)

    def scaled(self, ratio: float) -> Factor:
        """The factor of `ratio` * A (ratio > 0) without factorising again: the same L, and
        every solve divided by `ratio` (a stiffness scaled by a material's modulus)."""
        out = copy.copy(self)
        out._ratio = self._ratio * float(ratio)
        return out

    @property
    def nnz_L(self) -> int:
        """Entries of the factor L: a solve is about 4 nnz_L flops per right-hand side (the
        observer's deterministic cost of a frame, studyctl/synthetic/observer.py)."""
        if not hasattr(self, "_nnz_L"):
            L = self._solver.L()
            counts = np.diff(L.indptr).astype(np.float64)  # entries per column of L (CSC)
            self._nnz_L = int(L.nnz)
            self._factor_flops = float(np.sum(counts**2))  # multiply-adds of a column Cholesky
        return self._nnz_L

    @property
    def factor_flops(self) -> float:
        """About the flops it took to factorise: the sum of squared column counts of L."""
        _ = self.nnz_L
        return self._factor_flops

    def solve(self, b: np.ndarray) -> np.ndarray:
        """A^-1 b for b of shape (n,) or (n, k)."""
        b = np.asarray(b, dtype=np.float64)
        if b.shape[:1] != (self.n,):
            raise ValueError(f"right-hand side has {b.shape[0] if b.ndim else 0} rows; the matrix has {self.n}")
        if b.size == 0:
            return np.zeros_like(b)
        return self.rescaled(self.unscaled_solve(b))

    def unscaled_solve(self, b: np.ndarray) -> np.ndarray:
        """The solve with the factor itself, before a `scaled` factor's division: the same for
        every scaling of one factor, so such a solve can be kept and shared by them."""
        return np.asarray(self._solver.solve_A(np.asarray(b, dtype=np.float64)))

    def rescaled(self, x: np.ndarray) -> np.ndarray:
        """An `unscaled_solve` as this factor's `solve` (the same bits)."""
        return x if self._ratio == 1.0 else x / self._ratio


# shifts tried by `shifted_factor`, as multiples of the mean absolute diagonal
SHIFTS = (0.0, 1e-6, 1e-4, 1e-2, 1.0, 10.0, 100.0)


def shifted_factor(K, analysis=None, shifts=SHIFTS) -> Factor:
    """Factor K, or K + tau * mean(|diag K|) * I with the smallest tau in `SHIFTS` (1e-6..100) that
    is positive definite.

    For Newton tangents that can be indefinite (the neo-Hookean reference near a buckling
    load): a shifted factorisation, not a line search. The residual is still the exact one, so
    the shifted (modified) Newton steps converge to the same equilibrium, only more slowly
    (linearly). The shift used is `Factor.shift` (0 when K itself is positive definite).
    One symbolic analysis serves every attempt; a failed attempt's memory is reused. A Newton
    solver whose tangents keep one pattern passes `analysis` (`symbolic(K)`), so that only the
    numeric factorisation is done each iteration.
    """
    A = _csc(K)
    scale = float(np.mean(np.abs(A.diagonal()))) if A.shape[0] else 1.0
    factor, shift = _factorise(A, [tau * scale for tau in shifts], analysis=analysis)
    if factor is None:
        raise SingularSystemError("tangent stiffness is not positive definite even shifted by 100 times its mean |diagonal|")
    return Factor(A, _factor=factor, _shift=shift)



def symbolic(K):
    """CHOLMOD's symbolic analysis (ordering, supernodes) of K's pattern, for `shifted_factor`."""
    return _cholmod().analyze(_csc(K), mode="supernodal")
