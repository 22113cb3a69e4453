"""Triangle rasterisation at pixel centres (``rust/raster.rs``): the fragments are, to the
bit, those of the numpy rasteriser the synthetic captures were rendered with before, so
every figure measured on them stands."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from elastocap import InvalidInputError
from elastocap.render import render_silhouette
from elastocap.render.raster import coverage, fragments
from elastocap.synth.capture import ring_rig

EDGE_TOLERANCE = 1e-9


def _numpy_fragments(
    uv: NDArray[np.float64], faces: NDArray[np.int64], width: int, height: int
) -> tuple:
    # The numpy rasteriser elastocap used before rust/raster.rs, kept as the reference.
    # Per-corner coordinate columns: reductions over a length-3 axis are slow in numpy.
    u0, u1, u2 = (uv[faces[:, i], 0] for i in range(3))
    v0, v1, v2 = (uv[faces[:, i], 1] for i in range(3))
    u_lo = np.maximum(np.ceil(np.minimum(np.minimum(u0, u1), u2) - EDGE_TOLERANCE), 0.0)
    v_lo = np.maximum(np.ceil(np.minimum(np.minimum(v0, v1), v2) - EDGE_TOLERANCE), 0.0)
    u_hi = np.minimum(np.floor(np.maximum(np.maximum(u0, u1), u2) + EDGE_TOLERANCE), width - 1.0)
    v_hi = np.minimum(np.floor(np.maximum(np.maximum(v0, v1), v2) + EDGE_TOLERANCE), height - 1.0)
    twice_area = (u1 - u0) * (v2 - v0) - (v1 - v0) * (u2 - u0)
    with np.errstate(invalid="ignore"):
        keep = np.flatnonzero((u_hi >= u_lo) & (v_hi >= v_lo) & (twice_area != 0) & np.isfinite(twice_area))
    if keep.size == 0:
        empty_i = np.zeros(0, np.int64)
        return empty_i, empty_i, np.zeros((0, 3))
    u_lo, v_lo = u_lo[keep], v_lo[keep]
    nu = (u_hi[keep] - u_lo).astype(np.int64) + 1
    nv = (v_hi[keep] - v_lo).astype(np.int64) + 1
    inverse_area = 1.0 / twice_area[keep]
    # Barycentric coordinate i is the edge function of the opposite edge over twice the
    # area; an affine function of the offset (du, dv) from the bounding box's corner:
    # slope_u * du + slope_v * dv + value at the corner.
    coefficients = []
    for (ua, va), (ub, vb) in (((u1, v1), (u2, v2)), ((u2, v2), (u0, v0))):
        ua, va, ub, vb = ua[keep], va[keep], ub[keep], vb[keep]
        eu, ev = ub - ua, vb - va
        coefficients.append(
            (-ev * inverse_area, eu * inverse_area, (eu * (v_lo - va) - ev * (u_lo - ua)) * inverse_area)
        )

    counts = nu * nv
    owner = np.repeat(np.arange(keep.size), counts)
    first = np.cumsum(counts) - counts
    offset = np.arange(int(counts.sum()), dtype=np.int64) - first[owner]
    row_length = nu[owner]
    dv = offset // row_length
    du = offset - dv * row_length
    (a0, b0, c0), (a1, b1, c1) = coefficients
    l0 = a0[owner] * du + b0[owner] * dv + c0[owner]
    l1 = a1[owner] * du + b1[owner] * dv + c1[owner]
    l2 = 1.0 - l0 - l1
    inside = (l0 >= -EDGE_TOLERANCE) & (l1 >= -EDGE_TOLERANCE) & (l2 >= -EDGE_TOLERANCE)
    owner = owner[inside]
    u = u_lo[owner].astype(np.int64) + du[inside]
    v = v_lo[owner].astype(np.int64) + dv[inside]
    return v * width + u, keep[owner], np.stack([l0[inside], l1[inside], l2[inside]], axis=1)


def _same(uv: np.ndarray, faces: np.ndarray, width: int, height: int) -> int:
    found = fragments(uv, faces, width, height)
    pixel, face, barycentric = _numpy_fragments(uv, faces, width, height)
    np.testing.assert_array_equal(found.pixel, pixel)
    np.testing.assert_array_equal(found.face, face)
    np.testing.assert_array_equal(found.barycentric, barycentric)
    return len(pixel)


@given(st.integers(0, 2**32 - 1), st.integers(1, 40), st.integers(1, 40), st.integers(1, 60))
@settings(max_examples=150, deadline=None)
def test_fragments_are_the_numpy_rasteriser_to_the_bit(seed: int, width: int, height: int, n_faces: int) -> None:
    rng = np.random.default_rng(seed)
    n_vertices = 3 * n_faces
    # Corners anywhere around the image, some on pixel centres and edges exactly (integer and
    # half-integer coordinates), degenerate and non-finite triangles.
    uv = rng.uniform(-10, max(width, height) + 10, size=(n_vertices, 2))
    snapped = rng.random(n_vertices) < 0.3
    uv[snapped] = np.round(2 * uv[snapped]) / 2
    uv[rng.random(n_vertices) < 0.02] = np.nan
    faces = rng.integers(0, n_vertices, size=(n_faces, 3))
    repeated = rng.random(n_faces) < 0.05
    faces[repeated, 2] = faces[repeated, 0]  # zero area
    _same(uv, faces, width, height)


def test_a_mesh_in_a_distorted_skewed_camera_is_the_numpy_rasteriser_to_the_bit() -> None:
    camera = ring_rig(8, width=320, height=240).cameras[5]
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.4)
    mesh.apply_translation((0.1, 0.9, 0.0))
    uv = camera.project(np.asarray(mesh.vertices))[0]
    assert _same(uv, np.asarray(mesh.faces, dtype=np.int64), camera.width, camera.height) > 1000
    # The silhouette is the union of the fragments' pixels.
    assert render_silhouette(mesh, camera).sum() == np.unique(fragments(uv, mesh.faces, camera.width, camera.height).pixel).size


def test_coverage_fills_overlapping_triangles() -> None:
    uv = np.array([[2.0, 2.0], [12.0, 2.0], [2.0, 12.0], [4.0, 4.0], [14.0, 4.0], [4.0, 14.0]])
    covered = coverage(uv, np.array([[0, 1, 2], [3, 4, 5]]), 16, 16)
    assert covered[5, 5] and covered[3, 3] and covered[10, 5] and not covered[15, 15]


def test_faces_beyond_the_vertices_are_refused() -> None:
    uv = np.zeros((3, 2))
    for faces in (np.array([[0, 1, 3]]), np.array([[0, -1, 2]])):
        with pytest.raises(InvalidInputError, match="beyond"):
            fragments(uv, faces, 4, 4)
    with pytest.raises(InvalidInputError, match="shape"):
        fragments(np.zeros((3, 3)), np.array([[0, 1, 2]]), 4, 4)
