"""Distances from points to a triangle mesh, for measuring fits against ground truth."""

from __future__ import annotations

import numpy as np
import trimesh
from numpy.typing import NDArray

from elastocap.geometry.mesh_distance import TriangleMesh

__all__ = ["distance_to_mesh"]


def distance_to_mesh(points: NDArray[np.float64], mesh: trimesh.Trimesh | TriangleMesh) -> NDArray[np.float64]:
    """Unsigned distance of each point ``(N, 3)`` to the triangles of ``mesh`` (world units):
    the exact point-to-mesh distance (:class:`elastocap.geometry.mesh_distance.TriangleMesh`). Pass a
    ``TriangleMesh`` to reuse its index over several calls."""
    index = mesh if isinstance(mesh, TriangleMesh) else TriangleMesh(mesh)
    return index.distances(points)
