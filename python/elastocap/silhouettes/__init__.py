"""Silhouettes: background subtraction, dark-background thresholds, GrabCut refinement,
mask clean-up, and model-based silhouettes in clutter (snakes on the disparity-filtered
gradient, corrected by the body model)."""

from elastocap.silhouettes.background import clean_mask, refine_silhouette, segment_dark_background, subtract_background, threshold_dark_background
from elastocap.silhouettes.gradient import filtered_gradient
from elastocap.silhouettes.model_based import SilhouetteTracker, extract_silhouettes
from elastocap.silhouettes.snake import active_contour, snake_silhouette

__all__ = [
    "SilhouetteTracker",
    "active_contour",
    "clean_mask",
    "extract_silhouettes",
    "filtered_gradient",
    "refine_silhouette",
    "segment_dark_background",
    "snake_silhouette",
    "subtract_background",
    "threshold_dark_background",
]
