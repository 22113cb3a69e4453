"""elastocap: markerless capture of the shape and motion of moving people, animals and
objects from calibrated multi-view video.

The heavy kernels live in the Rust extension :mod:`elastocap._core`; this package holds
the public API, orchestration, I/O and the command line.
"""

from elastocap._core import ConvergenceError, ElastocapError, InvalidInputError, __version__
from elastocap.body import BodyFit, BodyModel, BodyObservations, BodyState, fit_body
from elastocap.camera import CalibrationWarning, Camera, Rig
from elastocap.capture import Capture
from elastocap.efg import stiffness_matrix
from elastocap.fit import FrameFit, SequenceFit, fit_sequence
from elastocap.fit_stage import run_fit_stage
from elastocap.elastic import ElasticModel, StaticSolution
from elastocap.grid import Grid
from elastocap.hull import Hull, visual_hull
from elastocap.hull_stage import load_hull, run_hull_stage
from elastocap.mls import mls_shape_functions
from elastocap.neighbors import SpatialIndex, knn, radius_neighbors
from elastocap.polar import polar_rotation
from elastocap.sdf import SDF, signed_distance
from elastocap.silhouette import clean_mask, subtract_background, threshold_dark_background
from elastocap.silhouette import refine_silhouette, segment_dark_background
from elastocap.solvers import SolveStatus, SparseCholesky, conjugate_gradient
from elastocap.synth import Figure, ring_rig, write_synthetic_capture

__all__ = [
    "BodyFit",
    "BodyModel",
    "BodyObservations",
    "BodyState",
    "CalibrationWarning",
    "Camera",
    "Capture",
    "ConvergenceError",
    "ElasticModel",
    "ElastocapError",
    "Figure",
    "FrameFit",
    "Grid",
    "Hull",
    "InvalidInputError",
    "Rig",
    "SDF",
    "SequenceFit",
    "SolveStatus",
    "SparseCholesky",
    "SpatialIndex",
    "StaticSolution",
    "__version__",
    "clean_mask",
    "fit_sequence",
    "conjugate_gradient",
    "fit_body",
    "knn",
    "load_hull",
    "mls_shape_functions",
    "polar_rotation",
    "radius_neighbors",
    "refine_silhouette",
    "ring_rig",
    "run_fit_stage",
    "run_hull_stage",
    "segment_dark_background",
    "signed_distance",
    "stiffness_matrix",
    "subtract_background",
    "threshold_dark_background",
    "visual_hull",
    "write_synthetic_capture",
]
