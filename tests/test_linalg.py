"""The one sparse SPD factoriser (sim/linalg.py, CHOLMOD): agrees with SciPy, refuses what is not
positive definite with the project's error, shifts indefinite tangents."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from sim.errors import SimError
from sim.linalg import Factor, SingularSystemError, shifted_factor
from sim.models.fem import LinearFem
from tests.helpers import grid_tets


def laplacian(n: int) -> sp.csr_matrix:
    return sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n), format="csr")


def fem_stiffness() -> sp.csr_matrix:
    nodes, tets = grid_tets(np.ones((3, 3, 4), bool), np.zeros(3), 0.01)
    return LinearFem(nodes, tets, 3000.0, 0.45, nodes[:, 2] < 1e-9).reduced


@pytest.mark.parametrize("simplicial", [False, True])
@pytest.mark.parametrize("make", [fem_stiffness, lambda: laplacian(200), lambda: sp.random(300, 300, 0.01, random_state=1, format="csr")])
def test_agrees_with_spsolve(make, simplicial):
    A = make()
    if A.shape == (300, 300):  # a random sparse SPD matrix: B B^T + I
        A = (A @ A.T + sp.identity(300)).tocsr()
    rng = np.random.default_rng(0)
    b = rng.standard_normal(A.shape[0])
    B = rng.standard_normal((A.shape[0], 3))
    f = Factor(A, simplicial=simplicial)
    x = f.solve(b)
    assert x.shape == b.shape
    assert np.linalg.norm(x - spsolve(A.tocsc(), b)) <= 1e-10 * np.linalg.norm(x)
    X = f.solve(B)  # several right-hand sides at once, as the grasp's three solves
    assert X.shape == B.shape
    assert np.linalg.norm(X - spsolve(A.tocsc(), B)) <= 1e-10 * np.linalg.norm(X)


@pytest.mark.parametrize("name, A", [
    ("indefinite", laplacian(50) - 0.5 * sp.identity(50)),  # CHOLMOD's L D L^T would accept it
    ("negative definite", -laplacian(50)),
    ("singular", sp.diags([1.0] * 49 + [0.0])),
    ("NaN", sp.diags([1.0] * 49 + [np.nan])),
    ("rigid-body modes", sp.csr_matrix(np.ones((4, 4)))),
])
@pytest.mark.parametrize("simplicial", [False, True])
def test_not_positive_definite_raises_the_projects_error(name, A, simplicial):
    with pytest.raises(SingularSystemError, match="not positive definite") as info:
        Factor(A, simplicial=simplicial)
    assert isinstance(info.value, SimError)  # the CLI prints it as one line
    # no scikit-sparse exception chained to it (it would hold the failed factor's memory)
    assert info.value.__cause__ is None
    assert info.value.__context__ is None


def test_shifted_factor():
    A = laplacian(50)
    f = shifted_factor(A)
    assert f.shift == 0.0
    K = (A - 0.5 * sp.identity(50)).tocsr()  # indefinite: the smallest shift that works
    f = shifted_factor(K)
    assert f.shift == pytest.approx(np.mean(K.diagonal()))  # 1e-2 of it is not enough, 1 is
    b = np.ones(50)
    x = f.solve(b)
    assert np.linalg.norm(K @ x + f.shift * x - b) < 1e-10
    with pytest.raises(SingularSystemError, match="even shifted"):
        shifted_factor(sp.diags([1.0] * 499 + [-1e9]))  # 100 x the mean |diagonal| is 2e8


def test_with_values_reuses_the_analysis_and_refuses_what_is_not_positive_definite():
    """New values on the same pattern (the warped FEM tangent): the same answer as a fresh
    factorisation; an indefinite matrix raises the project's error, nothing chained."""
    K = fem_stiffness()
    f = Factor(K)
    K2 = (1.7 * K + sp.diags(np.random.default_rng(1).random(K.shape[0]) * K.diagonal())).tocsr()
    b = np.ones(K.shape[0])
    assert np.allclose(f.with_values(K2).solve(b), spsolve(K2.tocsc(), b), rtol=1e-9)
    with pytest.raises(SingularSystemError, match="not positive definite") as info:
        f.with_values(-K)
    assert info.value.__cause__ is None
    assert info.value.__context__ is None


def test_every_blas_pool_runs_one_thread_once_cholmod_is_loaded():
    # the same bits in any process (issue 25): CHOLMOD's factor depends on the BLAS thread count
    from threadpoolctl import threadpool_info

    from sim.linalg import _cholmod

    _cholmod()
    pools = [p for p in threadpool_info() if p["internal_api"] == "openblas"]
    # CHOLMOD's, numpy's and scipy's own (scipy.libs), this image's wheels and system packages
    assert {p["prefix"] for p in pools} >= {"libopenblas", "libscipy_openblas"}, pools
    assert len(pools) >= 3, pools
    assert all(p["num_threads"] == 1 for p in pools), pools
    omp = [p for p in threadpool_info() if p["user_api"] == "openmp" and "site-packages" not in p["filepath"]]
    assert all(p["num_threads"] == 1 for p in omp), omp
