"""Sparse SPD solvers (SPEC 5, step 4): block-Jacobi PCG and the sparse Cholesky agree with
scipy.sparse.linalg.spsolve on random SPD block matrices and on the real EFG fitting
system; refactorisation, warm start, the iteration cap, the Cholesky preconditioner, and
bad input."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

import elastocap
from elastocap import InvalidInputError
from elastocap.solvers import SparseCholesky, conjugate_gradient
from tolerances import SOLVE_AGREEMENT_RTOL, SOLVE_CG_TOLERANCE, SOLVE_WARM_START_ITERATIONS, TWO_LEVEL_ITERATION_RATIO


def relative_error(x: np.ndarray, reference: np.ndarray) -> float:
    return float(np.linalg.norm(x - reference) / np.linalg.norm(reference))


def random_spd(n: int, block: int, density: float, seed: int) -> scipy.sparse.csr_array:
    """A random block-sparse SPD matrix: a symmetric random block pattern with random
    values, plus a diagonal that makes it strictly diagonally dominant (condition number
    a few units, so a residual of 1e-12 bounds the error well below 1e-8)."""
    rng = np.random.default_rng(seed)
    pattern = scipy.sparse.random_array((n, n), density=density, rng=rng, format="csr")
    pattern = (pattern + pattern.T + scipy.sparse.eye_array(n)).tocsr()
    off = scipy.sparse.kron(pattern, np.ones((block, block)), format="csr")
    off.data = rng.uniform(-1, 1, off.nnz)
    off = (off + off.T).tocsr()
    dominance = np.abs(off).sum(axis=1) + 1.0
    return (off + scipy.sparse.diags_array(dominance)).tocsr()


def fitting_system(
    dim: int, side: int, seed: int = 0
) -> tuple[scipy.sparse.csr_array, scipy.sparse.csr_array, np.ndarray]:
    """The real system: EFG stiffness of a jittered grid (k = 20, unit volumes) plus random
    SPD blocks ``s (0.3 I + g g^T)`` (SPEC 5's anisotropic metric, ``s`` the mean diagonal of
    K) on a random 30% of the nodes; and a random right-hand side. Returns
    ``(K, metric blocks, rhs)``."""
    rng = np.random.default_rng(seed)
    axes = np.meshgrid(*[np.arange(side, dtype=float)] * dim, indexing="ij")
    points = np.stack([a.ravel() for a in axes], axis=1) + rng.uniform(-0.3, 0.3, (side**dim, dim))
    n = len(points)
    stiffness = elastocap.stiffness_matrix(points, k=20, volumes=np.ones(n))
    scale = stiffness.diagonal().mean()
    surface = rng.choice(n, size=int(0.3 * n), replace=False)
    g = rng.normal(size=(len(surface), dim))
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    blocks = scale * (0.3 * np.eye(dim) + g[:, :, None] * g[:, None, :])
    rows = (surface[:, None, None] * dim + np.arange(dim)[None, :, None]).repeat(dim, axis=2)
    cols = (surface[:, None, None] * dim + np.arange(dim)[None, None, :]).repeat(dim, axis=1)
    metric = scipy.sparse.coo_array((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=stiffness.shape)
    return stiffness, metric.tocsr(), rng.normal(size=n * dim)


@pytest.fixture(scope="module", params=[(2, 12), (3, 6)], ids=["2d", "3d"])
def system(request: pytest.FixtureRequest) -> tuple[scipy.sparse.csr_array, np.ndarray, int]:
    dim, side = request.param
    stiffness, metric, rhs = fitting_system(dim, side)
    return (stiffness + metric).tocsr(), rhs, dim


@settings(max_examples=25, deadline=None)
@given(
    n=st.integers(1, 60),
    block=st.sampled_from([2, 3]),
    density=st.floats(0.0, 0.3),
    seed=st.integers(0, 2**32 - 1),
)
def test_random_spd_agrees_with_spsolve(n: int, block: int, density: float, seed: int) -> None:
    matrix = random_spd(n, block, density, seed)
    rhs = np.random.default_rng(seed + 1).normal(size=n * block)
    reference = scipy.sparse.linalg.spsolve(matrix.tocsc(), rhs)
    x, status = conjugate_gradient(matrix, rhs, block=block, tolerance=SOLVE_CG_TOLERANCE)
    assert status.converged and status.relative_residual <= SOLVE_CG_TOLERANCE
    assert relative_error(x, reference) <= SOLVE_AGREEMENT_RTOL
    # Any sparse format goes in; only the lower triangle matters to Cholesky.
    cholesky = SparseCholesky(matrix.tocoo(), block=block)
    assert relative_error(cholesky.solve(rhs), reference) <= SOLVE_AGREEMENT_RTOL


def test_fitting_system_agrees_with_spsolve(system: tuple[scipy.sparse.csr_array, np.ndarray, int]) -> None:
    matrix, rhs, dim = system
    reference = scipy.sparse.linalg.spsolve(matrix.tocsc(), rhs)
    x, status = conjugate_gradient(matrix, rhs, block=dim, tolerance=SOLVE_CG_TOLERANCE)
    assert status.converged and status.iterations > 0
    assert status.relative_residual <= SOLVE_CG_TOLERANCE
    assert relative_error(x, reference) <= SOLVE_AGREEMENT_RTOL
    # (N, D) in, (N, D) out.
    nodal, _ = conjugate_gradient(matrix, rhs.reshape(-1, dim), block=dim, tolerance=SOLVE_CG_TOLERANCE)
    assert nodal.shape == (len(rhs) // dim, dim)
    cholesky = SparseCholesky(matrix, block=dim)
    assert cholesky.size == matrix.shape[0] and cholesky.block == dim
    assert relative_error(cholesky.solve(rhs), reference) <= SOLVE_AGREEMENT_RTOL


def test_refactorisation_with_new_values(system: tuple[scipy.sparse.csr_array, np.ndarray, int]) -> None:
    matrix, rhs, dim = system
    cholesky = SparseCholesky(matrix, block=dim)
    # Same pattern, new values: alpha K + D changes as the fitting's weights do.
    changed = matrix.copy()
    changed.data = changed.data * 1.7
    changed = (changed + 0.5 * scipy.sparse.diags_array(matrix.diagonal())).tocsr()
    cholesky.factorize(changed)
    reference = scipy.sparse.linalg.spsolve(changed.tocsc(), rhs)
    assert relative_error(cholesky.solve(rhs), reference) <= SOLVE_AGREEMENT_RTOL
    assert relative_error(reference, scipy.sparse.linalg.spsolve(matrix.tocsc(), rhs)) > 0.1


@pytest.mark.parametrize("dim, side", [(2, 12), (3, 6)], ids=["2d", "3d"])
def test_cholesky_preconditions_the_next_iteration(dim: int, side: int) -> None:
    """The factor of K + D preconditions K + 1.3 D (the surface weights changed): the
    preconditioned spectrum lies in [1, 1.3], so CG needs a handful of iterations."""
    stiffness, metric, rhs = fitting_system(dim, side)
    factor = SparseCholesky((stiffness + metric).tocsr(), block=dim)
    changed = (stiffness + 1.3 * metric).tocsr()
    reference = scipy.sparse.linalg.spsolve(changed.tocsc(), rhs)
    x, status = conjugate_gradient(changed, rhs, block=dim, tolerance=SOLVE_CG_TOLERANCE, preconditioner=factor)
    _, jacobi = conjugate_gradient(changed, rhs, block=dim, tolerance=SOLVE_CG_TOLERANCE)
    assert status.converged and relative_error(x, reference) <= SOLVE_AGREEMENT_RTOL
    assert status.iterations <= 15 < jacobi.iterations


def test_another_pattern_is_rejected(system: tuple[scipy.sparse.csr_array, np.ndarray, int]) -> None:
    matrix, _, dim = system
    cholesky = SparseCholesky(matrix, block=dim)
    n = matrix.shape[0]
    coupled = scipy.sparse.csr_array(([1e-3, 1e-3], ([0, n - 1], [n - 1, 0])), shape=matrix.shape)
    with pytest.raises(InvalidInputError, match="pattern"):
        cholesky.factorize(matrix + coupled)


def test_warm_start_from_the_solution(system: tuple[scipy.sparse.csr_array, np.ndarray, int]) -> None:
    matrix, rhs, dim = system
    exact = scipy.sparse.linalg.spsolve(matrix.tocsc(), rhs)
    x, status = conjugate_gradient(matrix, rhs, x0=exact, block=dim, tolerance=SOLVE_CG_TOLERANCE)
    assert status.converged and status.iterations <= SOLVE_WARM_START_ITERATIONS
    assert relative_error(x, exact) <= SOLVE_AGREEMENT_RTOL
    # Nearby start: fewer iterations than a cold start.
    _, cold = conjugate_gradient(matrix, rhs, block=dim, tolerance=SOLVE_CG_TOLERANCE)
    near = exact * (1 + 1e-6 * np.random.default_rng(2).normal(size=exact.shape))
    _, warm = conjugate_gradient(matrix, rhs, x0=near, block=dim, tolerance=SOLVE_CG_TOLERANCE)
    assert warm.converged and warm.iterations < cold.iterations


def test_iteration_cap_reports_not_converged(system: tuple[scipy.sparse.csr_array, np.ndarray, int]) -> None:
    matrix, rhs, dim = system
    x, status = conjugate_gradient(matrix, rhs, block=dim, tolerance=SOLVE_CG_TOLERANCE, max_iterations=3)
    assert not status.converged and status.iterations == 3
    true_residual = np.linalg.norm(rhs - matrix @ x) / np.linalg.norm(rhs)
    assert status.relative_residual == pytest.approx(true_residual, rel=1e-9)
    # The CG residual is not monotone (the energy norm of the error is): only "not met".
    assert status.relative_residual > SOLVE_CG_TOLERANCE
    _, zero = conjugate_gradient(matrix, rhs, block=dim, max_iterations=0)
    assert not zero.converged and zero.iterations == 0 and zero.relative_residual == pytest.approx(1.0)


def test_zero_rhs_gives_zero() -> None:
    matrix = random_spd(5, 3, 0.3, 0)
    x, status = conjugate_gradient(matrix, np.zeros(15), x0=np.ones(15))
    assert status.converged and status.iterations == 0 and not x.any()


def test_bad_input_is_a_clear_error() -> None:
    matrix = random_spd(4, 3, 0.5, 1)
    rhs = np.ones(12)
    with pytest.raises(InvalidInputError, match="square"):
        conjugate_gradient(scipy.sparse.random_array((12, 9), density=0.5), rhs)
    with pytest.raises(InvalidInputError, match="multiple of the block size 3"):
        SparseCholesky(random_spd(5, 2, 0.5, 1), block=3)
    with pytest.raises(InvalidInputError, match="block must be 2 or 3"):
        conjugate_gradient(matrix, rhs, block=4)
    with pytest.raises(InvalidInputError, match="scipy.sparse"):
        conjugate_gradient(matrix.toarray(), rhs)
    asymmetric = random_spd(4, 3, 0.0, 1).tolil()  # block diagonal
    asymmetric[0, 11] = 0.1
    with pytest.raises(InvalidInputError, match="not symmetric"):
        conjugate_gradient(asymmetric.tocsr(), rhs)
    with pytest.raises(InvalidInputError, match="not symmetric"):
        SparseCholesky(asymmetric, block=3)
    nan = matrix.copy()
    nan.data[3] = np.nan
    with pytest.raises(InvalidInputError, match="non-finite"):
        conjugate_gradient(nan, rhs)
    with pytest.raises(InvalidInputError, match="non-finite"):
        SparseCholesky(nan, block=3)
    with pytest.raises(InvalidInputError, match="non-finite"):
        conjugate_gradient(matrix, np.where(np.arange(12) == 5, np.inf, 1.0))
    with pytest.raises(InvalidInputError, match=r"rhs must have shape \(12,\) or \(4, 3\)"):
        conjugate_gradient(matrix, np.ones(11))
    with pytest.raises(InvalidInputError, match="x0 must have shape"):
        conjugate_gradient(matrix, rhs, x0=np.ones(13))
    with pytest.raises(InvalidInputError, match=r"rhs must have shape"):
        SparseCholesky(matrix).solve(np.ones(10))
    with pytest.raises(InvalidInputError, match="tolerance"):
        conjugate_gradient(matrix, rhs, tolerance=-1.0)


def test_indefinite_matrix() -> None:
    """Cholesky names the row of the non-positive pivot; CG fails on a non-positive
    diagonal block, or on a direction of non-positive curvature; after a failed
    factorisation, solve refuses until a factorisation succeeds."""
    matrix = random_spd(6, 3, 0.4, 2).tolil()
    good = matrix.tocsr()
    matrix[7, 7] = -1.0
    bad = matrix.tocsr()
    with pytest.raises(elastocap.ConvergenceError, match="not positive definite.*row 7"):
        SparseCholesky(bad, block=3)
    cholesky = SparseCholesky(good, block=3)
    with pytest.raises(elastocap.ConvergenceError, match="not positive definite"):
        cholesky.factorize(bad)
    with pytest.raises(InvalidInputError, match="no factor"):
        cholesky.solve(np.ones(18))
    cholesky.factorize(good)
    assert np.allclose(good @ cholesky.solve(np.ones(18)), 1)
    with pytest.raises(elastocap.ConvergenceError, match="diagonal block"):
        conjugate_gradient(bad, np.ones(18))
    # Positive definite diagonal blocks, indefinite whole: [[I, 2I], [2I, I]].
    eye = np.eye(3)
    indefinite = scipy.sparse.csr_array(np.block([[eye, 2 * eye], [2 * eye, eye]]))
    with pytest.raises(elastocap.ConvergenceError, match="p\\^T A p <= 0"):
        conjugate_gradient(indefinite, np.array([1.0, 0, 0, -1.0, 0, 0]))
    with pytest.raises(elastocap.ConvergenceError, match="not positive definite"):
        SparseCholesky(indefinite)


def test_int64_indices_give_the_same_solution() -> None:
    """scipy uses int64 indices for large matrices; both index types are read in place."""
    matrix = random_spd(20, 2, 0.2, 3)
    wide = matrix.copy()
    wide.indptr, wide.indices = wide.indptr.astype(np.int64), wide.indices.astype(np.int64)
    rhs = np.arange(40.0)
    narrow_x, _ = conjugate_gradient(matrix, rhs, block=2)
    wide_x, _ = conjugate_gradient(wide, rhs, block=2)
    assert np.array_equal(narrow_x, wide_x)
    assert np.array_equal(SparseCholesky(matrix, block=2).solve(rhs), SparseCholesky(wide, block=2).solve(rhs))


@pytest.mark.parametrize("dim, side", [(2, 24), (3, 9)], ids=["2d", "3d"])
def test_two_level_agrees_with_spsolve_in_fewer_iterations(dim: int, side: int) -> None:
    """The rigid-mode coarse correction (``nodes=``) gives the same solution as spsolve and
    needs fewer iterations than block Jacobi on a body held only weakly (a soft surface
    term on its outer layer: the fitting with a stiff model)."""
    rng = np.random.default_rng(4)
    axes = np.meshgrid(*[np.arange(side, dtype=float)] * dim, indexing="ij")
    points = np.stack([a.ravel() for a in axes], axis=1) + rng.uniform(-0.3, 0.3, (side**dim, dim))
    n = len(points)
    model = elastocap.ElasticModel(points, np.ones(n), k=20)
    stiffness = model.stiffness()
    outer = np.flatnonzero(((points < 0.5) | (points > side - 1.5)).any(axis=1))
    weight = np.zeros(n * dim)
    weight[(outer[:, None] * dim + np.arange(dim)).ravel()] = 0.02 * stiffness.diagonal().mean()
    matrix = (stiffness + scipy.sparse.diags_array(weight)).tocsr()
    rhs = rng.normal(size=n * dim)
    reference = scipy.sparse.linalg.spsolve(matrix.tocsc(), rhs)
    x, two_level = conjugate_gradient(matrix, rhs, block=dim, tolerance=SOLVE_CG_TOLERANCE, nodes=points)
    _, jacobi = conjugate_gradient(matrix, rhs, block=dim, tolerance=SOLVE_CG_TOLERANCE)
    assert two_level.converged and relative_error(x, reference) <= SOLVE_AGREEMENT_RTOL
    assert two_level.iterations < TWO_LEVEL_ITERATION_RATIO * jacobi.iterations, (two_level, jacobi)
    with pytest.raises(InvalidInputError, match="nodes"):
        conjugate_gradient(matrix, rhs, block=dim, nodes=points[1:])
    with pytest.raises(InvalidInputError, match="nodes"):
        conjugate_gradient(matrix, rhs, block=dim, nodes=np.full_like(points, np.nan))
