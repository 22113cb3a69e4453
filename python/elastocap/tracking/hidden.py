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
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from elastocap.cameras import Camera
from elastocap.tracking import settings
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.views import intersect_views
from elastocap.tracking.visibility import predicted_visible

if TYPE_CHECKING:
    from elastocap.tracking.step import FrameTracker

__all__ = ["end_hidden_views", "hidden_run", "hidden_views"]


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


def end_hidden_views(tracker: FrameTracker, masks: list[NDArray[np.bool_]], uv: NDArray[np.float64], cov2d: NDArray[np.float64],
                     x: NDArray[np.float64], xcov: NDArray[np.float64], used: NDArray[np.bool_], corr: NDArray[np.float64],
                     shift: NDArray[np.float64], flags2d: NDArray[np.uint8]
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                                NDArray[np.bool_], NDArray[np.bool_]]:
    """The tracker's held views (``used`` in the intersection ``x``) predicted hidden for
    ``settings.HIDDEN_FRAMES`` consecutive frames (the count kept in ``tracker.hidden``),
    optionally only where the view's own match agrees (``settings.HIDDEN_EVIDENCE``:
    ``corr`` its frame-to-frame correlation, ``shift`` its re-tie's), ended (2-D flag
    HIDDEN in ``flags2d``) or, with ``settings.HIDDEN_SET_ASIDE`` and two other views
    left, kept tracked but left out of the intersection; the points concerned are
    intersected again. Returns ``uv``, ``cov2d``, ``x``, ``xcov``, ``used`` after it and
    the views set aside (N, C)."""
    n, c = uv.shape[:2]
    held = used & np.all(np.isfinite(x), axis=1)[:, None]
    hidden = hidden_views(tracker.cameras, masks, x, held, tracker.normals, facing=settings.HIDDEN_FACING)
    tracker.hidden = hidden_run(tracker.hidden, hidden)
    end = hidden & (tracker.hidden >= settings.HIDDEN_FRAMES)
    if settings.HIDDEN_EVIDENCE:
        # The view's own match says the patch changed: its correlation fell, or its
        # re-tie to the reference moved it (or failed).
        with np.errstate(invalid="ignore"):
            end &= (corr < settings.HIDDEN_CORRELATION) | (shift > settings.HIDDEN_SHIFT)
    set_aside = np.zeros((n, c), bool)
    if settings.HIDDEN_SET_ASIDE:
        set_aside = end & ((held & ~end).sum(axis=1) >= 2)[:, None]
        end &= ~set_aside
    if not (end.any() or set_aside.any()):
        return uv, cov2d, x, xcov, used, set_aside
    uv = np.where(end[..., None], np.nan, uv)
    cov2d = np.where(end[..., None, None], np.nan, cov2d)
    flags2d[end] = TrackFlag.HIDDEN
    rows = np.flatnonzero((end | set_aside).any(axis=1))
    sub = np.where(set_aside[rows, :, None], np.nan, uv[rows])
    rx, rcov, rused, rrejected = intersect_views(tracker.cameras, sub, cov2d[rows], max_residual=tracker.o["max_residual"],
                                                 floor=settings.FLOOR)
    x, xcov, used = x.copy(), xcov.copy(), used.copy()
    x[rows], xcov[rows], used[rows] = rx, rcov, rused
    flags2d[rows] = np.where(rrejected, TrackFlag.EPIPOLAR, flags2d[rows])
    return uv, cov2d, x, xcov, used, set_aside & np.all(np.isfinite(x), axis=1)[:, None]
