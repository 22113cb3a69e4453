"""Point-to-mesh distances used to score fits against ground truth (demo, horse evaluation)."""

from __future__ import annotations

import numpy as np
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from elastocap.geometry._distance import distance_to_mesh

HALF = np.array([0.5, 0.3, 0.2])


def _box() -> trimesh.Trimesh:
    """A 1 x 0.6 x 0.4 box cut into even triangles (about 0.03 across)."""
    box = trimesh.creation.box(extents=2 * HALF)
    vertices, faces = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=0.04)
    return trimesh.Trimesh(vertices, faces)


BOX = _box()


def _box_distance(points: np.ndarray) -> np.ndarray:
    """Exact unsigned distance to the box's surface."""
    q = np.abs(points) - HALF
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    inside = -np.max(q, axis=1)
    return np.where(np.any(q > 0, axis=1), outside, inside)


@settings(max_examples=30, deadline=None)
@given(arrays(np.float64, (64, 3), elements=st.floats(-0.8, 0.8)))
def test_distance_to_mesh_is_the_exact_distance_to_an_evenly_meshed_box(points: np.ndarray) -> None:
    np.testing.assert_allclose(distance_to_mesh(points, BOX), _box_distance(points), atol=1e-12)


def test_points_on_the_surface_are_at_zero_distance() -> None:
    points, _ = trimesh.sample.sample_surface(BOX, 500, seed=0)
    assert distance_to_mesh(points, BOX).max() < 1e-12
