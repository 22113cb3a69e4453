"""knn, radius_neighbors and SpatialIndex against scipy's exact cKDTree and brute force.

Clouds cover the shapes that stress a spatial hash: uniform, clustered with far outliers,
integer lattices (many exact ties), coplanar and collinear, duplicated points, many
identical points, points on a sphere; 2-D and 3-D; self queries and explicit queries,
including queries far outside the cloud.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial import cKDTree

import elastocap
from tolerances import DISTANCE_ATOL, DISTANCE_RTOL, RADIUS_BOUNDARY_RTOL, TIE_ATOL, TIE_RTOL

# ------------------------------------------------------------------------------------------
# Clouds
# ------------------------------------------------------------------------------------------


def _uniform(rng, n, dim):
    return rng.random((n, dim))


def _clustered(rng, n, dim):
    """A few tight Gaussian clusters (sigma 1e-2) plus outliers spanning 1e4 * sigma."""
    sigma = 1e-2
    n_out = max(n // 100, 10)
    centers = rng.uniform(-1.0, 1.0, (5, dim))
    labels = rng.integers(0, len(centers), n - n_out)
    bulk = centers[labels] + sigma * rng.standard_normal((n - n_out, dim))
    outliers = rng.uniform(-50.0, 50.0, (n_out, dim))
    return rng.permutation(np.vstack([bulk, outliers]))


def _lattice(rng, n, dim):
    """An integer lattice of about n points (shuffled, shifted by an integer)."""
    side = round(n ** (1.0 / dim))
    axes = [np.arange(side, dtype=np.float64)] * dim
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, dim)
    return rng.permutation(grid + 3.0)


def _coplanar(rng, n, dim):
    assert dim == 3
    points = np.empty((n, 3))
    points[:, :2] = rng.random((n, 2))
    points[:, 2] = 0.37
    return points


def _collinear(rng, n, dim):
    t = rng.random(n)
    direction = np.array([0.3, -0.5, 0.8][:dim])
    return 2.0 + t[:, None] * direction


def _duplicated(rng, n, dim):
    """Each point repeated two or three times, shuffled."""
    base = rng.random((max(n * 2 // 5, 1), dim))
    repeats = rng.integers(2, 4, len(base))
    return rng.permutation(np.repeat(base, repeats, axis=0))


def _many_identical(rng, n, dim):
    """A third of the cloud is one and the same point."""
    same = np.full((n // 3, dim), 0.5)
    return rng.permutation(np.vstack([same, rng.random((n - len(same), dim))]))


def _sphere(rng, n, dim):
    v = rng.standard_normal((n, dim))
    return 5.0 * v / np.linalg.norm(v, axis=1, keepdims=True)


CLOUDS = {
    "uniform": _uniform,
    "clustered": _clustered,
    "lattice": _lattice,
    "coplanar": _coplanar,
    "collinear": _collinear,
    "duplicated": _duplicated,
    "many_identical": _many_identical,
    "sphere": _sphere,
}


def make_cloud(kind: str, n: int, dim: int, seed: int = 0) -> np.ndarray:
    return np.ascontiguousarray(CLOUDS[kind](np.random.default_rng(seed), n, dim), dtype=np.float64)


def make_queries(points: np.ndarray, kind: str, m: int, seed: int = 1) -> np.ndarray:
    """Query points: inside the bounding box, far outside it, on top of points, or a mix."""
    rng = np.random.default_rng(seed)
    lo, hi = points.min(axis=0), points.max(axis=0)
    extent = max(float((hi - lo).max()), 1.0)
    dim = points.shape[1]
    if kind == "inside":
        return lo + rng.random((m, dim)) * (hi - lo)
    if kind == "far":
        direction = rng.standard_normal((m, dim))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        scale = np.where(np.arange(m) % 2 == 0, 1e3, 1e6) * extent
        return (lo + hi) / 2 + direction * scale[:, None]
    if kind == "on_points":
        return points[rng.integers(0, len(points), m)].copy()
    if kind == "mixed":
        parts = [make_queries(points, k, m // 3 + 1, seed + i) for i, k in enumerate(("inside", "far", "on_points"))]
        return rng.permutation(np.vstack(parts))[:m]
    raise ValueError(kind)


def pairwise_distances(queries: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Brute force, summing squared differences axis by axis (as the library does)."""
    d2 = np.zeros((len(queries), len(points)))
    for a in range(points.shape[1]):
        d2 += (queries[:, a, None] - points[None, :, a]) ** 2
    return np.sqrt(d2)


# ------------------------------------------------------------------------------------------
# Reference checks
# ------------------------------------------------------------------------------------------


def reference_knn(points, k, queries):
    """cKDTree's (distances, indices) with k + 1 columns where possible (k when the cloud
    has no (k+1)-th candidate); for self queries the query's own index is removed from
    its row (not column 0: with duplicates, self need not come first)."""
    n = len(points)
    tree = cKDTree(points)
    if queries is None:
        kk = min(k + 2, n)
        d, i = tree.query(points, k=kk)
        d, i = d.reshape(n, kk), i.reshape(n, kk)
        drop = i == np.arange(n)[:, None]
        # Self not among the kk returned (more than kk - 1 copies at distance 0): any
        # column may go; all of them are at distance 0 like self.
        drop[~drop.any(axis=1), -1] = True
        keep = ~drop
        return d[keep].reshape(n, kk - 1), i[keep].reshape(n, kk - 1)
    kk = min(k + 1, n)
    d, i = tree.query(queries, k=kk)
    return d.reshape(len(queries), kk), i.reshape(len(queries), kk)


def assert_knn_matches(points, k, queries, distances, indices):
    q = points if queries is None else queries
    n, m = len(points), len(q)
    assert indices.shape == (m, k) and distances.shape == (m, k)
    assert indices.dtype == np.int64 and distances.dtype == np.float64

    ref_d, ref_i = reference_knn(points, k, queries)
    # Distances: the same multiset per row (both sorted ascending).
    np.testing.assert_allclose(distances, ref_d[:, :k], rtol=DISTANCE_RTOL, atol=DISTANCE_ATOL)
    assert np.all(np.diff(distances, axis=1) >= 0), "rows not sorted by distance"

    # Every returned index is a distinct valid point at the returned distance.
    assert indices.min() >= 0 and indices.max() < n
    sorted_rows = np.sort(indices, axis=1)
    assert np.all(np.diff(sorted_rows, axis=1) > 0), "an index repeats within a row"
    actual = np.sqrt(((points[indices] - q[:, None, :]) ** 2).sum(axis=-1))
    np.testing.assert_allclose(actual, distances, rtol=DISTANCE_RTOL, atol=DISTANCE_ATOL)
    if queries is None:
        assert not np.any(indices == np.arange(m)[:, None]), "a point is its own neighbour"

    # Row keys (row * n + index) for set comparisons over all rows at once.
    rows = np.arange(m)[:, None]
    got_keys = (rows * n + indices).ravel()

    # Points strictly closer than the k-th reference distance must all be returned.
    kth = ref_d[:, k - 1 : k]
    closer = ref_d[:, :k] < kth * (1 - TIE_RTOL) - TIE_ATOL
    must = (rows * n + ref_i[:, :k])[closer]
    assert np.isin(must, got_keys).all(), "a strictly nearer point is missing"

    # Where the k-th and (k+1)-th reference distances differ, the sets agree exactly.
    if ref_d.shape[1] > k:
        resolved = ref_d[:, k] > ref_d[:, k - 1] * (1 + TIE_RTOL) + TIE_ATOL
    else:
        resolved = np.ones(m, dtype=bool)
    np.testing.assert_array_equal(
        np.sort(indices[resolved], axis=1), np.sort(ref_i[resolved, :k], axis=1)
    )


def csr_rows(indptr):
    return np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))


def assert_radius_matches(points, radius, queries, distances, indices, indptr):
    q = points if queries is None else queries
    n, m = len(points), len(q)
    assert indptr.shape == (m + 1,)
    assert indptr.dtype == np.int64 and indices.dtype == np.int64 and distances.dtype == np.float64
    assert indptr[0] == 0 and np.all(np.diff(indptr) >= 0)
    assert indptr[-1] == len(indices) == len(distances)

    rows = csr_rows(indptr)
    # Distances are those of the returned points, within the (inclusive) radius.
    if len(indices):
        assert indices.min() >= 0 and indices.max() < n
        actual = np.sqrt(((points[indices] - q[rows]) ** 2).sum(axis=-1))
        np.testing.assert_allclose(distances, actual, rtol=DISTANCE_RTOL, atol=DISTANCE_ATOL)
        assert np.all(distances <= radius)
    # Each row sorted by distance.
    same_row = rows[1:] == rows[:-1]
    assert np.all(distances[1:][same_row] >= distances[:-1][same_row]), "row not sorted"

    # Same sets as cKDTree.query_ball_point (minus the point itself for self queries).
    ref = cKDTree(points).query_ball_point(q, radius)
    if queries is None:
        ref = [[j for j in row if j != i] for i, row in enumerate(ref)]
    ref_counts = np.array([len(r) for r in ref], dtype=np.int64)
    np.testing.assert_array_equal(np.diff(indptr), ref_counts)
    ref_keys = np.concatenate(
        [np.asarray(r, dtype=np.int64) + i * n for i, r in enumerate(ref)] + [np.empty(0, np.int64)]
    )
    np.testing.assert_array_equal(np.sort(rows * n + indices), np.sort(ref_keys))


# ------------------------------------------------------------------------------------------
# knn vs cKDTree
# ------------------------------------------------------------------------------------------

KNN_SELF_CASES = [
    ("uniform", 3, 20_000, 8),
    ("uniform", 2, 5_000, 5),
    ("uniform", 3, 500, 40),
    ("clustered", 3, 10_000, 10),
    ("clustered", 2, 5_000, 7),
    ("lattice", 3, 8_000, 6),
    ("lattice", 3, 8_000, 7),
    ("lattice", 3, 1_000, 26),
    ("lattice", 2, 3_600, 4),
    ("lattice", 2, 3_600, 9),
    ("coplanar", 3, 5_000, 8),
    ("collinear", 3, 2_000, 4),
    ("collinear", 2, 2_000, 3),
    ("duplicated", 3, 6_000, 5),
    ("duplicated", 2, 3_000, 3),
    ("many_identical", 3, 2_000, 10),
    ("many_identical", 3, 2_000, 700),
    ("many_identical", 2, 1_000, 400),
    ("sphere", 3, 5_000, 12),
    ("sphere", 2, 2_000, 6),
]


@pytest.mark.parametrize(("kind", "dim", "n", "k"), KNN_SELF_CASES, ids=lambda v: str(v))
def test_knn_self_queries_match_ckdtree(kind, dim, n, k):
    points = make_cloud(kind, n, dim)
    distances, indices = elastocap.knn(points, k)
    assert_knn_matches(points, k, None, distances, indices)


KNN_QUERY_CASES = [
    ("uniform", 3, 20_000, 8),
    ("uniform", 2, 5_000, 5),
    ("clustered", 3, 10_000, 10),
    ("clustered", 2, 3_000, 6),
    ("lattice", 3, 8_000, 7),
    ("lattice", 2, 3_600, 9),
    ("coplanar", 3, 5_000, 8),
    ("duplicated", 3, 3_000, 5),
    ("many_identical", 3, 1_500, 600),
    ("sphere", 3, 5_000, 12),
    ("sphere", 2, 2_000, 6),
]


@pytest.mark.parametrize("query_kind", ["inside", "far", "on_points", "mixed"])
@pytest.mark.parametrize(("kind", "dim", "n", "k"), KNN_QUERY_CASES, ids=lambda v: str(v))
def test_knn_explicit_queries_match_ckdtree(kind, dim, n, k, query_kind):
    points = make_cloud(kind, n, dim)
    queries = make_queries(points, query_kind, 700)
    distances, indices = elastocap.knn(points, k, queries=queries)
    assert_knn_matches(points, k, queries, distances, indices)


@pytest.mark.parametrize("dim", [2, 3])
def test_knn_k_equal_to_all_points(dim):
    """k = N with explicit queries (every point) and k = N - 1 without (every other point)."""
    points = make_cloud("uniform", 300, dim)
    queries = make_queries(points, "mixed", 50)
    distances, indices = elastocap.knn(points, len(points), queries=queries)
    assert_knn_matches(points, len(points), queries, distances, indices)
    distances, indices = elastocap.knn(points, len(points) - 1)
    assert_knn_matches(points, len(points) - 1, None, distances, indices)


@pytest.mark.parametrize("dim", [2, 3])
def test_knn_all_points_identical(dim):
    points = np.full((200, dim), -7.25)
    distances, indices = elastocap.knn(points, 199)
    assert np.all(distances == 0.0)
    assert_knn_matches(points, 199, None, distances, indices)


@pytest.mark.parametrize("dim", [2, 3])
def test_knn_ties_in_index_order(dim):
    """SpatialIndex.knn documents 'nearest first (ties in index order)': equidistant
    neighbours within a row come with ascending indices."""
    points = make_cloud("lattice", 1_000 if dim == 3 else 900, dim)
    distances, indices = elastocap.SpatialIndex(points).knn(8)
    tied = distances[:, 1:] == distances[:, :-1]
    assert tied.any()  # the lattice does produce ties
    assert np.all(indices[:, 1:][tied] > indices[:, :-1][tied]), "ties not in index order"


# ------------------------------------------------------------------------------------------
# knn vs brute force, hypothesis
# ------------------------------------------------------------------------------------------

# A few values, drawn often, force coincident coordinates, duplicate points and ties.
TIE_VALUES = st.sampled_from([-1.0, 0.0, 0.5, 1.0, 3.0])
FREE_VALUES = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False, allow_subnormal=False)


@st.composite
def small_clouds(draw, min_points=2, max_points=40):
    dim = draw(st.sampled_from([2, 3]))
    n = draw(st.integers(min_points, max_points))
    elements = draw(st.sampled_from([TIE_VALUES, st.one_of(TIE_VALUES, FREE_VALUES), FREE_VALUES]))
    return draw(arrays(np.float64, (n, dim), elements=elements))


def assert_knn_matches_brute_force(points, k, queries, distances, indices):
    q = points if queries is None else queries
    all_d = pairwise_distances(q, points)
    if queries is None:
        np.fill_diagonal(all_d, np.inf)
    want = np.sort(all_d, axis=1)[:, :k]
    assert indices.shape == distances.shape == (len(q), k)
    np.testing.assert_allclose(distances, want, rtol=DISTANCE_RTOL, atol=DISTANCE_ATOL)
    assert np.all(np.diff(distances, axis=1) >= 0), "rows not sorted ascending"
    # Distinct indices, each at its returned distance (never self for self queries).
    assert np.all(np.diff(np.sort(indices, axis=1), axis=1) > 0)
    got_d = np.take_along_axis(all_d, indices, axis=1)
    np.testing.assert_allclose(got_d, distances, rtol=DISTANCE_RTOL, atol=DISTANCE_ATOL)


@st.composite
def self_knn_cases(draw):
    points = draw(small_clouds())
    return points, draw(st.integers(1, len(points) - 1), label="k")


@st.composite
def query_knn_cases(draw):
    points = draw(small_clouds(min_points=1))
    m = draw(st.integers(1, 10), label="m")
    elements = st.one_of(TIE_VALUES, FREE_VALUES)
    queries = draw(arrays(np.float64, (m, points.shape[1]), elements=elements), label="queries")
    return points, queries, draw(st.integers(1, len(points)), label="k")


@settings(max_examples=300)
@given(case=self_knn_cases())
# Found by hypothesis: a duplicated point on the bounding box's maximum (see
# test_knn_duplicates_on_the_bounding_box_maximum).
@example(case=(np.array([[-0.3, 0.0], [0.9, 0.0], [0.9, 0.0]]), 1))
def test_knn_self_queries_match_brute_force(case):
    points, k = case
    distances, indices = elastocap.knn(points, k)
    assert_knn_matches_brute_force(points, k, None, distances, indices)
    assert not np.any(indices == np.arange(len(points))[:, None]), "a point is its own neighbour"


@settings(max_examples=300)
@given(case=query_knn_cases())
def test_knn_explicit_queries_match_brute_force(case):
    points, queries, k = case
    distances, indices = elastocap.knn(points, k, queries=queries)
    assert_knn_matches_brute_force(points, k, queries, distances, indices)


@pytest.mark.parametrize("k", [1, 2, 5])
@pytest.mark.parametrize("dim", [2, 3])
def test_knn_duplicates_on_the_bounding_box_maximum(dim, k):
    """A point repeated k + 1 times at the largest x of the cloud: each copy's k nearest are
    the other copies, at distance 0. Minimal case: [[-0.3, 0], [0.9, 0], [0.9, 0]], k = 1."""
    minimal = np.zeros((3, dim))
    minimal[0, 0], minimal[1:, 0] = -0.3, 0.9
    distances, indices = elastocap.knn(minimal, 1)
    np.testing.assert_array_equal(indices[:, 0], [1, 2, 1])
    np.testing.assert_array_equal(distances[:, 0], [1.2, 0.0, 0.0])

    rng = np.random.default_rng(11)
    for _ in range(40):
        points = rng.uniform(-3.0, 2.0, (200, dim))
        top = points[np.argmax(points[:, 0])]
        points = np.vstack([points] + [top] * (k + 1))
        distances, indices = elastocap.knn(points, k)
        assert_knn_matches(points, k, None, distances, indices)


# ------------------------------------------------------------------------------------------
# radius_neighbors vs cKDTree.query_ball_point
# ------------------------------------------------------------------------------------------

# Radii are never a lattice spacing (no distance sits exactly on the sphere) except in
# test_radius_lattice_points_at_exactly_the_radius_are_included.
RADIUS_CASES = [
    ("uniform", 3, 20_000, 0.06),
    ("uniform", 2, 5_000, 0.03),
    ("uniform", 3, 500, 3.0),  # larger than the cloud: every other point
    ("clustered", 3, 10_000, 0.005),
    ("clustered", 2, 5_000, 0.003),
    ("lattice", 3, 8_000, 1.5),
    ("lattice", 2, 3_600, 2.3),
    ("coplanar", 3, 5_000, 0.04),
    ("collinear", 3, 2_000, 0.01),
    ("duplicated", 3, 6_000, 0.05),
    ("duplicated", 2, 3_000, 0.03),
    ("many_identical", 3, 2_000, 0.05),
    ("sphere", 3, 5_000, 0.5),
    ("sphere", 2, 2_000, 0.1),
]


@pytest.mark.parametrize(("kind", "dim", "n", "radius"), RADIUS_CASES, ids=lambda v: str(v))
def test_radius_self_queries_match_query_ball_point(kind, dim, n, radius):
    points = make_cloud(kind, n, dim)
    result = elastocap.radius_neighbors(points, radius)
    assert_radius_matches(points, radius, None, *result)
    _, indices, indptr = result
    assert not np.any(indices == csr_rows(indptr)), "a point is its own neighbour"


@pytest.mark.parametrize("query_kind", ["inside", "far", "on_points", "mixed"])
@pytest.mark.parametrize(("kind", "dim", "n", "radius"), RADIUS_CASES, ids=lambda v: str(v))
def test_radius_explicit_queries_match_query_ball_point(kind, dim, n, radius, query_kind):
    points = make_cloud(kind, n, dim)
    queries = make_queries(points, query_kind, 500)
    result = elastocap.radius_neighbors(points, radius, queries=queries)
    assert_radius_matches(points, radius, queries, *result)


@pytest.mark.parametrize("dim", [2, 3])
def test_radius_queries_just_outside_the_cloud(dim):
    """Queries outside the bounding box but within reach of the radius."""
    points = make_cloud("uniform", 5_000, dim)
    rng = np.random.default_rng(5)
    queries = rng.random((500, dim))
    axis = rng.integers(0, dim, len(queries))
    queries[np.arange(len(queries)), axis] = np.where(rng.random(len(queries)) < 0.5, -0.05, 1.05)
    result = elastocap.radius_neighbors(points, 0.1, queries=queries)
    assert_radius_matches(points, 0.1, queries, *result)
    assert np.count_nonzero(np.diff(result.indptr)) > len(queries) // 2  # most reach the cloud


@pytest.mark.parametrize("dim", [2, 3])
def test_radius_larger_than_cloud_reaches_outside_queries(dim):
    """A radius larger than the cloud itself, queried from outside its bounding box: the
    whole cloud of unit size lies within radius 10 of a query 5 units away."""
    points = make_cloud("uniform", 500, dim)
    queries = np.zeros((3, dim))
    queries[0, 0] = 5.0
    queries[1, :] = -3.0
    queries[2, :] = 0.5  # inside, for contrast
    distances, indices, indptr = elastocap.radius_neighbors(points, 10.0, queries=queries)
    np.testing.assert_array_equal(np.diff(indptr), [500, 500, 500])
    assert_radius_matches(points, 10.0, queries, distances, indices, indptr)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("radius", [1.0, 2.0])
def test_radius_lattice_points_at_exactly_the_radius_are_included(dim, radius):
    """On an integer lattice with an integer radius, distances are exact: neighbours at
    exactly the radius must be included (the radius is inclusive)."""
    side = 9
    axes = [np.arange(side, dtype=np.float64)] * dim
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, dim)
    offsets = np.stack(np.meshgrid(*[np.arange(-2, 3)] * dim, indexing="ij"), axis=-1).reshape(-1, dim)
    norms = np.sqrt((offsets**2).sum(axis=1))
    expected_count = int(np.sum((norms <= radius) & (norms > 0)))  # 4/12 in 2-D, 6/32 in 3-D
    interior = np.all((points >= 2) & (points <= side - 3), axis=1)

    distances, indices, indptr = elastocap.radius_neighbors(points, radius)
    assert_radius_matches(points, radius, None, distances, indices, indptr)
    counts = np.diff(indptr)
    assert np.all(counts[interior] == expected_count)
    rows = csr_rows(indptr)
    assert np.any(distances[interior[rows]] == radius)

    # Explicit queries on the lattice points themselves: self (distance 0) is included.
    distances_q, indices_q, indptr_q = elastocap.radius_neighbors(points, radius, queries=points)
    assert_radius_matches(points, radius, points, distances_q, indices_q, indptr_q)
    assert np.all(np.diff(indptr_q)[interior] == expected_count + 1)
    # Nearest first: each row starts with the query point itself.
    np.testing.assert_array_equal(indices_q[indptr_q[:-1]], np.arange(len(points)))


@st.composite
def radius_cases(draw):
    points = draw(small_clouds(min_points=1))
    queries = None
    if draw(st.booleans()):
        m = draw(st.integers(1, 10), label="m")
        elements = st.one_of(TIE_VALUES, FREE_VALUES)
        queries = draw(arrays(np.float64, (m, points.shape[1]), elements=elements), label="queries")
    radius = draw(st.one_of(st.sampled_from([0.5, 1.0, 1.5, 2.0, 4.0]), st.floats(1e-3, 3e3)), label="radius")
    return points, queries, radius


@settings(max_examples=300)
@given(case=radius_cases())
def test_radius_matches_brute_force(case):
    points, queries, radius = case
    q = points if queries is None else queries
    distances, indices, indptr = elastocap.radius_neighbors(points, radius, queries=queries)
    assert indptr.shape == (len(q) + 1,) and indptr[0] == 0 and indptr[-1] == len(indices) == len(distances)
    all_d = pairwise_distances(q, points)
    if queries is None:
        np.fill_diagonal(all_d, np.inf)
    rows = csr_rows(indptr)
    np.testing.assert_allclose(distances, all_d[rows, indices], rtol=DISTANCE_RTOL, atol=DISTANCE_ATOL)
    same_row = rows[1:] == rows[:-1]
    assert np.all(distances[1:][same_row] >= distances[:-1][same_row]), "row not sorted"
    got = np.zeros(all_d.shape, dtype=bool)
    got[rows, indices] = True
    assert len(indices) == got.sum(), "an index repeats within a row"
    inner = all_d <= radius * (1 - RADIUS_BOUNDARY_RTOL)
    outer = all_d <= radius * (1 + RADIUS_BOUNDARY_RTOL)
    assert not np.any(inner & ~got), "a point inside the radius is missing"
    assert not np.any(got & ~outer), "a point outside the radius is returned"


# ------------------------------------------------------------------------------------------
# SpatialIndex
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
def test_spatial_index_properties(dim):
    points = make_cloud("uniform", 1234, dim)
    index = elastocap.SpatialIndex(points)
    assert index.n_points == 1234
    assert index.dim == dim


@pytest.mark.parametrize("dim", [2, 3])
def test_spatial_index_reuse_gives_the_same_answers_as_fresh_calls(dim):
    points = make_cloud("clustered", 3_000, dim)
    queries = make_queries(points, "mixed", 300)
    index = elastocap.SpatialIndex(points)

    fresh = {
        ("knn", 5, None): elastocap.knn(points, 5),
        ("knn", 9, "q"): elastocap.knn(points, 9, queries=queries),
        ("radius", 0.004, None): elastocap.radius_neighbors(points, 0.004),
        ("radius", 0.02, "q"): elastocap.radius_neighbors(points, 0.02, queries=queries),
    }
    # Interleave different queries on the one index, twice, in different orders.
    for order in (list(fresh), list(reversed(fresh))):
        for key in order:
            method, param, q = key
            q = queries if q else None
            got = index.knn(param, queries=q) if method == "knn" else index.radius_neighbors(param, queries=q)
            for g, f in zip(got, fresh[key], strict=True):
                np.testing.assert_array_equal(g, f)
    assert_knn_matches(points, 5, None, *fresh[("knn", 5, None)])


@pytest.mark.parametrize("dim", [2, 3])
def test_spatial_index_does_not_see_later_mutation(dim):
    points = make_cloud("uniform", 2_000, dim)
    original = points.copy()
    queries = make_queries(points, "inside", 200)
    index = elastocap.SpatialIndex(points)
    before = index.knn(6, queries=queries), index.radius_neighbors(0.05)

    points[:] = points[::-1] * 100.0 + 7.0  # overwrite the caller's array in place
    after = index.knn(6, queries=queries), index.radius_neighbors(0.05)

    for b, a in zip(before, after, strict=True):
        for x, y in zip(b, a, strict=True):
            np.testing.assert_array_equal(x, y)
    assert_knn_matches(original, 6, queries, *after[0])
    assert_radius_matches(original, 0.05, None, *after[1])


def test_spatial_index_accepts_non_contiguous_and_list_input():
    base = make_cloud("uniform", 600, 3)
    fortran = np.asfortranarray(base)
    strided = np.repeat(base, 2, axis=0)[::2]
    as_list = base.tolist()
    as_float32 = base.astype(np.float32)
    ref = elastocap.knn(base, 4)
    for variant in (fortran, strided, as_list):
        got = elastocap.SpatialIndex(variant).knn(4)
        np.testing.assert_array_equal(got[0], ref[0])
        np.testing.assert_array_equal(got[1], ref[1])
    # float32 is accepted and searched as the float64 values it holds.
    widened = as_float32.astype(np.float64)
    got = elastocap.knn(as_float32, 4)
    assert_knn_matches(widened, 4, None, *got)


def test_results_are_named_in_scipys_order():
    points = make_cloud("uniform", 500, 3)
    found = elastocap.knn(points, 4)
    assert isinstance(found, elastocap.geometry.neighbors.Neighbors)
    distances, indices = found  # scipy's cKDTree.query order
    assert distances is found.distances and indices is found.indices
    assert distances.dtype == np.float64 and indices.dtype == np.int64
    assert (np.diff(distances, axis=1) >= 0).all()
    within = elastocap.radius_neighbors(points, 0.1)
    assert within._fields == ("distances", "indices", "indptr")
    assert within.indptr[-1] == len(within.indices) == len(within.distances)
    with pytest.raises(TypeError):
        elastocap.knn(points, 4, points[:3])  # queries is keyword-only
