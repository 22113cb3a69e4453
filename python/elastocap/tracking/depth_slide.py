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
px-eq for the kept positions within 5 px-eq of the truth on m15, 3.4 for those beyond). The
prediction is no better than the intersection where they disagree (half of the time the
neighbours slid too), so the position is withheld, not moved; the point found leaves its
neighbours' fits (:func:`planned_positions`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.tracking import settings
from elastocap.tracking.rigidity import RigidResiduals

if TYPE_CHECKING:
    from elastocap.tracking.step import FrameTracker

__all__ = ["along_run", "along_slid", "along_state", "planned_positions", "slid_in_depth"]


def along_run(previous: NDArray[np.int64], over: NDArray[np.bool_]) -> NDArray[np.int64]:
    """(N,) the number of consecutive frames, this one included, on which each point was
    ``over`` (N,) the bound (``previous``: the counts of the frame before, as long as
    ``over`` or shorter; points seeded since start at zero)."""
    run = np.zeros(len(over), np.int64)
    m = min(len(previous), len(over))
    run[:m] = previous[:m]
    return np.where(over, run + 1, 0)


def slid_in_depth(tracker: FrameTracker, residuals: RigidResiduals) -> NDArray[np.bool_]:
    """(N,) the points farther along the direction to their cameras from their neighbours'
    rigid prediction than ``settings.SLIDE_ALONG`` pixel equivalents on
    ``settings.SLIDE_ALONG_FRAMES`` consecutive frames, this one included (the count kept in
    ``tracker.along_run``; a frame without a prediction restarts it; those found are added
    to ``tracker.depth_slid``). No point when the bound is infinite (off).

    The pair's depth noise crosses the bound on single frames of points that did not slide
    (a tenth of a pixel of disparity is a pixel equivalent); a slide stays. On the tuning
    captures m15 / m41 (benches/log/139-kept2.md) two frames over 5 px-eq withhold a quarter
    / two fifths of the positions that one frame over 5 does, for two thirds / half of the
    far ones.

    Raises
    ------
    InvalidInputError
        ``settings.SLIDE_ALONG`` is NaN or not positive, or ``settings.SLIDE_ALONG_FRAMES``
        not a whole number >= 1.
    """
    bound = float(settings.SLIDE_ALONG)
    frames = settings.SLIDE_ALONG_FRAMES
    if np.isnan(bound) or bound <= 0:
        raise InvalidInputError(f"settings.SLIDE_ALONG must be positive (infinite: off), got {bound}")
    if not (isinstance(frames, (int, np.integer)) and not isinstance(frames, bool) and frames >= 1):
        raise InvalidInputError(f"settings.SLIDE_ALONG_FRAMES must be a whole number >= 1, got {frames!r}")
    if np.isinf(bound):
        return np.zeros(len(residuals.along), bool)
    with np.errstate(invalid="ignore"):
        over = np.asarray(residuals.along > bound)
    tracker.along_run = along_run(tracker.along_run, over)
    slid = np.asarray(tracker.along_run >= frames)
    tracker.depth_slid = _grown(tracker.depth_slid, len(slid)) | slid
    return slid


def along_slid(previous: NDArray[np.bool_], run: NDArray[np.integer]) -> NDArray[np.bool_]:
    """(N,) the points found slid in depth so far: ``previous`` (as long or shorter) and those
    whose count ``run`` (N,) of a written frame reached ``settings.SLIDE_ALONG_FRAMES`` (a
    resumed run's state, :func:`~elastocap.tracking.step_state.resume_state`)."""
    return _grown(previous, len(run)) | (np.asarray(run) >= settings.SLIDE_ALONG_FRAMES)


def _grown(flags: NDArray[np.bool_], n: int) -> NDArray[np.bool_]:
    out = np.zeros(n, bool)
    m = min(n, len(flags))
    out[:m] = flags[:m]
    return out


def planned_positions(tracker: FrameTracker, x: NDArray[np.float64]) -> NDArray[np.float64]:
    """The intersections ``x`` (N, 3) the neighbours' rigid fits are chosen from and fitted
    to: without the points found slid in depth on an earlier frame (NaN rows) when
    ``settings.SLIDE_ALONG_LEAVES``. Withheld, such a point is still tracked; left in, it
    pulls its neighbours' predictions by a share of its offset and takes them over the
    bound after it (m15 / m41 at 6 px-eq: kept 3-D beyond 5 px-eq 0.953 / 0.540% -> 0.830 /
    0.476%, through 27.74 / 30.77% -> 27.74 / 30.56%; benches/log/139-kept2.md). ``x``
    itself where there are none."""
    if not settings.SLIDE_ALONG_LEAVES or not tracker.depth_slid.any():
        return x
    gone = np.flatnonzero(tracker.depth_slid)
    gone = gone[gone < len(x)]
    out = x.copy()
    out[gone] = np.nan
    return out


def along_state(tracker: FrameTracker, n: int) -> dict[str, NDArray[np.int32]]:
    """The frame file's ``along_run`` (n,) int32: each point's count of frames beyond the
    bound, which a resumed run reads back (:func:`~elastocap.tracking.step_state.resume_state`);
    nothing while the check is off, so that the files are as they were without it."""
    if not np.isfinite(float(settings.SLIDE_ALONG)):
        return {}
    out = np.zeros(n, np.int32)
    m = min(n, len(tracker.along_run))
    out[:m] = tracker.along_run[:m]
    return {"along_run": out}
