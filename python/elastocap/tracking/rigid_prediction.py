"""The step's prediction from the neighbourhood's rigid 3-D motion (issue 15,
``settings.RIGID_PREDICTION``: on for new views by default).

The Rust step centres its box search at the linear prediction ``2 last - before`` of each
view, and at ``last`` for a view with no previous position (a new seed). On a fast limb the
first step after seeding is lost to that prediction (benches/README.md, track19: the box
placed by the truth finds a third of the lost views that the linear one misses): a new
point has no velocity of its own, and a limb that turns moves its points on arcs. Here each
point's last 3-D position is moved by the rigid motion (rotation and translation, a
weighted Kabsch fit) that carried its 3-D neighbours from the frame before to the last
frame, and the view is predicted as its last position plus the image motion of that 3-D
step in its camera. The neighbours are the points tracked on both frames nearest to it
(within ``reach`` pixels-equivalent at its depth), Gaussian-weighted by distance, so that a
limb's points predict a limb's point even when a few of the body's other points are near.

:func:`rigid_predictions` gives the (N, C, 2) predictions; :func:`predicting_before` the
``before`` array that makes the Rust step's linear prediction equal to them for the views
chosen (the step takes no prediction of its own)."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from elastocap.cameras import Camera
from elastocap.tracking.rigidity import rigid_motions

__all__ = ["predicting_before", "rigid_predictions"]


def rigid_predictions(cameras: Sequence[Camera], uv: NDArray[np.float64], x_last: NDArray[np.float64],
                      x_before: NDArray[np.float64], pixel: NDArray[np.float64], *, neighbours: int = 8,
                      min_neighbours: int = 4, reach: float = 20.0,
                      rotation: bool = True) -> NDArray[np.float64]:
    """Per view, the image position the neighbourhood's rigid motion predicts.

    Parameters
    ----------
    cameras : sequence of C cameras
    uv : (N, C, 2) float64
        The views held on the last frame (pixels; NaN where not held).
    x_last, x_before : (N, 3) float64
        Each point's 3-D position on the last frame and on the frame before (world units;
        NaN where not tracked). Points with both are the neighbours.
    pixel : (N,) float64
        World units per pixel at each point (:func:`elastocap.tracking.filters.pixel_size`).
    neighbours, min_neighbours : int
        How many neighbours are asked; points with fewer than ``min_neighbours`` within
        ``reach`` are not predicted.
    reach : float
        Neighbourhood radius in pixels-equivalent at the point's depth; the weights are
        Gaussian with a standard deviation of half of it.
    rotation : bool
        False: the neighbours' weighted mean translation only (for comparison).

    Returns
    -------
    (N, C, 2) float64
        ``uv`` plus the projected displacement of the point's predicted 3-D step; NaN where
        the view is not held or the point not predicted."""
    n, c = uv.shape[:2]
    out = np.full((n, c, 2), np.nan)
    movers = np.flatnonzero(np.isfinite(x_last).all(axis=1) & np.isfinite(x_before).all(axis=1))
    rows = np.flatnonzero(np.isfinite(uv[..., 0]).any(axis=1) & np.isfinite(x_last).all(axis=1) & np.isfinite(pixel))
    if movers.size < max(min_neighbours, 1) or rows.size == 0:
        return out
    k = min(neighbours, movers.size)
    radius = reach * pixel[rows]
    dist, near = cKDTree(x_last[movers]).query(x_last[rows], k=k, distance_upper_bound=float(radius.max()))
    dist, near = np.asarray(dist).reshape(len(rows), k), np.asarray(near).reshape(len(rows), k)
    valid = (near < movers.size) & (dist <= radius[:, None])
    enough = valid.sum(axis=1) >= min_neighbours
    rows, dist, near, valid, radius = rows[enough], dist[enough], near[enough], valid[enough], radius[enough]
    if rows.size == 0:
        return out
    index = movers[np.where(valid, near, 0)]
    weights = np.where(valid, np.exp(-0.5 * (np.where(valid, dist, 0.0) / (0.5 * radius[:, None])) ** 2), 0.0)
    a, b = x_before[index], x_last[index]
    x = x_last[rows]
    if rotation:
        r, t = rigid_motions(a, b, weights)
        moved = np.einsum("mij,mj->mi", r, x) + t
    else:
        w = weights / weights.sum(axis=1, keepdims=True)
        moved = x + np.einsum("mk,mki->mi", w, b - a)
    for j, cam in enumerate(cameras):
        # The projections' depths are the camera frame's z (one transform, not two).
        now, depth_now = cam.project(x)
        then, depth_then = cam.project(moved)
        ahead = (depth_now > 0) & (depth_then > 0)
        out[rows, j] = np.where(ahead[:, None], uv[rows, j] + then - now, np.nan)
    return out


def predicting_before(uv: NDArray[np.float64], before: NDArray[np.float64], prediction: NDArray[np.float64],
                      use: NDArray[np.bool_]) -> NDArray[np.float64]:
    """(N, C, 2) ``before`` for the Rust step: ``2 uv - prediction`` where ``use`` (N, C)
    and the prediction is finite (the step then predicts ``prediction``), else ``before``."""
    take = use & np.isfinite(prediction[..., 0]) & np.isfinite(uv[..., 0])
    return np.where(take[..., None], 2 * uv - prediction, before)
