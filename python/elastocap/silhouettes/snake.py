"""Active contours for silhouettes (SPEC 8): :func:`active_contour` on an attraction image,
:func:`snake_silhouette` from a mask or polygon to a mask, and the contour helpers.

The contour is the core's (``rust/snake.rs``): semi-implicit elasticity and rigidity,
resampled to keep its spacing within bounds as it stretches, a collapse reported as a
status rather than returned.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

import elastocap._core as _core
from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_float_array, as_positive

__all__ = ["SnakeResult", "active_contour", "mask_contours", "polygon_mask", "snake_silhouette"]


@dataclass(frozen=True)
class SnakeResult:
    """The outcome of :func:`active_contour`.

    Attributes
    ----------
    points : (M, 2) float64 or None
        The closed contour ``(x, y)`` = (column, row), pixels; None when it collapsed.
    status : str
        "converged", "maximum iterations" or "collapsed".
    iterations, resamplings : int
    """

    points: NDArray[np.float64] | None
    status: str
    iterations: int
    resamplings: int


def active_contour(
    attraction: Any,
    init: Any,
    *,
    alpha: float = 0.05,
    beta: float = 0.5,
    gamma: float = 1.0,
    kappa: float = 2.0,
    max_move: float = 1.0,
    spacing: float = 3.0,
    spacing_bounds: tuple[float, float] = (1.5, 6.0),
    max_iterations: int = 300,
    tolerance: float = 0.1,
    window: int = 10,
    min_area: float = 50.0,
) -> SnakeResult:
    """A closed active contour (Kass et al. 1988) climbing ``attraction``.

    Parameters
    ----------
    attraction : (H, W) array_like
        What the contour is pulled towards (it climbs the image's gradient), e.g. the
        first output of :func:`~elastocap.silhouettes.gradient.filtered_gradient`.
    init : (N, 2) array_like
        Closed polygon ``(x, y)`` pixels, N >= 3, either orientation.
    alpha, beta : float, keyword-only
        Elasticity and rigidity of the internal energy ``alpha |x'|^2 + beta |x''|^2``.
    gamma : float, keyword-only
        Step damping of the semi-implicit iteration.
    kappa : float, keyword-only
        Weight of the attraction's gradient.
    max_move : float, keyword-only
        Largest move of a point per iteration, pixels.
    spacing : float, keyword-only
        Target point spacing, pixels; the contour is resampled to it whenever a segment
        leaves ``spacing_bounds``.
    spacing_bounds : (float, float), keyword-only
    max_iterations, window : int, keyword-only
    tolerance : float, keyword-only
        Converged when no point moved more than this (pixels) over ``window`` iterations.
    min_area : float, keyword-only
        A contour enclosing less (pixels^2) has collapsed.

    Returns
    -------
    SnakeResult

    Raises
    ------
    InvalidInputError
        Malformed image or polygon, non-finite values, bad options.
    """
    image = as_float_array("attraction", attraction)
    if image.ndim != 2:
        raise InvalidInputError(f"attraction must have shape (H, W), got {image.shape}")
    points = as_float_array("init", init)
    if points.ndim != 2 or points.shape[1] != 2 or len(points) < 3:
        raise InvalidInputError(f"init must have shape (N, 2) with N >= 3, got {points.shape}")
    low, high = (float(v) for v in spacing_bounds)
    out, status, iterations, resamplings = _core.active_contour(
        image,
        np.ascontiguousarray(points),
        alpha=float(alpha),
        beta=float(beta),
        gamma=as_positive("gamma", gamma),
        kappa=float(kappa),
        max_move=as_positive("max_move", max_move),
        spacing=as_positive("spacing", spacing),
        min_spacing=low,
        max_spacing=high,
        max_iterations=as_count("max_iterations", max_iterations),
        tolerance=as_positive("tolerance", tolerance),
        window=as_count("window", window),
        min_area=float(min_area),
    )
    return SnakeResult(None if status == "collapsed" else out, status, iterations, resamplings)


def mask_contours(mask: Any, *, min_area: float = 50.0) -> list[NDArray[np.float64]]:
    """Outer contours ``(N, 2) float64`` (x, y) of a mask's components of at least
    ``min_area`` pixels, largest first."""
    m = (np.asarray(mask) != 0).astype(np.uint8)
    if m.ndim != 2:
        raise InvalidInputError(f"mask must have shape (H, W), got {m.shape}")
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    kept = [c.reshape(-1, 2).astype(np.float64) for c in contours if cv2.contourArea(c) >= min_area and len(c) >= 3]
    return sorted(kept, key=lambda c: -abs(cv2.contourArea(c.astype(np.float32))))


def polygon_mask(polygons: list[NDArray[np.float64]], shape: tuple[int, int]) -> NDArray[np.bool_]:
    """The union of filled polygons as an ``(H, W)`` bool mask (pixel centres inside)."""
    out = np.zeros(shape, dtype=np.uint8)
    if polygons:
        cv2.fillPoly(out, [np.round(p * 16).astype(np.int32) for p in polygons], 1, lineType=cv2.LINE_8, shift=4)
    return out != 0


def snake_silhouette(attraction: Any, init: Any, *, min_area: float = 200.0, **options: Any) -> tuple[NDArray[np.bool_] | None, list[SnakeResult]]:
    """A silhouette by active contours: one contour per component of ``init`` (a mask) or
    from ``init`` (one polygon), each run by :func:`active_contour` on ``attraction``, the
    surviving contours filled.

    Parameters
    ----------
    attraction : (H, W) array_like
    init : (H, W) mask or (N, 2) polygon
    min_area : float, keyword-only
        Components smaller than this (pixels) are ignored, and a contour enclosing less has
        collapsed.
    **options
        Passed to :func:`active_contour`.

    Returns
    -------
    mask : (H, W) bool or None
        None when every contour collapsed (reported, not returned).
    results : list of SnakeResult
    """
    image = np.asarray(attraction)
    init_array = np.asarray(init)
    if init_array.ndim == 2 and init_array.shape == image.shape:
        starts = mask_contours(init_array, min_area=min_area)
    else:
        starts = [as_float_array("init", init)]
    results = [active_contour(image, start, min_area=min_area, **options) for start in starts]
    kept = [r.points for r in results if r.points is not None]
    if not kept:
        return None, results
    return polygon_mask(kept, image.shape[:2]), results
