"""The held views of a tracked point re-tied to one another by spatial matching on every
frame (issue 15; SPEC 7's "confirmation by spatial LSM in the other cameras").

Each view follows its own chain of frame-to-frame matches and anchors, so the views of one
point drift apart independently (the drift enters when an anchor is cut again). Across the
narrow stereo pairs that hold most points (10-20 degrees apart) an image drift of a few
tenths of a pixel along the epipolar line is a depth error of pixel equivalents that the
reprojection residual cannot see. A spatial match of the reference view's patch into the
other held views, started at their tracked positions, measures the disparity afresh on
this frame: on the textured capture (seed 0) its distance from the tracked view predicts
the 3-D error (kept positions beyond 5 px-equivalents: 1.1% where it is under 0.1 px,
16% at 0.3-0.5 px, 38-55% beyond 0.5 px; benches/README.md, branch track7). The
reference is the view whose anchor is oldest: it has been cut again fewest times, so it
has drifted least (on seed 0 it beats the view of best correlation on every figure)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from elastocap.tracking.views import spatial_match

__all__ = ["retie_views"]


def retie_views(
    images: Sequence[NDArray[np.float32]],
    uv: NDArray[np.float64],
    cov: NDArray[np.float64],
    preference: NDArray[np.float64],
    *,
    size: int,
    min_correlation: float,
    tolerance: float,
    drop: float,
    drop_failed: bool = True,
    min_texture: float,
    weights: Sequence[NDArray[np.float32]] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64]]:
    """Re-tie the views ``uv`` (N, C, 2; NaN where not held, covariances ``cov`` (N, C, 2,
    2)) of points held in two or more cameras to each point's reference view (its held view
    of highest ``preference`` (N, C)).

    The reference patch is matched into each other held view started at its tracked
    position; a match that converges within ``tolerance`` pixels of it replaces it (with
    its covariance). A view whose match lands farther than ``drop`` pixels from the tracked
    position is removed (NaN) when ``drop`` is finite; one whose match fails (or lands
    beyond ``tolerance``) is then removed too when ``drop_failed``, and kept as tracked
    otherwise. Returns the views, their covariances, the
    removed views (N, C) and each asked view's shift (N, C): the distance of its match from
    the tracked position in pixels, infinite where the match failed or landed beyond
    ``tolerance``, NaN where not asked (a reference or a lone view): a view that has lost
    its point drifts off its reference's (:mod:`elastocap.tracking.hidden`)."""
    held = np.isfinite(uv[..., 0])
    rows = np.flatnonzero(held.sum(axis=1) >= 2)
    removed = np.zeros(held.shape, bool)
    shift = np.full(held.shape, np.nan)
    if rows.size == 0:
        return uv, cov, removed, shift
    score = np.where(held[rows], np.nan_to_num(preference[rows], nan=0.0) + 1.0, -1.0)
    reference = np.argmax(score, axis=1)
    sub = np.arange(rows.size)
    targets = np.where(held[rows, :, None], uv[rows], np.nan)
    targets[sub, reference] = np.nan
    matched, mcov = spatial_match(images, reference, uv[rows, reference], targets, size=size,
                                  min_correlation=min_correlation, tolerance=tolerance, min_texture=min_texture,
                                  weights=weights)
    found = np.isfinite(matched[..., 0])
    asked = np.isfinite(targets[..., 0])
    with np.errstate(invalid="ignore"):
        far = found & (np.linalg.norm(matched - targets, axis=2) > drop)
    with np.errstate(invalid="ignore"):
        shift[rows] = np.where(found, np.linalg.norm(matched - targets, axis=2), np.where(asked, np.inf, np.nan))
    out_uv, out_cov = uv.copy(), cov.copy()
    replace = found & ~far
    out_uv[rows] = np.where(replace[..., None], matched, uv[rows])
    out_cov[rows] = np.where(replace[..., None, None], mcov, cov[rows])
    if np.isfinite(drop):
        gone = asked & (far | (~found if drop_failed else False))
        out_uv[rows] = np.where(gone[..., None], np.nan, out_uv[rows])
        out_cov[rows] = np.where(gone[..., None, None], np.nan, out_cov[rows])
        removed[rows] = gone
    return out_uv, out_cov, removed, shift
