"""Geometry kernels: nearest neighbours (spatial hash), nearest rotations, distances to
meshes."""

from elastocap.geometry.mesh_distance import ClosestPoints, RayHits, TriangleMesh
from elastocap.geometry.neighbors import SpatialIndex, knn, radius_neighbors
from elastocap.geometry.polar import polar_rotation

__all__ = ["ClosestPoints", "RayHits", "SpatialIndex", "TriangleMesh", "knn", "polar_rotation", "radius_neighbors"]
