"""Silhouettes: background subtraction, dark-background thresholds, GrabCut refinement,
mask clean-up."""

from elastocap.silhouettes.background import clean_mask, refine_silhouette, segment_dark_background, subtract_background, threshold_dark_background

__all__ = ["clean_mask", "refine_silhouette", "segment_dark_background", "subtract_background", "threshold_dark_background"]
