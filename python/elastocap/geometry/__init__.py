"""Geometry kernels: nearest neighbours (spatial hash), nearest rotations, distances to
meshes."""

from elastocap.geometry.neighbors import SpatialIndex, knn, radius_neighbors
from elastocap.geometry.polar import polar_rotation

__all__ = ["SpatialIndex", "knn", "polar_rotation", "radius_neighbors"]
