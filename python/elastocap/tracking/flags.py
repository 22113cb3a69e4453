"""Why a tracked point has no position in a frame: the codes of ``Tracks.flags`` (the same
integers as the Rust core's ``track::Flag`` up to 10)."""

from __future__ import annotations

from enum import IntEnum

__all__ = ["TrackFlag"]


class TrackFlag(IntEnum):
    """Flag of a point in a frame (``Tracks.flags``, uint8).

    Attributes
    ----------
    TRACKED : 0
        The position is valid.
    NOT_SEEDED : 1
        The point does not exist yet in this frame (seeded later), or was lost before it.
    IMAGE_BORDER : 2
        Its patch or search box left the image in the cameras that held it.
    LOW_CORRELATION : 3
        The box search's or the least-squares match's correlation fell below the threshold
        (occlusion, change of appearance).
    FORWARD_BACKWARD : 4
        Matching back into the previous frame missed the start.
    EPIPOLAR : 5
        The cameras disagree: a view was a blunder in the forward intersection or its
        reprojection residual exceeds the threshold.
    VELOCITY : 6
        Its 3-D speed exceeds the threshold.
    ACCELERATION : 7
        Its 3-D acceleration exceeds the threshold.
    NONUNIFORM : 8
        Its velocity differs from the median velocity of the neighbouring trajectories.
    MATCH_FAILED : 9
        Least-squares matching diverged or found too little texture.
    FEW_VIEWS : 10
        Fewer than two cameras kept it.
    HIDDEN : 11
        Its views were ended because their cameras were predicted not to see it (outside
        the silhouette or behind another tracked point) on consecutive frames (Python
        only: the Rust core's step does not set it).
    UNCERTAIN : 12
        Tracked, but its predicted standard deviation (the covariance with the drift of
        its views) exceeds ``settings.UNCERTAIN_SD`` pixel equivalents (after the rigid
        fusion; ``settings.UNCERTAIN_DRIFT_SD`` before it), or its
        intersection's covariance is not positive definite (rays too near parallel for
        the inverse to mean anything): withheld (the tracker follows it on).
    SLID : 13
        Tracked, but farther across its rays from where the rigid motion of its
        neighbours since its seeding frame puts it than ``settings.SLIDE`` pixel
        equivalents plus ``settings.SLIDE_SCALE`` times the neighbours' own residual to
        that motion: it slid along the surface in both views of its pair, a few tenths of a
        pixel a frame, which no one-frame check sees (:func:`~elastocap.tracking.rigidity.rigid_residuals`);
        or farther along its rays than ``settings.SLIDE_ALONG`` (its pair's depth slid,
        :mod:`~elastocap.tracking.depth_slide`). Withheld (the tracker follows it on), and on
        every later frame of the track.
    OUTSIDE : 14
        Tracked, but its position projects farther than ``settings.OUTSIDE`` pixels
        outside the silhouette of a camera whose image it falls in: off the surface, in
        front of it, mostly along the rays of its own pair
        (:func:`~elastocap.tracking.silhouette.outside_silhouettes`). Withheld on that frame
        (the tracker follows it on).
    """

    TRACKED = 0
    NOT_SEEDED = 1
    IMAGE_BORDER = 2
    LOW_CORRELATION = 3
    FORWARD_BACKWARD = 4
    EPIPOLAR = 5
    VELOCITY = 6
    ACCELERATION = 7
    NONUNIFORM = 8
    MATCH_FAILED = 9
    FEW_VIEWS = 10
    HIDDEN = 11
    UNCERTAIN = 12
    SLID = 13
    OUTSIDE = 14
