"""TriangleMesh (parry's BVH) against independent numpy brute force: point-to-triangle
distances on adversarial triangle soups, signs against the generalised winding number on
closed meshes, ray casts against Möller-Trumbore, and the documented edge cases."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from tolerances import MESH_DISTANCE_RTOL, WINDING_MARGIN

from elastocap._core import InvalidInputError
from elastocap.geometry._distance import distance_to_mesh
from elastocap.geometry.mesh_distance import TriangleMesh

# Slivers down to this log10 of height over length (10,000:1). Past ~1e5:1 a double-precision
# plane normal is off by more than 1e-12 of the size in parry and in the numpy reference alike
# (both checked against exact rational arithmetic): not a property either can keep.
THINNEST = -4


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(M, T) distances of points (M, 1, 3) to segments (1, T, 3)."""
    ab = b - a
    length2 = np.einsum("...i,...i", ab, ab)
    t = np.einsum("...i,...i", p - a, ab) / np.where(length2 > 0, length2, 1.0)
    t = np.clip(np.where(length2 > 0, t, 0.0), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def brute_force_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Exact unsigned distance of each point to the nearest triangle, by checking all.

    The distance to a triangle is the distance to its plane when the point's projection falls
    inside it (three edge-side tests, each a triple product, robust for slivers), else the
    distance to the nearest of its three edges."""
    p = points[:, None, :]
    a, b, c = (vertices[faces[:, i]][None] for i in range(3))
    edges = np.minimum(np.minimum(_segment_distance(p, a, b), _segment_distance(p, b, c)), _segment_distance(p, c, a))
    n = np.cross(b - a, c - a)
    area2 = np.linalg.norm(n, axis=-1)
    unit = n / np.where(area2 > 0, area2, 1.0)[..., None]
    plane = np.einsum("...i,...i", p - a, unit)
    q = p - plane[..., None] * unit
    sides = [np.einsum("...i,...i", np.cross(v1 - v0, q - v0), n) for v0, v1 in ((a, b), (b, c), (c, a))]
    inside = (area2 > 0) & (sides[0] >= 0) & (sides[1] >= 0) & (sides[2] >= 0)
    return np.where(inside, np.minimum(np.abs(plane), edges), edges).min(axis=1)


def winding_number(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Generalised winding number (solid angles by Van Oosterom & Strackee): 1 inside a
    closed outward mesh, 0 outside."""
    a, b, c = (vertices[faces[:, i]][None] - points[:, None, :] for i in range(3))
    la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
    numerator = np.einsum("...i,...i", a, np.cross(b, c))
    denominator = (
        la * lb * lc + np.einsum("...i,...i", a, b) * lc + np.einsum("...i,...i", b, c) * la + np.einsum("...i,...i", c, a) * lb
    )
    return np.arctan2(numerator, denominator).sum(axis=1) / (2 * np.pi)


@st.composite
def triangle_soups(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangles of sizes over four decades, a third of them slivers (aspect up to 1e9),
    some collapsed to segments; queries on and near edges and vertices, inside the soup's
    box and far from it."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    count = draw(st.integers(1, 60))
    a = rng.uniform(-1, 1, (count, 3))
    sizes = 10.0 ** rng.uniform(-4, 0, count)[:, None]
    b = a + sizes * rng.normal(size=(count, 3))
    c = a + sizes * rng.normal(size=(count, 3))
    kind = rng.integers(0, 6, count)
    thin = 10.0 ** rng.uniform(THINNEST, -2, count)[:, None]
    sliver = a + rng.uniform(0, 1, (count, 1)) * (b - a) + thin * sizes * rng.normal(size=(count, 3))
    c = np.where((kind < 2)[:, None], sliver, c)
    c = np.where((kind == 2)[:, None], a, c)  # collapsed onto an edge
    vertices = np.concatenate([a, b, c])
    faces = np.arange(3 * count).reshape(3, count).T.copy()
    m = 64
    pick = rng.integers(0, count, m)
    on_edge = a[pick] + rng.uniform(0, 1, (m, 1)) * (b[pick] - a[pick])
    near = np.concatenate([on_edge, a[pick], c[pick]]) + 10.0 ** rng.uniform(-12, -2, (3 * m, 1)) * rng.normal(size=(3 * m, 3))
    far = rng.normal(size=(16, 3)) * 10.0 ** rng.uniform(1, 3, (16, 1))
    queries = np.concatenate([near, rng.uniform(-2, 2, (m, 3)), far])
    return vertices, faces, queries


@settings(max_examples=60, deadline=None)
@given(triangle_soups())
def test_distances_equal_brute_force_on_adversarial_soups(soup: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    vertices, faces, queries = soup
    mesh = TriangleMesh(vertices, faces)
    # The mesh's size, or the size of its coordinates for a tiny mesh far from the origin
    # (coordinates of magnitude L are only known to eps L).
    tolerance = MESH_DISTANCE_RTOL * max(mesh.size, float(np.abs(vertices).max()))
    expected = brute_force_distance(queries, vertices, faces)
    found = mesh.closest_points(queries)
    np.testing.assert_allclose(found.distances, expected, rtol=0, atol=tolerance)
    np.testing.assert_allclose(mesh.distances(queries), expected, rtol=0, atol=tolerance)
    # The closest point is at that distance and lies on the triangle reported.
    np.testing.assert_allclose(np.linalg.norm(queries - found.points, axis=1), expected, rtol=0, atol=tolerance)
    on_own = [brute_force_distance(found.points[i : i + 1], vertices, faces[found.triangles[i] : found.triangles[i] + 1])[0] for i in range(len(queries))]
    np.testing.assert_allclose(on_own, 0.0, rtol=0, atol=tolerance)


def _lumpy_sphere(seed: int, subdivisions: int) -> trimesh.Trimesh:
    """A closed star-shaped mesh: an icosphere with radii varied over 0.3..1."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    rng = np.random.default_rng(seed)
    radii = rng.uniform(0.3, 1.0, len(sphere.vertices))
    return trimesh.Trimesh(sphere.vertices * radii[:, None], sphere.faces, process=False)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 2))
def test_signs_and_containment_agree_with_the_winding_number(seed: int, subdivisions: int) -> None:
    solid = _lumpy_sphere(seed, subdivisions)
    rng = np.random.default_rng(seed)
    queries = np.concatenate(
        [rng.uniform(-1.1, 1.1, (300, 3)), solid.vertices + 1e-3 * rng.normal(size=solid.vertices.shape)]
    )
    winding = winding_number(queries, solid.vertices, solid.faces)
    clear = np.abs(winding - 0.5) > WINDING_MARGIN  # leave out points whose reference is unsure
    mesh = TriangleMesh(solid)
    signed = mesh.distances(queries, signed=True)
    unsigned = brute_force_distance(queries, solid.vertices, solid.faces)
    np.testing.assert_allclose(np.abs(signed), unsigned, rtol=0, atol=MESH_DISTANCE_RTOL * mesh.size)
    away = clear & (unsigned > MESH_DISTANCE_RTOL * mesh.size)
    np.testing.assert_array_equal((signed < 0)[away], (winding > 0.5)[away])
    np.testing.assert_array_equal(mesh.contains(queries)[away], (winding > 0.5)[away])
    assert mesh.volume == pytest.approx(solid.volume, rel=1e-12)


def _moller_trumbore(origins: np.ndarray, directions: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(M,) smallest t >= 0 of each ray over all triangles (inf for a miss)."""
    a, b, c = (vertices[faces[:, i]][None] for i in range(3))
    e1, e2 = b - a, c - a
    d = directions[:, None, :]
    pvec = np.cross(d, e2)
    det = np.einsum("...i,...i", e1, pvec)
    inv = 1.0 / np.where(det != 0, det, np.inf)
    s = origins[:, None, :] - a
    u = np.einsum("...i,...i", s, pvec) * inv
    qvec = np.cross(s, e1)
    v = np.einsum("...i,...i", d, qvec) * inv
    t = np.einsum("...i,...i", e2, qvec) * inv
    hit = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0)
    return np.where(hit, t, np.inf).min(axis=1)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_ray_casts_equal_brute_force(seed: int) -> None:
    solid = _lumpy_sphere(seed, 2)
    rng = np.random.default_rng(seed)
    origins = np.concatenate([rng.uniform(-3, 3, (200, 3)), rng.uniform(-0.1, 0.1, (50, 3))])  # outside, inside
    directions = rng.normal(size=origins.shape) * rng.uniform(0.5, 2.0, (len(origins), 1))
    hits = TriangleMesh(solid).cast_rays(origins, directions)
    expected = _moller_trumbore(origins, directions, solid.vertices, solid.faces)
    assert np.isinf(expected).any() and np.isfinite(expected).any()
    np.testing.assert_array_equal(np.isinf(hits.distances), np.isinf(expected))
    finite = np.isfinite(expected)
    np.testing.assert_allclose(hits.distances[finite], expected[finite], rtol=1e-9)
    assert np.all((hits.triangles >= 0) == finite)
    # The hit point lies on the triangle reported.
    points = origins[finite] + hits.distances[finite, None] * directions[finite]
    on_own = [brute_force_distance(p[None], solid.vertices, solid.faces[t : t + 1])[0] for p, t in zip(points, hits.triangles[finite])]
    assert max(on_own) < 1e-9
    short = TriangleMesh(solid).cast_rays(origins, directions, max_distance=0.0)
    assert np.all(np.isinf(short.distances) | (short.distances == 0))


def test_degenerate_triangles_are_segments_and_points() -> None:
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [5, 5, 5]])
    mesh = TriangleMesh(vertices, np.array([[0, 1, 2], [3, 3, 3]]))
    found = mesh.closest_points(np.array([[1.5, 1.0, 0.0], [-1.0, 0, 0], [5, 5, 6]]))
    np.testing.assert_allclose(found.distances, [1.0, 1.0, 1.0], atol=1e-15)
    np.testing.assert_array_equal(found.triangles, [0, 0, 1])


def test_empty_queries_give_empty_results() -> None:
    mesh = TriangleMesh(trimesh.creation.box())
    found = mesh.closest_points(np.zeros((0, 3)))
    assert found.points.shape == (0, 3) and found.distances.shape == (0,) and found.triangles.shape == (0,)
    assert mesh.contains(np.zeros((0, 3))).shape == (0,)


@pytest.mark.parametrize(
    ("vertices", "faces", "message"),
    [
        (np.zeros((0, 3)), np.zeros((0, 3), np.int64), "vertices is empty"),
        (np.eye(3), np.zeros((0, 3), np.int64), "triangles is empty"),
        (np.eye(3), np.array([[0, 1, 3]]), r"triangles\[0\] = 3 is out of range"),
        (np.eye(3), np.array([[0, -1, 2]]), "out of range"),
        (np.array([[0.0, 0, 0], [1, 0, 0], [0, np.nan, 0]]), np.array([[0, 1, 2]]), "non-finite value .* row 2"),
        (np.eye(4), np.array([[0, 1, 2]]), r"vertices must have shape \(N, 3\)"),
        (np.eye(3), np.array([[0.0, 1, 2]]), "faces must hold integer"),
        (np.eye(3), np.array([0, 1, 2]), r"faces must have shape \(M, 3\)"),
    ],
)
def test_bad_meshes_raise_naming_the_argument(vertices: np.ndarray, faces: np.ndarray, message: str) -> None:
    with pytest.raises(InvalidInputError, match=message):
        TriangleMesh(vertices, faces)


def test_bad_queries_raise_naming_the_argument() -> None:
    mesh = TriangleMesh(trimesh.creation.box())
    with pytest.raises(InvalidInputError, match="points must have shape"):
        mesh.distances(np.zeros((4, 2)))
    with pytest.raises(InvalidInputError, match="queries holds a non-finite value"):
        mesh.distances(np.array([[0.0, np.inf, 0.0]]))
    with pytest.raises(InvalidInputError, match="directions row 0 is zero"):
        mesh.cast_rays(np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(InvalidInputError, match="faces is missing"):
        TriangleMesh(np.eye(3))


def test_distance_to_mesh_is_exact_on_the_horse() -> None:
    """The evaluation helper on a real, uneven mesh (the horse gallop's first frame)."""
    from data_paths import HORSE

    if not HORSE.exists():
        pytest.skip("the horse gallop data is not in ../shared/data")
    data = np.load(HORSE)
    vertices, faces = data["vertices"][0].astype(np.float64), data["faces"]
    rng = np.random.default_rng(3)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    queries = np.concatenate([rng.uniform(lo, hi, (150, 3)), vertices[rng.choice(len(vertices), 150)] + 1e-3 * rng.normal(size=(150, 3))])
    expected = np.concatenate([brute_force_distance(q, vertices, faces) for q in np.array_split(queries, 30)])
    size = float(np.linalg.norm(hi - lo))
    np.testing.assert_allclose(distance_to_mesh(queries, trimesh.Trimesh(vertices, faces, process=False)), expected, rtol=0, atol=MESH_DISTANCE_RTOL * size)
