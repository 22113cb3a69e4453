"""Distances from points to a triangle mesh, for measuring fits against ground truth."""

from __future__ import annotations

import numpy as np
import trimesh
from numpy.typing import NDArray
from scipy.spatial import cKDTree

__all__ = ["distance_to_mesh"]

# Candidate triangles per point: the closest triangle is among the 16 with the nearest
# centroids on meshes of even triangles (marching-cubes and remeshed surfaces, the synthetic
# figure, the horse gallop), which is what this is used on.
CANDIDATES = 16


def distance_to_mesh(points: NDArray[np.float64], mesh: trimesh.Trimesh, tree: cKDTree | None = None) -> NDArray[np.float64]:
    """Unsigned distance of each point ``(N, 3)`` to the triangles of ``mesh`` (world units):
    the exact point-to-triangle distance to the ``CANDIDATES`` triangles with the nearest
    centroids, the smallest kept. ``tree`` may hold a cKDTree of the centroids already.

    Unlike a voxelised distance field it has no grid error, and it needs no spatial index
    beyond scipy's (trimesh's own proximity queries need rtree)."""
    triangles = np.asarray(mesh.triangles)
    tree = cKDTree(triangles.mean(axis=1)) if tree is None else tree
    count = min(CANDIDATES, len(triangles))
    _, near = tree.query(points, k=count)
    near = near.reshape(len(points), count)
    repeated = np.repeat(np.asarray(points, dtype=np.float64), count, axis=0)
    closest = trimesh.triangles.closest_point(triangles[near.reshape(-1)], repeated)
    return np.linalg.norm(closest - repeated, axis=1).reshape(-1, count).min(axis=1)
