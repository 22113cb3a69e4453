"""Re-acquisition (issue 15): a tracked point's lost views found again in the other cameras
by spatial least-squares matching at the projection of its 3-D position, from its view of
best correlation and with the start shape of the neighbouring points' plane; only in the
cameras predicted to see it (:mod:`elastocap.tracking.visibility`), optionally after a
plane-warped NCC search (``settings.REACQUIRE_RADIUS``), and confirmed at once by
intersection with the views it holds (``settings.CONFIRM_REACQUIRED``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from elastocap.tracking import settings
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.views import confirm_views, intersect_views, project_all, spatial_match, spatial_search
from elastocap.tracking.visibility import predicted_visible

if TYPE_CHECKING:
    from elastocap.tracking.step import FrameTracker

__all__ = ["reacquire"]


def reacquire(tracker: FrameTracker, grey: list[NDArray[np.float32]], masks: list[NDArray[np.bool_]],
              weights: list[NDArray[np.float32]] | None, uv: NDArray[np.float64], cov2d: NDArray[np.float64],
              corr: NDArray[np.float64], x: NDArray[np.float64], xcov: NDArray[np.float64], flags: NDArray[np.uint8],
              tracked: NDArray[np.bool_], single: NDArray[np.bool_], anchor: NDArray[np.float64]) -> None:
    """Finds the lost views of the points ``tracked`` (or down to one view, ``single``) at
    the projections of ``anchor`` (their position, or its prediction); updates ``uv``,
    ``cov2d``, ``x``, ``xcov`` and ``flags`` in place (a point whose new views intersect
    with its held ones is intersected again; a single-view point that finds a partner is
    tracked again)."""
    n, c = uv.shape[:2]
    found = tracked | single
    if not (n and found.any()):
        return
    targets = project_all(tracker.cameras, anchor, margin=tracker.size)
    for k in range(c):
        iu = np.clip(np.round(np.nan_to_num(targets[:, k, 0])).astype(int), 0, masks[k].shape[1] - 1)
        iv = np.clip(np.round(np.nan_to_num(targets[:, k, 1])).astype(int), 0, masks[k].shape[0] - 1)
        wanted = found & ~np.isfinite(uv[:, k, 0]) & masks[k][iv, iu]
        targets[~wanted, k] = np.nan
    normals = np.full((n, 3), np.nan)
    normals[found] = tracker.normals(anchor[found], x, np.isfinite(uv[found, :, 0]))
    if settings.PREDICT_VISIBILITY:
        # Only the cameras that can see the point: its surface facing them and no
        # tracked point in front of it.
        asked = np.all(np.isfinite(targets), axis=2)
        targets[asked & ~predicted_visible(tracker.cameras, masks, anchor, normals, x, asked)] = np.nan
    score = np.where(np.isfinite(uv[..., 0]), np.nan_to_num(corr, nan=0.0) + 1.0, -1.0)
    reference = np.argmax(score, axis=1)
    rows = np.flatnonzero(np.any(np.all(np.isfinite(targets), axis=2), axis=1))
    if rows.size:
        matched, mcov = spatial_match(grey, reference[rows], uv[rows, reference[rows]], targets[rows],
                                      size=tracker.size, min_correlation=tracker.min_correlation,
                                      tolerance=settings.REACQUIRE_TOLERANCE + np.where(single[rows], 2.0, 0.0),
                                      min_texture=float(min(tracker.texture)), cameras=tracker.cameras,
                                      points=anchor[rows], normals=normals[rows],
                                      weights=weights)
        if settings.REACQUIRE_RADIUS:
            # The views the match started at the projection did not find: searched for.
            missed = np.where(np.isfinite(matched), np.nan, targets[rows])
            searched, scov = spatial_search(
                grey, reference[rows], uv[rows, reference[rows]], missed, cameras=tracker.cameras,
                points=anchor[rows], normals=normals[rows], size=tracker.size, radius=settings.REACQUIRE_RADIUS,
                min_correlation=tracker.min_correlation, box_correlation=min(tracker.min_correlation, settings.BOX_CORRELATION),
                forward_backward=tracker.o["forward_backward"],
                tolerance=settings.REACQUIRE_SEARCH_TOLERANCE + np.where(single[rows], 2.0, 0.0),
                min_texture=float(min(tracker.texture)), max_iterations=settings.REACQUIRE_ITERATIONS, weights=weights)
            matched = np.where(np.isfinite(searched), searched, matched)
            mcov = np.where(np.isfinite(scov), scov, mcov)
        if settings.CONFIRM_REACQUIRED:
            # A tracked point's new views are checked now with its held ones (one
            # wrong view would fail the point's intersection on the next frame):
            # kept, and the point intersected again, when every view agrees.
            check = np.flatnonzero(tracked[rows])
            matched[check], mcov[check], cx, ccov = confirm_views(
                tracker.cameras, uv[rows[check]], cov2d[rows[check]], matched[check], mcov[check],
                max_residual=tracker.o["max_residual"], floor=settings.FLOOR)
            ok = np.isfinite(cx).all(axis=1)
            x[rows[check[ok]]], xcov[rows[check[ok]]] = cx[ok], ccov[ok]
        uv[rows] = np.where(np.isfinite(matched), matched, uv[rows])
        cov2d[rows] = np.where(np.isfinite(mcov), mcov, cov2d[rows])
        # Points that were down to one view and got others back: intersect now.
        back = rows[single[rows] & (np.isfinite(uv[rows, :, 0]).sum(axis=1) >= 2)]
        if back.size:
            bx, bcov, bused, _ = intersect_views(tracker.cameras, uv[back], cov2d[back],
                                                 max_residual=tracker.o["max_residual"], floor=settings.FLOOR)
            ok = np.all(np.isfinite(bx), axis=1)
            x[back[ok]], xcov[back[ok]], flags[back[ok]] = bx[ok], bcov[ok], TrackFlag.TRACKED
            uv[back] = np.where((bused & ok[:, None])[..., None], uv[back], np.nan)
