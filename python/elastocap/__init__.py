"""elastocap: markerless capture of the shape and motion of moving people, animals and
objects from calibrated multi-view video.

The heavy kernels live in the Rust extension :mod:`elastocap._core`; this package holds
the public API, orchestration, I/O and the command line.
"""

from elastocap._core import ConvergenceError, ElastocapError, InvalidInputError, __version__
from elastocap.camera import Camera, Rig
from elastocap.capture import Capture
from elastocap.grid import Grid
from elastocap.hull import Hull, visual_hull
from elastocap.neighbors import SpatialIndex, knn, radius_neighbors
from elastocap.polar import polar_rotation
from elastocap.sdf import SDF, signed_distance
from elastocap.silhouette import clean_mask, subtract_background, threshold_dark_background

__all__ = [
    "Camera",
    "Capture",
    "ConvergenceError",
    "ElastocapError",
    "Grid",
    "Hull",
    "InvalidInputError",
    "Rig",
    "SDF",
    "SpatialIndex",
    "__version__",
    "clean_mask",
    "knn",
    "polar_rotation",
    "radius_neighbors",
    "signed_distance",
    "subtract_background",
    "threshold_dark_background",
    "visual_hull",
]
