"""New points for the tracker (issue 15, SPEC 7.2): seeded where the textured masks have
none (:func:`elastocap.tracking.seeding.seed_points`), intersected, and appended to the
frame's arrays and to the tracker's state."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from elastocap.tracking import settings
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.seeding import seed_points
from elastocap.tracking.views import intersect_views

if TYPE_CHECKING:
    from elastocap.tracking.step import FrameTracker

__all__ = ["add_new_points"]


def add_new_points(tracker: FrameTracker, grey: list[NDArray[np.float32]], masks: list[NDArray[np.bool_]],
                   uv: NDArray[np.float64], x: NDArray[np.float64], xcov: NDArray[np.float64],
                   flags: NDArray[np.uint8], flags2d: NDArray[np.uint8], *, bare: int
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.uint8], NDArray[np.uint8]]:
    """The frame's ``uv`` (N, C, 2), ``x`` (N, 3), ``xcov`` (N, 3, 3), ``flags`` (N,) and
    ``flags2d`` (N, C) with the new points appended (M of them: N + M rows), and the
    tracker's state grown by M untracked rows. ``bare`` 0 seeds wherever the masks have no
    point; ``bare`` > 0 only where none lies within ``bare`` cells."""
    c = uv.shape[1]
    new = seed_points(grey, masks, tracker.cameras, uv, spacing=tracker.spacing, size=tracker.size,
                      min_correlation=tracker.min_correlation, min_views=tracker.o["min_views"],
                      min_texture=float(min(tracker.texture)), tolerance=tracker.o["max_residual"],
                      max_residual=tracker.o["max_residual"], floor=settings.FLOOR, bare=bare,
                      margin=tracker.o.get("seed_margin"))
    if len(new):
        ncov = np.where(np.isfinite(new)[..., None], np.eye(2) * 0.01, np.nan)
        nx, nxcov, nused, _ = intersect_views(tracker.cameras, new, ncov, max_residual=tracker.o["max_residual"], floor=settings.FLOOR)
        ok = np.isfinite(nx).all(axis=1)
        new, nx, nxcov, nused = new[ok], nx[ok], nxcov[ok], nused[ok]
        new = np.where(nused[..., None], new, np.nan)
        m = len(new)
        uv = np.concatenate([uv, new])
        x = np.concatenate([x, nx])
        xcov = np.concatenate([xcov, nxcov])
        flags = np.concatenate([flags, np.zeros(m, np.uint8)])
        flags2d = np.concatenate([flags2d, np.where(nused, 0, TrackFlag.NOT_SEEDED).astype(np.uint8)])
        tracker.uv = np.concatenate([tracker.uv, np.full((m, c, 2), np.nan)])
        tracker.x_last = np.concatenate([tracker.x_last, np.full((m, 3), np.nan)])
        tracker.x_before = np.concatenate([tracker.x_before, np.full((m, 3), np.nan)])
    return uv, x, xcov, flags, flags2d
