"""A tracked point whose pair's depth slid off its neighbours' rigid motion (issue 15, the
kept 3-D line; benches/log/139-kept2.md).

Most points are held by one narrow stereo pair only, ~5-6 degrees apart: a disparity error
of 0.1 px there is ~1 px-equivalent of depth, which the reprojection residual cannot see.
The re-tie measures the disparity afresh on every frame, but where the pair sees the
surface obliquely (a limb or the head turning away from it) both views slide along it
together and the slide is mostly along the rays: on the tuning capture m15, 110 of the 148
kept positions farther than 5 px-eq from the truth are off more along the pair's mean ray
than across it. The SLID check (:func:`~elastocap.tracking.step_report.withhold_slid`)
looks across the rays only; this one looks along them, at the same rigid prediction
(:func:`~elastocap.tracking.rigidity.rigid_residuals`' ``along``: the distance from where the
neighbours' rigid motion since the seeding frame puts the point, along the direction to its
cameras, pixel equivalents). Its threshold sits above the pair's depth noise (a median 0.95
px-eq for the kept positions within 5 px-eq of the truth on m15, 3.4 for those beyond)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.tracking import settings
from elastocap.tracking.rigidity import RigidResiduals

__all__ = ["slid_in_depth"]


def slid_in_depth(residuals: RigidResiduals) -> NDArray[np.bool_]:
    """(N,) the points farther along the direction to their cameras from their neighbours'
    rigid prediction than ``settings.SLIDE_ALONG`` pixel equivalents (False where no
    prediction was made, and everywhere when the setting is infinite: off).

    Raises
    ------
    InvalidInputError
        ``settings.SLIDE_ALONG`` is NaN or not positive.
    """
    bound = float(settings.SLIDE_ALONG)
    if np.isnan(bound) or bound <= 0:
        raise InvalidInputError(f"settings.SLIDE_ALONG must be positive (infinite: off), got {bound}")
    if np.isinf(bound):
        return np.zeros(len(residuals.along), bool)
    with np.errstate(invalid="ignore"):
        return np.asarray(residuals.along > bound)
