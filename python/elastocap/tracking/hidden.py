"""Held views of a tracked point that its camera no longer sees (issue 15, branch track8).

A view whose point went behind an occluder or over a grazing edge keeps matching: its
patch follows the occluder or the turned surface, and a narrow stereo pair does so
consistently, so neither the correlation nor the reprojection residual sees it. On the
textured capture (seed 0, after the re-tie) 57% of the kept 3-D positions farther than 5
px-equivalents from the truth hold two or more views the truth does not see (branch
track7). The test here is the one the re-acquisition uses, without truth
(:func:`elastocap.tracking.visibility.predicted_visible`): the point must project inside
the camera's silhouette, no other tracked point may lie in front of it along the line of
sight, and (optionally) its surface must face the camera. A single frame's prediction is
noisy at the silhouette's edge, so a view is ended only after it has been predicted
hidden on ``frames`` consecutive frames (:func:`hidden_run`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from elastocap.cameras import Camera
from elastocap.tracking.visibility import predicted_visible

__all__ = ["hidden_run", "hidden_views"]


def hidden_views(cameras: Sequence[Camera], masks: Sequence[NDArray[np.bool_]], points: NDArray[np.float64],
                 held: NDArray[np.bool_], normals: Callable[[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]],
                                                            NDArray[np.float64]],
                 *, facing: float) -> NDArray[np.bool_]:
    """(N, C) the views ``held`` (N, C) of the points at ``points`` (N, 3; world, NaN where
    not tracked) that their camera is predicted not to see on this frame.

    ``normals(points, cloud, seen)`` gives the surface normals at the points (the tracker's
    plane of the neighbouring points, turned towards the cameras that see them); the
    tracked points themselves are the cloud and the z-buffer's occluders. ``facing`` is the
    least cosine between the normal and the direction to the camera (below -1: the
    silhouette and the z-buffer only)."""
    out = np.zeros(held.shape, bool)
    rows = np.flatnonzero(held.any(axis=1) & np.isfinite(points).all(axis=1))
    if rows.size == 0:
        return out
    normal = normals(points[rows], points, held[rows])
    seen = predicted_visible(cameras, masks, points[rows], normal, points, held[rows], facing=facing)
    out[rows] = held[rows] & ~seen
    return out


def hidden_run(previous: NDArray[np.int64], hidden: NDArray[np.bool_]) -> NDArray[np.int64]:
    """(N, C) the number of consecutive frames, this one included, on which each view has
    been predicted hidden (``previous``: the counts of the frame before, as long as
    ``hidden`` or shorter; points seeded since start at zero)."""
    run = np.zeros(hidden.shape, np.int64)
    m = min(len(previous), len(hidden))
    run[:m] = previous[:m]
    return np.where(hidden, run + 1, 0)
