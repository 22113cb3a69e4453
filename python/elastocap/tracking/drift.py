"""The covariance of a tracked position with the drift of its views (issue 15, branch track8).

The forward intersection's covariance holds one frame's matching noise (the matches'
covariances and a floor), not the error a view accumulates along its chain of matches:
each view is corrected against its anchor patch (its first appearance), which does not
drift, until the patch stops matching and is cut again where the view is then -- every
cut again freezes the error of that moment into the anchor. On the textured capture (seed
0, branch track8) the 3-D error grows with the number of cuts since the view was acquired
(RMS 1.4 px-equivalents for positions whose views were never cut again, 2.5 after 1-3
cuts, 6.2 after 4 or more) while the intersection's covariance stays flat, so its median
Mahalanobis distance was 5.7 (1.54 for a calibrated 3-D Gaussian).

The model: with ``f`` the most cuts again among the views the position is intersected
from, the covariance ``S`` of the intersection becomes

    S' = (s0 + s1 f) S + p^2 (v0 + v1 f) I

with ``p`` the pixel's size at the point (world units per pixel): the intersection's shape
(narrow stereo pairs: long in depth) scaled, and an isotropic term for the drift along the
surface. The four constants (``settings.DRIFT_SCALE``, ``settings.DRIFT_VARIANCE``) are
calibrated on seed 0 so that the median Mahalanobis distance is near 1.54 in bins of ``f``,
of age and of the number of views."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["drift_covariance", "not_positive_definite", "weakest_sd"]


def drift_covariance(covariance: NDArray[np.float64], pixel: NDArray[np.float64], recuts: NDArray[np.int64], *,
                     scale: tuple[float, float], variance: tuple[float, float]) -> NDArray[np.float64]:
    """(N, 3, 3) ``covariance`` (N, 3, 3; world units squared, NaN where not tracked) with
    the drift of ``recuts`` (N,) cuts again of the anchors (the most among the point's
    views), ``pixel`` (N,) world units per pixel at the point: ``(scale[0] + scale[1] f)
    S + pixel^2 (variance[0] + variance[1] f) I``."""
    f = np.asarray(recuts, float)
    factor = scale[0] + scale[1] * f
    extra = np.asarray(pixel, float) ** 2 * (variance[0] + variance[1] * f)
    # The symmetric part: both terms are then symmetric, and with ``S`` positive definite
    # (the intersection's, by construction) and positive factors the sum is too.
    sym = 0.5 * (covariance + np.swapaxes(covariance, -1, -2))
    return sym * factor[:, None, None] + extra[:, None, None] * np.eye(3)


def weakest_sd(covariance: NDArray[np.float64], pixel: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N,) the standard deviation along the weakest direction of ``covariance`` (N, 3, 3)
    in pixel equivalents (over ``pixel`` (N,), world units per pixel); NaN where not finite."""
    ok = np.isfinite(covariance).all(axis=(1, 2)) & np.isfinite(pixel) & (pixel > 0)
    out = np.full(len(covariance), np.nan)
    if ok.any():
        out[ok] = np.sqrt(np.maximum(np.linalg.eigvalsh(covariance[ok])[:, -1], 0.0)) / pixel[ok]
    return out


def not_positive_definite(covariance: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(N,) where a finite ``covariance`` (N, 3, 3) has an eigenvalue <= 0 (of its symmetric
    part) or a NaN among finite ones: the inverse of a near-singular normal matrix (rays
    near parallel), which says nothing about the position and which the fits refuse as bad
    input (held-out seed 4 of branch trackfit4: one position of 58,490 with an eigenvalue of
    -2.8e-3 m^2). Rows entirely NaN (not tracked) are False."""
    covariance = np.asarray(covariance, dtype=np.float64)
    finite = np.all(np.isfinite(covariance), axis=(1, 2))
    out = ~finite & np.isfinite(covariance).any(axis=(1, 2))
    if finite.any():
        c = covariance[finite]
        out[finite] = np.linalg.eigvalsh(0.5 * (c + c.transpose(0, 2, 1)))[:, 0] <= 0
    return out
