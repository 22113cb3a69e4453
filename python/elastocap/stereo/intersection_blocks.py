"""Forward intersection with one 2x2 covariance per view (SPEC 7; the tracker's case):
:func:`elastocap.stereo.intersect` given ``covariance`` of shape ``(N, C, 2, 2)``.

The same weighted least squares as the joint-covariance path of
:mod:`elastocap.stereo.intersection` (Gauss-Newton from the rays' midpoint through the full
camera model, covariance from the normal matrix, blunders rejected by normalised residuals),
with the weight matrix kept as its C diagonal blocks, solved point by point in the core
(``rust/intersect.rs``, parallel over points, the projection's Jacobian analytic). The
results agree with the joint path to rounding (tests/test_intersection.py) and with the
numpy block solver it replaced to ~1e-15 relative (benches/README.md, "isect1").
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from elastocap._core import intersect_per_view
from elastocap.cameras import Camera
from elastocap.cameras.distortion import padded

if TYPE_CHECKING:
    from elastocap.stereo.intersection import Intersection

__all__ = ["intersect_blocks"]


def intersect_blocks(cams: list[Camera], obs: NDArray[np.float64], cov: NDArray[np.float64], *, reject: bool,
                     critical: float, iterations: int, step_tolerance: float) -> Intersection:
    """The :class:`~elastocap.stereo.Intersection` of ``obs`` (N, C, 2, pixels; NaN where
    not observed) with per-view covariances ``cov`` (N, C, 2, 2, pixels squared; ignored
    where not observed), checked by the caller; ``critical``, ``iterations`` as in
    :func:`~elastocap.stereo.intersect`, ``step_tolerance`` in world units."""
    from elastocap.stereo.intersection import _result

    x, point_cov, resid, normalised, used, quad, converged = intersect_per_view(
        np.ascontiguousarray(obs, dtype=np.float64),
        np.ascontiguousarray(cov, dtype=np.float64),
        np.ascontiguousarray([cam.K for cam in cams], dtype=np.float64),
        np.array([padded(cam.dist) for cam in cams]),
        np.ascontiguousarray([cam.R for cam in cams], dtype=np.float64),
        np.ascontiguousarray([cam.t for cam in cams], dtype=np.float64),
        reject, critical, iterations, step_tolerance,
    )
    return _result(cams, x, point_cov, resid, normalised, used, quad, converged)
