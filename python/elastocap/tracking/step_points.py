"""The tracker's 3-D stage of a frame (issue 15, SPEC 7): the held views intersected
(forward intersection with per-view covariances; views that break the intersection
rejected), the views predicted hidden set aside, the trajectories filtered (velocity,
acceleration, uniformity against the neighbours), and each point's flag and the 3-D
anchor its lost views are searched from."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from elastocap.tracking import settings
from elastocap.tracking.filters import pixel_size, trajectory_flags
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.hidden import end_hidden_views
from elastocap.tracking.prediction import drop_breaking_views, drop_far_views
from elastocap.tracking.step_views import ViewStep
from elastocap.tracking.views import intersect_views

if TYPE_CHECKING:
    from elastocap.tracking.step import FrameTracker

__all__ = ["PointStep", "locate_points", "point_flags"]


@dataclass(frozen=True)
class PointStep:
    """One frame's 3-D points (N of them, C cameras) and the views they keep."""

    uv: NDArray[np.float64]
    """(N, C, 2) the views kept, px (NaN elsewhere)."""
    cov2d: NDArray[np.float64]
    """(N, C, 2, 2) their covariances, px^2."""
    x: NDArray[np.float64]
    """(N, 3) the intersected positions, m; NaN where not tracked."""
    xcov: NDArray[np.float64]
    """(N, 3, 3) their covariances, m^2."""
    flags: NDArray[np.uint8]
    """(N,) per point: 0 where tracked, else why not (:func:`point_flags`)."""
    tracked: NDArray[np.bool_]
    """(N,) intersected and through the trajectory filters."""
    single: NDArray[np.bool_]
    """(N,) down to one view: kept a frame at its predicted position."""
    anchor: NDArray[np.float64]
    """(N, 3) where the point's lost views are searched from, m: its position, or the
    prediction from the last two frames for a single-view point (NaN for the others)."""


def locate_points(tracker: FrameTracker, masks: list[NDArray[np.bool_]], stepped: ViewStep,
                  alive: NDArray[np.bool_]) -> PointStep:
    """The frame's ``stepped`` views intersected and filtered as trajectories; ``alive`` (N,)
    the points held on the frame before. ``stepped.flags2d`` is updated in place (EPIPOLAR where
    an intersection rejected a view)."""
    n, c = stepped.uv.shape[:2]
    uv, cov2d, flags2d, corr = stepped.uv, stepped.cov2d, stepped.flags2d, stepped.corr
    researched, wide, shift = stepped.researched, stepped.wide, stepped.shift
    x, xcov, used, rejected = intersect_views(tracker.cameras, uv, cov2d, max_residual=tracker.o["max_residual"], floor=settings.FLOOR)
    if researched.any():
        x, xcov, used, rejected = drop_breaking_views(tracker.cameras, uv, cov2d, flags2d, researched, x, xcov, used, rejected,
                                                      max_residual=tracker.o["max_residual"], floor=settings.FLOOR)
    if np.isfinite(settings.RESEARCH_WIDE_RESIDUAL) and wide.any():
        # The wide box's finds held to a tighter residual than the intersection's.
        x, xcov, used, rejected = drop_far_views(tracker.cameras, uv, cov2d, flags2d, wide, x, xcov, used, rejected,
                                                 tolerance=settings.RESEARCH_WIDE_RESIDUAL,
                                                 max_residual=tracker.o["max_residual"], floor=settings.FLOOR)
    flags2d[rejected] = TrackFlag.EPIPOLAR
    set_aside = np.zeros((n, c), bool)
    if settings.HIDDEN_FRAMES and n:
        uv, cov2d, x, xcov, used, set_aside = end_hidden_views(tracker, masks, uv, cov2d, x, xcov, used, corr, shift, flags2d)
    pixel = pixel_size(tracker.cameras, x, used)
    traj = trajectory_flags(x, tracker.x_last, tracker.x_before, pixel, max_velocity=tracker.o["max_velocity"],
                            max_acceleration=tracker.o["max_acceleration"], uniformity=tracker.o["uniformity"],
                            neighbours=tracker.o["neighbours"])
    x[traj > 0] = np.nan
    xcov[traj > 0] = np.nan
    tracked = np.all(np.isfinite(x), axis=1)
    # A point down to one view (occluded in the others) keeps it for a frame: its 3-D
    # position predicted from the last two is where the others are searched again.
    views = np.isfinite(uv[..., 0])
    single = ~tracked & (traj == 0) & (views.sum(axis=1) == 1) & np.all(np.isfinite(tracker.x_last), axis=1)
    keep = ((used | set_aside) & tracked[:, None]) | (views & single[:, None])
    uv = np.where(keep[..., None], uv, np.nan)
    flags = point_flags(flags2d, tracker.uv, traj, tracked, alive, tracker.point_flags)
    anchor = np.where(tracked[:, None], x, np.where(np.isfinite(tracker.x_before), 2 * tracker.x_last - tracker.x_before, tracker.x_last))
    anchor[~(tracked | single)] = np.nan
    return PointStep(uv=uv, cov2d=cov2d, x=x, xcov=xcov, flags=flags, tracked=tracked, single=single, anchor=anchor)


def point_flags(flags2d: NDArray[np.uint8], previous: NDArray[np.float64], traj: NDArray[np.uint8],
                 tracked: NDArray[np.bool_], alive: NDArray[np.bool_], before: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """Per point: 0 where tracked; else the trajectory filter's flag; else the most common
    2-D reason among the cameras that held it; a point dead before keeps its flag."""
    n = len(tracked)
    flags = np.zeros(n, np.uint8)
    held = np.isfinite(previous).all(axis=2)
    counts = np.zeros((n, len(TrackFlag)), int)
    rows, cols = np.nonzero(held)
    np.add.at(counts, (rows, flags2d[rows, cols]), 1)
    counts[:, :2] = 0
    reason = np.where(counts.any(axis=1), np.argmax(counts, axis=1), TrackFlag.FEW_VIEWS)
    flags[~tracked] = reason[~tracked]
    flags[traj > 0] = traj[traj > 0]
    flags[~alive] = np.where(before[~alive] == 0, TrackFlag.NOT_SEEDED, before[~alive])
    return flags
