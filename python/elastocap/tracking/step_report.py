"""What a tracked frame reports (issue 15, SPEC 7): the intersections' covariances grown by
the views' drift, the positions fused with their neighbours' rigid prediction, and the
positions withheld where they cannot be trusted (slid off their neighbours' rigid map,
outside a silhouette, too uncertain). The tracker's state keeps the intersections."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from elastocap.tracking import settings
from elastocap.tracking.depth_slide import planned_positions, slid_in_depth
from elastocap.tracking.drift import drift_covariance, not_positive_definite, weakest_sd
from elastocap.tracking.filters import pixel_size
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.rigidity import NeighbourPlan, neighbour_plans, rigid_fusion, rigid_residuals
from elastocap.tracking.silhouette import outside_silhouettes
from elastocap.tracking.views import facing_normals

if TYPE_CHECKING:
    from elastocap.tracking.step import FrameTracker

__all__ = ["reported", "withhold_slid"]


def reported(tracker: FrameTracker, uv: NDArray[np.float64], x: NDArray[np.float64], xcov: NDArray[np.float64],
             flags: NDArray[np.uint8]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.uint8]]:
    """The positions, covariances and flags written out: the covariance with the drift
    of the views (``settings.DRIFT``), the positions fused with their neighbours' rigid
    prediction (``settings.RIGID``), and withheld (the state the next frame starts from
    keeps them): slid off that prediction (``settings.SLIDE``), outside a camera's
    silhouette (``settings.OUTSIDE``), too uncertain before the fusion
    (``settings.UNCERTAIN_DRIFT_SD``) or after it (``settings.UNCERTAIN_SD``), and
    where the intersection's covariance is not positive definite."""
    broken = np.isfinite(x).all(axis=1) & not_positive_definite(xcov)
    if broken.any():
        x, xcov, flags = x.copy(), xcov.copy(), flags.copy()
        x[broken], xcov[broken], flags[broken] = np.nan, np.nan, TrackFlag.UNCERTAIN
    if not settings.DRIFT:
        return x, xcov, flags
    views = np.isfinite(uv[..., 0])
    recuts = tracker.anchors.recuts(views) if tracker.anchors is not None else np.zeros(len(x), np.int64)
    pixel = pixel_size(tracker.cameras, x, views)
    xcov = drift_covariance(xcov, pixel, recuts, scale=settings.DRIFT_SCALE, variance=settings.DRIFT_VARIANCE)
    x_in, cov_in = x, xcov
    # The fusion and the slide check choose the same neighbours (the intersections, their
    # covariances, the same options): chosen once.
    plans = None
    if settings.RIGID or np.isfinite(settings.SLIDE):
        plans = neighbour_plans(planned_positions(tracker, x_in), cov_in, pixel, tracker.seeded_at, tracker.history,
                                neighbours=settings.RIGID_NEIGHBOURS, both_frames=settings.RIGID_BOTH_FRAMES,
                                candidates=settings.RIGID_CANDIDATES, stretch=settings.RIGID_STRETCH)
    if settings.RIGID:
        x, xcov = rigid_fusion(x, xcov, pixel, tracker.seeded_at, tracker.history, neighbours=settings.RIGID_NEIGHBOURS,
                               sigma=settings.RIGID_SIGMA, both_frames=settings.RIGID_BOTH_FRAMES,
                               candidates=settings.RIGID_CANDIDATES, stretch=settings.RIGID_STRETCH, plans=plans)
    if np.isfinite(settings.SLIDE):
        x, xcov, flags = withhold_slid(tracker, x_in, cov_in, x, xcov, flags, pixel, views, plans=plans)
    if np.isfinite(settings.OUTSIDE) and tracker.masks is not None:
        outside = outside_silhouettes(tracker.cameras, tracker.masks, x, settings.OUTSIDE)
        if outside.any():
            x, xcov, flags = x.copy(), xcov.copy(), flags.copy()
            x[outside], xcov[outside], flags[outside] = np.nan, np.nan, TrackFlag.OUTSIDE
    if np.isfinite(settings.UNCERTAIN_DRIFT_SD):
        # The drift covariance before the fusion: the fusion shrinks it by the
        # neighbours' prediction, which drifted with the point when the whole
        # neighbourhood did.
        with np.errstate(invalid="ignore"):
            unsure = (weakest_sd(cov_in, pixel) > settings.UNCERTAIN_DRIFT_SD) & np.isfinite(x).all(axis=1)
        if unsure.any():
            x, xcov, flags = x.copy(), xcov.copy(), flags.copy()
            x[unsure], xcov[unsure], flags[unsure] = np.nan, np.nan, TrackFlag.UNCERTAIN
    if settings.COVARIANCE_SCALE != 1.0:
        xcov = xcov * settings.COVARIANCE_SCALE
    if not np.isfinite(settings.UNCERTAIN_SD):
        return x, xcov, flags
    with np.errstate(invalid="ignore"):
        unsure = weakest_sd(xcov, pixel) > settings.UNCERTAIN_SD
    x, xcov, flags = x.copy(), xcov.copy(), flags.copy()
    x[unsure], xcov[unsure], flags[unsure] = np.nan, np.nan, TrackFlag.UNCERTAIN
    return x, xcov, flags

def withhold_slid(tracker: FrameTracker, x_in: NDArray[np.float64], cov_in: NDArray[np.float64], x: NDArray[np.float64],
                  xcov: NDArray[np.float64], flags: NDArray[np.uint8], pixel: NDArray[np.float64],
                  views: NDArray[np.bool_], *,
                  plans: list[NeighbourPlan] | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.uint8]]:
    """Positions withheld as SLID (``settings.SLIDE``): the intersection ``x_in`` (N, 3)
    farther across its rays from its neighbours' rigid map since its seeding frame
    (fitted to the reported ``x``) than ``SLIDE + SLIDE_SCALE`` times the neighbours'
    own held-out residual, pixel equivalents; with ``SLIDE_STICKY`` on every later
    frame too (a slide does not come back). ``plans``: the rigid neighbours
    (:func:`~elastocap.tracking.rigidity.neighbour_plans` of ``x_in``, ``cov_in``), chosen
    here when not given."""
    towards = facing_normals(tracker.cameras, np.nan_to_num(x_in), views)
    res = rigid_residuals(x_in, x, cov_in, pixel, towards, tracker.seeded_at, tracker.history,
                          neighbours=settings.RIGID_NEIGHBOURS, both_frames=settings.RIGID_BOTH_FRAMES,
                          candidates=settings.RIGID_CANDIDATES, stretch=settings.RIGID_STRETCH, plans=plans)
    with np.errstate(invalid="ignore"):
        slid = res.across > settings.SLIDE + settings.SLIDE_SCALE * np.nan_to_num(res.held_out)
    # And along the rays: the pair's depth slid (depth_slide.py; settings.SLIDE_ALONG).
    slid |= slid_in_depth(tracker, res)
    if len(tracker.slid) < len(x):
        tracker.slid = np.concatenate([tracker.slid, np.zeros(len(x) - len(tracker.slid), bool)])
    if settings.SLIDE_STICKY:
        slid |= tracker.slid[: len(x)]
        tracker.slid[: len(x)] |= slid
    slid &= np.isfinite(x).all(axis=1)
    if not slid.any():
        return x, xcov, flags
    x, xcov, flags = x.copy(), xcov.copy(), flags.copy()
    x[slid], xcov[slid], flags[slid] = np.nan, np.nan, TrackFlag.SLID
    return x, xcov, flags
