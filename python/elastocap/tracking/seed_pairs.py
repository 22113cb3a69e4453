"""New points whose depth no narrow stereo pair measured (issue 15, the kept 3-D line;
benches/log/139-kept2.md).

A seed's depth is searched along its ray in its camera's nearest partner and, where that
fails, in the second nearest (:func:`elastocap.tracking.seeding.seed_points`); the
intersection of all its confirmed views may also reject the partner's view as the blunder.
Either way the point can end up held by two cameras that are not each other's nearest (on
the textured captures' rig, two pairs ~90 degrees apart). Such a match is made with an
unwarped window across a wide baseline, and its error lies along the epipolar line, where
two views cannot see it: on the tuning captures m15 / m68 / m69 one / eight / one such
seeds, of which one / seven / none were farther than 5 px-equivalents from the truth on
their seeding frame, and all of their 12 / 21 / 0 kept positions beyond it after. A pair
seeds the same surface from its own cameras' cells, so the points are dropped as they
are made (:func:`drop_unpaired`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from elastocap.cameras import Camera

if TYPE_CHECKING:
    from elastocap.tracking.step import FrameTracker

__all__ = ["drop_unpaired", "nearest_cameras", "paired"]


def nearest_cameras(cameras: Sequence[Camera]) -> NDArray[np.int64]:
    """(C,) each camera's nearest other camera by the angle between their optical axes
    (its narrow stereo partner)."""
    if len(cameras) < 2:
        return np.full(len(cameras), -1, np.int64)
    axes = np.array([cam.R[2] for cam in cameras])
    cosine = axes @ axes.T
    np.fill_diagonal(cosine, -np.inf)
    return np.argmax(cosine, axis=1).astype(np.int64)


def paired(views: NDArray[np.bool_], nearest: NDArray[np.int64]) -> NDArray[np.bool_]:
    """(M,) whether the held ``views`` (M, C) of each point include some camera together
    with its ``nearest`` (C,) partner."""
    views = np.asarray(views, bool)
    if views.ndim != 2 or views.shape[1] != len(nearest):
        raise ValueError(f"views must be (M, {len(nearest)}), got {views.shape}")
    return np.any(views & views[:, nearest], axis=1)


def drop_unpaired(tracker: FrameTracker, start: int, uv: NDArray[np.float64], x: NDArray[np.float64],
                  xcov: NDArray[np.float64], flags: NDArray[np.uint8], flags2d: NDArray[np.uint8]
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.uint8], NDArray[np.uint8]]:
    """The frame's ``uv`` (N, C, 2), ``x`` (N, 3), ``xcov`` (N, 3, 3), ``flags`` (N,) and
    ``flags2d`` (N, C) without the new points (rows ``start`` on, just seeded) that hold no
    narrow pair (:func:`paired`), and the tracker's ``uv``, ``x_last`` and ``x_before`` (grown
    by the seeding to N rows) cut to match. The points before ``start`` are untouched, so
    the ids stay those of the seeding order."""
    if start >= len(uv):
        return uv, x, xcov, flags, flags2d
    keep = np.ones(len(uv), bool)
    keep[start:] = paired(np.isfinite(uv[start:, :, 0]), nearest_cameras(tracker.cameras))
    if keep.all():
        return uv, x, xcov, flags, flags2d
    tracker.uv = tracker.uv[keep[: len(tracker.uv)]]
    tracker.x_last = tracker.x_last[keep[: len(tracker.x_last)]]
    tracker.x_before = tracker.x_before[keep[: len(tracker.x_before)]]
    return uv[keep], x[keep], xcov[keep], flags[keep], flags2d[keep]
