"""Bad input raises InvalidInputError (also a ValueError and an ElastocapError) whose message
names the offending argument; valid edge cases work; numerical failure on valid input
raises ConvergenceError or is reported in a returned status."""

from __future__ import annotations

import re

import numpy as np
import pytest
import scipy.sparse

import elastocap
from elastocap import SparseCholesky, conjugate_gradient
from elastocap.body import BodyModel, BodyObservations, BodyState, fit_body
from tolerances import DISTANCE_ATOL, DISTANCE_RTOL, ROTATION_MATCH_ATOL

RNG = np.random.default_rng(0)
POINTS3 = RNG.random((10, 3))
POINTS2 = RNG.random((10, 2))


def assert_invalid(argument: str, call, *args, **kwargs) -> elastocap.InvalidInputError:
    """``call(*args, **kwargs)`` raises InvalidInputError naming ``argument``."""
    with pytest.raises(elastocap.InvalidInputError, match=rf"\b{re.escape(argument)}\b") as info:
        call(*args, **kwargs)
    assert isinstance(info.value, ValueError)
    assert isinstance(info.value, elastocap.ElastocapError)
    return info.value


def test_exception_hierarchy():
    assert issubclass(elastocap.ElastocapError, Exception)
    assert issubclass(elastocap.InvalidInputError, elastocap.ElastocapError)
    assert issubclass(elastocap.InvalidInputError, ValueError)
    assert issubclass(elastocap.ConvergenceError, elastocap.ElastocapError)
    assert not issubclass(elastocap.ConvergenceError, ValueError)


# ------------------------------------------------------------------------------------------
# points: every entry point that takes them
# ------------------------------------------------------------------------------------------

POINT_ENTRIES = {
    "knn": lambda points: elastocap.knn(points, 1),
    "radius_neighbors": lambda points: elastocap.radius_neighbors(points, 0.5),
    "SpatialIndex": lambda points: elastocap.SpatialIndex(points),
}
points_entry = pytest.mark.parametrize("entry", list(POINT_ENTRIES.values()), ids=list(POINT_ENTRIES))


@points_entry
def test_points_with_four_columns(entry):
    assert_invalid("points", entry, np.zeros((5, 4)))


@points_entry
def test_points_with_one_column(entry):
    assert_invalid("points", entry, np.zeros((5, 1)))


@points_entry
def test_points_one_dimensional(entry):
    assert_invalid("points", entry, np.zeros(3))


@points_entry
def test_points_three_dimensional(entry):
    assert_invalid("points", entry, np.zeros((4, 5, 3)))


@points_entry
def test_points_scalar(entry):
    assert_invalid("points", entry, 1.0)


@points_entry
def test_points_complex_dtype(entry):
    assert_invalid("points", entry, POINTS3.astype(np.complex128))


@points_entry
def test_points_string_dtype(entry):
    assert_invalid("points", entry, np.array([["0", "1", "2"], ["3", "4", "5"]]))


@points_entry
def test_points_object_dtype(entry):
    assert_invalid("points", entry, np.array([[0.0, 1.0, None], [1.0, 2.0, 3.0]], dtype=object))


@points_entry
def test_points_bool_dtype(entry):
    assert_invalid("points", entry, np.ones((4, 3), dtype=bool))


@points_entry
def test_points_with_nan(entry):
    points = POINTS3.copy()
    points[7, 1] = np.nan
    assert_invalid("points", entry, points)


@pytest.mark.parametrize("value", [np.inf, -np.inf], ids=["+inf", "-inf"])
@points_entry
def test_points_with_inf(entry, value):
    points = POINTS2.copy()
    points[3, 0] = value
    assert_invalid("points", entry, points)


@points_entry
def test_points_empty(entry):
    assert_invalid("points", entry, np.zeros((0, 3)))


# ------------------------------------------------------------------------------------------
# queries
# ------------------------------------------------------------------------------------------

QUERY_ENTRIES = {
    "knn": lambda points, queries: elastocap.knn(points, 2, queries=queries),
    "radius_neighbors": lambda points, queries: elastocap.radius_neighbors(points, 0.5, queries=queries),
    "SpatialIndex.knn": lambda points, queries: elastocap.SpatialIndex(points).knn(2, queries=queries),
    "SpatialIndex.radius_neighbors": lambda points, queries: elastocap.SpatialIndex(points).radius_neighbors(
        0.5, queries=queries
    ),
}
queries_entry = pytest.mark.parametrize("entry", list(QUERY_ENTRIES.values()), ids=list(QUERY_ENTRIES))


@queries_entry
def test_queries_with_nan(entry):
    queries = RNG.random((6, 3))
    queries[5, 2] = np.nan
    assert_invalid("queries", entry, POINTS3, queries)


@queries_entry
def test_queries_with_inf(entry):
    queries = RNG.random((6, 2))
    queries[0, 0] = np.inf
    assert_invalid("queries", entry, POINTS2, queries)


@queries_entry
def test_queries_empty(entry):
    assert_invalid("queries", entry, POINTS3, np.zeros((0, 3)))


@queries_entry
def test_queries_2d_against_3d_points(entry):
    assert_invalid("queries", entry, POINTS3, RNG.random((4, 2)))


@queries_entry
def test_queries_3d_against_2d_points(entry):
    assert_invalid("queries", entry, POINTS2, RNG.random((4, 3)))


@queries_entry
def test_queries_one_dimensional(entry):
    assert_invalid("queries", entry, POINTS3, np.zeros(3))


@queries_entry
def test_queries_complex_dtype(entry):
    assert_invalid("queries", entry, POINTS3, RNG.random((4, 3)).astype(np.complex128))


# ------------------------------------------------------------------------------------------
# k
# ------------------------------------------------------------------------------------------

KNN_ENTRIES = {
    "knn": lambda points, k, queries=None: elastocap.knn(points, k, queries=queries),
    "SpatialIndex.knn": lambda points, k, queries=None: elastocap.SpatialIndex(points).knn(k, queries=queries),
}
knn_entry = pytest.mark.parametrize("entry", list(KNN_ENTRIES.values()), ids=list(KNN_ENTRIES))


@knn_entry
def test_k_zero(entry):
    assert_invalid("k", entry, POINTS3, 0)


@knn_entry
def test_k_zero_with_queries(entry):
    assert_invalid("k", entry, POINTS3, 0, POINTS3[:2])


@knn_entry
def test_k_equal_to_number_of_points_for_self_queries(entry):
    """A point is not its own neighbour: self queries have N - 1 candidates."""
    assert_invalid("k", entry, POINTS3, len(POINTS3))


@knn_entry
def test_k_above_number_of_points_for_self_queries(entry):
    assert_invalid("k", entry, POINTS2, len(POINTS2) + 5)


@knn_entry
def test_k_above_number_of_points_with_queries(entry):
    assert_invalid("k", entry, POINTS3, len(POINTS3) + 1, RNG.random((3, 3)))


@knn_entry
def test_k_not_an_integer(entry):
    assert_invalid("k", entry, POINTS3, 2.5)


@knn_entry
def test_k_integral_float(entry):
    assert_invalid("k", entry, POINTS3, 2.0)


@knn_entry
def test_k_bool(entry):
    assert_invalid("k", entry, POINTS3, True)


@knn_entry
def test_k_string(entry):
    assert_invalid("k", entry, POINTS3, "3")


@knn_entry
def test_k_negative(entry):
    assert_invalid("k", entry, POINTS3, -1)


@knn_entry
def test_k_too_large_for_any_integer_type(entry):
    assert_invalid("k", entry, POINTS3, 2**70)


# ------------------------------------------------------------------------------------------
# radius
# ------------------------------------------------------------------------------------------

RADIUS_ENTRIES = {
    "radius_neighbors": lambda points, radius: elastocap.radius_neighbors(points, radius),
    "radius_neighbors+queries": lambda points, radius: elastocap.radius_neighbors(points, radius, queries=points[:3]),
    "SpatialIndex.radius_neighbors": lambda points, radius: elastocap.SpatialIndex(points).radius_neighbors(radius),
}
radius_entry = pytest.mark.parametrize("entry", list(RADIUS_ENTRIES.values()), ids=list(RADIUS_ENTRIES))


@radius_entry
def test_radius_zero(entry):
    assert_invalid("radius", entry, POINTS3, 0.0)


@radius_entry
def test_radius_negative(entry):
    assert_invalid("radius", entry, POINTS3, -0.5)


@radius_entry
def test_radius_nan(entry):
    assert_invalid("radius", entry, POINTS3, float("nan"))


@radius_entry
def test_radius_inf(entry):
    assert_invalid("radius", entry, POINTS3, float("inf"))


@radius_entry
def test_radius_minus_inf(entry):
    assert_invalid("radius", entry, POINTS3, float("-inf"))


@radius_entry
def test_radius_not_a_number(entry):
    assert_invalid("radius", entry, POINTS3, "wide")


@radius_entry
def test_radius_none(entry):
    assert_invalid("radius", entry, POINTS3, None)


# ------------------------------------------------------------------------------------------
# polar_rotation
# ------------------------------------------------------------------------------------------


def test_polar_non_square_batch():
    assert_invalid("matrices", elastocap.polar_rotation, np.zeros((5, 3, 2)))


def test_polar_four_by_four_batch():
    assert_invalid("matrices", elastocap.polar_rotation, np.zeros((5, 4, 4)))


def test_polar_single_non_square():
    assert_invalid("matrices", elastocap.polar_rotation, np.zeros((2, 3)))


def test_polar_one_dimensional():
    assert_invalid("matrices", elastocap.polar_rotation, np.zeros(9))


def test_polar_four_dimensional():
    assert_invalid("matrices", elastocap.polar_rotation, np.zeros((2, 2, 3, 3)))


def test_polar_nan_matrix():
    matrices = RNG.random((4, 3, 3))
    matrices[2, 1, 1] = np.nan
    assert_invalid("matrices", elastocap.polar_rotation, matrices)


def test_polar_inf_matrix():
    matrices = RNG.random((4, 2, 2))
    matrices[0, 0, 1] = -np.inf
    assert_invalid("matrices", elastocap.polar_rotation, matrices)


def test_polar_nan_single_matrix_with_stretch():
    matrix = np.eye(3)
    matrix[0, 2] = np.nan
    assert_invalid("matrices", elastocap.polar_rotation, matrix, return_stretch=True)


def test_polar_empty_batch():
    assert_invalid("matrices", elastocap.polar_rotation, np.zeros((0, 3, 3)))


def test_polar_complex_dtype():
    assert_invalid("matrices", elastocap.polar_rotation, np.eye(3, dtype=np.complex128)[None])


def test_polar_object_dtype():
    assert_invalid("matrices", elastocap.polar_rotation, np.array([[1.0, None], [0.0, 1.0]], dtype=object))


# ------------------------------------------------------------------------------------------
# Valid edge cases
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
def test_k_n_minus_one_for_self_queries(dim):
    points = RNG.random((7, dim))
    distances, indices = elastocap.knn(points, 6)
    assert indices.shape == distances.shape == (7, 6)
    for i, row in enumerate(indices):
        assert sorted(row) == [j for j in range(7) if j != i]
    assert np.all(np.diff(distances, axis=1) >= 0)


@pytest.mark.parametrize("dim", [2, 3])
def test_single_point_index_with_queries_and_k_one(dim):
    point = RNG.random((1, dim))
    queries = RNG.random((5, dim)) * 10 - 5
    index = elastocap.SpatialIndex(point)
    assert index.n_points == 1 and index.dim == dim
    distances, indices = index.knn(1, queries=queries)
    np.testing.assert_array_equal(indices, np.zeros((5, 1), dtype=np.int64))
    np.testing.assert_allclose(
        distances[:, 0], np.linalg.norm(queries - point, axis=1), rtol=DISTANCE_RTOL, atol=DISTANCE_ATOL
    )
    # Self queries: no other point to find.
    assert_invalid("k", index.knn, 1)
    dist, found, indptr = index.radius_neighbors(100.0)
    np.testing.assert_array_equal(indptr, [0, 0])
    assert len(found) == len(dist) == 0


@pytest.mark.parametrize("dtype", [np.int64, np.int32, np.uint8])
def test_integer_points_accepted(dtype):
    grid = np.stack(np.meshgrid(np.arange(6), np.arange(6), np.arange(6), indexing="ij"), -1).reshape(-1, 3)
    points = grid.astype(dtype)
    as_float = grid.astype(np.float64)
    for got, want in zip(elastocap.knn(points, 4), elastocap.knn(as_float, 4), strict=True):
        np.testing.assert_array_equal(got, want)
    for got, want in zip(
        elastocap.radius_neighbors(points, 1, queries=points[:5]), elastocap.radius_neighbors(as_float, 1.0, queries=as_float[:5]),
        strict=True,
    ):
        np.testing.assert_array_equal(got, want)
    assert elastocap.SpatialIndex(points).n_points == len(grid)


def test_numpy_integer_k_and_list_inputs_accepted():
    points = POINTS3.tolist()
    distances, indices = elastocap.knn(points, np.int64(3), queries=[[0.5, 0.5, 0.5]])
    assert indices.shape == distances.shape == (1, 3)
    _, indices_u = elastocap.knn(POINTS3, np.uint16(3), queries=np.array([[0.5, 0.5, 0.5]]))
    np.testing.assert_array_equal(indices, indices_u)


def test_polar_integer_matrices_accepted():
    r = elastocap.polar_rotation(np.array([[[0, -2, 0], [2, 0, 0], [0, 0, 3]]]))
    np.testing.assert_allclose(r[0], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=ROTATION_MATCH_ATOL)


# ------------------------------------------------------------------------------------------
# Numerical failure on valid input: ConvergenceError, or a status where documented
# ------------------------------------------------------------------------------------------


def _indefinite_with_spd_blocks() -> scipy.sparse.csr_array:
    """[[I, 2I], [2I, I]]: positive definite 3x3 diagonal blocks, indefinite as a whole."""
    eye = np.eye(3)
    return scipy.sparse.csr_array(np.block([[eye, 2 * eye], [2 * eye, eye]]))


def test_conjugate_gradient_on_a_matrix_that_is_not_positive_definite_raises_convergence_error():
    """Found by CG itself (a direction of non-positive curvature) or by its block-Jacobi
    preconditioner (a diagonal block with a non-positive pivot): ConvergenceError, not
    InvalidInputError (the matrix is well formed)."""
    with pytest.raises(elastocap.ConvergenceError, match=r"not positive definite.*p\^T A p <= 0") as info:
        conjugate_gradient(_indefinite_with_spd_blocks(), np.array([1.0, 0, 0, -1.0, 0, 0]))
    assert not isinstance(info.value, ValueError)
    negative = scipy.sparse.csr_array(np.diag([2.0, 2.0, -1.0, 2.0, 2.0, 2.0]))
    with pytest.raises(elastocap.ConvergenceError, match=r"not positive definite.*diagonal block.*row 2"):
        conjugate_gradient(negative, np.ones(6))
    # The same matrices on the coarse (two-level) path.
    with pytest.raises(elastocap.ConvergenceError, match="not positive definite"):
        conjugate_gradient(negative, np.ones(6), nodes=np.zeros((2, 3)))


def test_conjugate_gradient_out_of_iterations_reports_it_in_its_status():
    """Running out of iterations is not an exception: the status says so."""
    rng = np.random.default_rng(4)
    a = rng.standard_normal((30, 30))
    spd = scipy.sparse.csr_array(a @ a.T + 0.1 * np.eye(30))
    x, status = conjugate_gradient(spd, np.ones(30), tolerance=1e-12, max_iterations=2)
    assert not status.converged
    assert status.iterations == 2
    assert status.relative_residual > 1e-12
    assert np.isfinite(x).all()


def test_sparse_cholesky_of_an_indefinite_matrix_raises_convergence_error_naming_the_row():
    with pytest.raises(elastocap.ConvergenceError, match="not positive definite"):
        SparseCholesky(_indefinite_with_spd_blocks(), block=3)
    negative = scipy.sparse.csr_array(np.diag([2.0, 2.0, 2.0, 2.0, -1.0, 2.0]))
    with pytest.raises(elastocap.ConvergenceError, match="row 4"):
        SparseCholesky(negative, block=3)


def test_body_fit_that_cannot_converge_in_its_iterations_reports_it_in_its_status():
    model = BodyModel.default_human()
    truth = model.rest_state(position=(0, 0, 0.95))
    points = model.skin_points(truth, 800, seed=2, spacing=0.02)
    start = truth.motion.copy()
    start[6:] = np.clip(start[6:] + 0.2, model.lower[6:], model.upper[6:])
    init = BodyState(truth.shape.copy(), start)
    # The shape held: one LM run (with the shape fitted, a motion-only run comes first).
    fit = fit_body(model, [BodyObservations(points=points)], init=init, shape=truth.shape, max_iterations=2)
    assert fit.status == "maximum iterations"
    assert fit.iterations == 2
    assert fit.final_cost < fit.initial_cost  # it did make progress, it just did not finish


@pytest.mark.parametrize("dim", [2, 3])
def test_mls_neighbourhood_singular_after_enlarging_the_support_is_invalid_input_naming_the_node(dim):
    """SPEC 4.2: the support is enlarged before giving up; points on a line (2-D) or in a
    plane (3-D) stay degenerate at any support, which is bad input, named by node."""
    rng = np.random.default_rng(5)
    t = rng.random((40, 2))
    points = np.c_[t[:, 0], 2 * t[:, 0]] if dim == 2 else np.c_[t, t[:, 0] + t[:, 1]]
    with pytest.raises(elastocap.InvalidInputError, match=r"node \d+ do not span.*support enlarged") as info:
        elastocap.mls_shape_functions(points, k=8)
    assert isinstance(info.value, ValueError)
    assert not isinstance(info.value, elastocap.ConvergenceError)
