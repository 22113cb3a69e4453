"""elastocap: markerless capture of the shape and motion of moving people, animals and
objects from calibrated multi-view video.

The package reads as the data flow: ``cameras`` and ``capture`` (input), ``silhouettes``,
``hull`` (carving, signed distance), ``elastic`` (the element-free model and its fit),
``body`` (the articulated metaball model), ``render`` (drawing meshes into cameras),
``pipeline`` (the stages, the command line, the report), with ``geometry`` (neighbours,
rotations) and ``solvers`` (sparse SPD solves) underneath and ``synth`` (synthetic captures)
beside. The heavy kernels live in the Rust extension :mod:`elastocap._core`. This top level
holds what a user calls: stages, models, fits, cameras.
"""

from typing import Any

from elastocap._core import ConvergenceError, ElastocapError, InvalidInputError, __version__
from elastocap import _moved
from elastocap.body import BodyFit, BodyModel, BodyObservations, BodyState, fit_body
from elastocap.cameras import CalibrationWarning, Camera, Rig
from elastocap.capture import Capture
from elastocap.elastic import ElasticModel, FrameFit, SequenceFit, StaticSolution, TrackTerms, fit_sequence
from elastocap.elastic import SelfIntersection, SilhouetteTerm, StiffStage, StoppingRules
from elastocap.elastic import mls_shape_functions, stiffness_matrix
from elastocap.geometry import SpatialIndex, knn, polar_rotation, radius_neighbors
from elastocap.hull import SDF, Grid, Hull, signed_distance, visual_hull
from elastocap.pipeline import load_hull, run_fit_stage, run_hull_stage
from elastocap.silhouettes import clean_mask, refine_silhouette, segment_dark_background
from elastocap.silhouettes import subtract_background, threshold_dark_background
from elastocap.stereo import grow_matches, intersect, match_patches
from elastocap.tracking import Tracks, load_tracks, track_points

_moved.install()


def __getattr__(name: str) -> Any:
    # Names that moved (synthetic data to elastocap.synth, solver internals to
    # elastocap.solvers) still resolve, with a DeprecationWarning.
    return _moved.moved_name(name)


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
    "FrameFit",
    "Grid",
    "Hull",
    "InvalidInputError",
    "Rig",
    "SDF",
    "SelfIntersection",
    "SequenceFit",
    "SilhouetteTerm",
    "SpatialIndex",
    "StaticSolution",
    "StiffStage",
    "StoppingRules",
    "TrackTerms",
    "Tracks",
    "__version__",
    "clean_mask",
    "fit_body",
    "fit_sequence",
    "grow_matches",
    "intersect",
    "knn",
    "load_hull",
    "load_tracks",
    "match_patches",
    "mls_shape_functions",
    "polar_rotation",
    "radius_neighbors",
    "refine_silhouette",
    "run_fit_stage",
    "run_hull_stage",
    "segment_dark_background",
    "signed_distance",
    "stiffness_matrix",
    "subtract_background",
    "threshold_dark_background",
    "track_points",
    "visual_hull",
]
