"""Tracks in the body fit (issue 15, item 4): each tracked surface point is attached to the
body part it lies on at its anchor frame (its frame nearest the rest frame), at a fixed
position in that part's frame, and pulled to its tracked position in every other frame.

In the core a track's observation is a joint observation with an offset
(``rust/body/observe.rs``: the point ``o_b + R_b offset`` of part ``b``, residual against
the tracked position, weight ``1 / (sigma_joint * scale)``), so its derivatives are the
part's twists at that point. The part and offset come from a fit of the anchor frame:
:func:`fit_body` fits once without tracks, attaches them to that fit, and fits again with
them; a track farther than ``outlier`` from where the first fit puts its point in a frame
is left out of that frame (a wrong track cannot drag a limb).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.body.model import BodyModel, BodyState
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.tracks import Tracks

__all__ = ["SequentialAnchors", "TrackObservations", "anchored_arrays", "append_tracks", "attach_tracks", "nearest_part"]

# The track sigma that fit_body's sigma_joint stands for: a track of this standard
# deviation weighs as one joint observation.
TRACK_SIGMA_REFERENCE = 0.01
# No track is trusted below this standard deviation (metres): the forward intersection's
# covariance is optimistic on faint texture (session 6, issue 14).
SIGMA_FLOOR = 0.003


def nearest_part(model: BodyModel, state: BodyState, points: NDArray[np.float64]) -> NDArray[np.int64]:
    """The part of each point: that of the metaball whose scaled radius reaches it best
    (smallest distance to the centre over the largest radius)."""
    centres, reach = model.ball_centers(state)
    part = model._balls[0]
    ratio = np.linalg.norm(points[:, None, :] - centres[None], axis=2) / reach[None]
    return np.asarray(part, np.int64)[ratio.argmin(axis=1)]


class TrackObservations:
    """Per frame index, the arrays of the attached tracks (``BodyObservations.anchored``):
    ``points (T, 3)``, ``part (T,)``, ``offset (T, 3)`` (metres, in the part's frame) and
    ``sigma (T,)`` (metres, at least 1 mm)."""

    def __init__(self, n_frames: int) -> None:
        empty = (np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0))
        self.frames: list[tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]] = [empty] * n_frames

    @property
    def count(self) -> int:
        """Track observations over all frames."""
        return sum(len(f[0]) for f in self.frames)


def attach_tracks(
    model: BodyModel,
    states: Sequence[BodyState],
    tracks: Tracks,
    frame_numbers: Sequence[int],
    *,
    rest_frame: int,
    outlier: float,
) -> TrackObservations:
    """Attach ``tracks`` to the parts of ``states`` (one per entry of ``frame_numbers``)
    and return their observations in the other frames (module docs).

    Raises
    ------
    InvalidInputError
        Not a :class:`Tracks`; non-finite tracked positions or covariances; frames of the
        tracks that are not in ``frame_numbers``.
    """
    if not isinstance(tracks, Tracks):
        raise InvalidInputError(f"tracks must be elastocap.Tracks (elastocap.load_tracks), got {type(tracks).__name__}")
    numbers = [int(v) for v in frame_numbers]
    result = TrackObservations(len(numbers))
    if len(tracks.ids) == 0 or len(tracks.frames) == 0:
        return result
    missing = sorted(set(int(v) for v in tracks.frames) - set(numbers))
    if missing:
        raise InvalidInputError(f"tracks hold frames {missing[:5]} that are not frames of the fit ({numbers[0]}..{numbers[-1]})")
    tracked = tracks.flags == TrackFlag.TRACKED
    if not (np.isfinite(tracks.positions[tracked]).all() and np.isfinite(tracks.covariances[tracked]).all()):
        raise InvalidInputError("tracks: a position or covariance flagged TRACKED is not finite")
    index = np.array([numbers.index(int(v)) for v in tracks.frames])
    gap = np.abs(tracks.frames - rest_frame) * 2 + (tracks.frames < rest_frame)
    cost = np.where(tracked, gap[:, None], np.iinfo(np.int64).max)
    anchor = cost.argmin(axis=0)
    usable = tracked.any(axis=0)
    part = np.zeros(len(tracks.ids), np.int64)
    offset = np.zeros((len(tracks.ids), 3))
    for row in np.unique(anchor[usable]):
        which = np.flatnonzero(usable & (anchor == row))
        state = states[index[row]]
        points = tracks.positions[row, which]
        part[which] = nearest_part(model, state, points)
        rotations, origins = model.pose(state)
        offset[which] = np.einsum("tji,tj->ti", rotations[part[which]], points - origins[part[which]])
    for row, f in enumerate(index):
        use = np.flatnonzero(tracked[row] & usable & (anchor != row))
        if len(use) == 0:
            continue
        rotations, origins = model.pose(states[f])
        predicted = origins[part[use]] + np.einsum("tij,tj->ti", rotations[part[use]], offset[use])
        observed = tracks.positions[row, use]
        near = np.linalg.norm(observed - predicted, axis=1) <= outlier
        use = use[near]
        sigma = np.sqrt(np.maximum(np.trace(tracks.covariances[row, use], axis1=1, axis2=2) / 3, 1e-12))
        result.frames[f] = (observed[near], part[use], offset[use], np.maximum(sigma, SIGMA_FLOOR))
    return result


class SequentialAnchors:
    """Tracks for a body fitted frame by frame (``BodyTracker``, ``elastocap body``): a
    track is attached at the first frame where it is tracked (its frame nearest the first
    fitted frame), to the part it lies on in that frame's fitted state, and observed in
    the later frames as ``BodyObservations.anchored``.

    ``positions`` and ``covariances`` are ``tracks``' arrays moved into the body's frame
    (``rotation``: world -> body, applied as ``points @ rotation``)."""

    def __init__(self, model: BodyModel, tracks: Tracks, rotation: NDArray[np.float64] | None = None) -> None:
        self.model = model
        self.frames = [int(v) for v in tracks.frames]
        r = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
        tracked = tracks.flags == TrackFlag.TRACKED
        self.positions = np.where(tracked[..., None], np.nan_to_num(tracks.positions) @ r, np.nan)
        cov = np.nan_to_num(tracks.covariances)
        self.sigma = np.sqrt(np.maximum(np.trace(cov, axis1=2, axis2=3) / 3, SIGMA_FLOOR**2))
        self.tracked = tracked
        n = len(tracks.ids)
        self.attached = np.zeros(n, bool)
        self.part = np.zeros(n, np.int64)
        self.offset = np.zeros((n, 3))

    def observations(
        self, frame: int
    ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]] | None:
        """``anchored`` for ``frame``: the attached tracks tracked there (None if none)."""
        if frame not in self.frames:
            return None
        row = self.frames.index(frame)
        use = np.flatnonzero(self.attached & self.tracked[row])
        if len(use) == 0:
            return None
        return self.positions[row, use], self.part[use], self.offset[use], self.sigma[row, use]

    def attach(self, frame: int, state: BodyState) -> int:
        """Attach the tracks tracked at ``frame`` and not attached yet to ``state``'s parts;
        returns how many."""
        if frame not in self.frames:
            return 0
        row = self.frames.index(frame)
        which = np.flatnonzero(~self.attached & self.tracked[row])
        if len(which):
            points = self.positions[row, which]
            self.part[which] = nearest_part(self.model, state, points)
            rotations, origins = self.model.pose(state)
            self.offset[which] = np.einsum("tji,tj->ti", rotations[self.part[which]], points - origins[self.part[which]])
            self.attached[which] = True
        return len(which)


def anchored_arrays(anchored: Any, name: str, n_parts: int) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """``BodyObservations.anchored`` checked: ``(points (T, 3), part (T,), offset (T, 3),
    joint_scale (T,))``, the scale being sigma over :data:`TRACK_SIGMA_REFERENCE`.

    Raises
    ------
    InvalidInputError
        Wrong shapes, non-finite values, a sigma that is not positive, a part index out of
        range; the message names ``name``.
    """
    try:
        at, part, offset, sigma = (np.asarray(v) for v in anchored)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be (points, part, offset, sigma)") from None
    t = len(at)
    if at.shape != (t, 3) or part.shape != (t,) or offset.shape != (t, 3) or sigma.shape != (t,):
        raise InvalidInputError(f"{name} must be points (T, 3), part (T,), offset (T, 3), sigma (T,)")
    if not (np.isfinite(at).all() and np.isfinite(offset).all() and np.isfinite(sigma).all() and (sigma > 0).all()):
        raise InvalidInputError(f"{name} holds non-finite values or a sigma that is not positive")
    if t and not ((part >= 0) & (part < n_parts)).all():
        raise InvalidInputError(f"{name} part indices must be in 0..{n_parts}")
    return at.astype(np.float64), part.astype(np.int64), offset.astype(np.float64), sigma.astype(np.float64) / TRACK_SIGMA_REFERENCE


def append_tracks(observations: dict[str, Any], attached: TrackObservations) -> None:
    """Append the tracks' joint observations (with offsets and scales) to the core's
    observation arrays, after the frames' own joints."""
    extra = [(f, *a) for f, a in enumerate(attached.frames) if len(a[0])]
    for key, column in (("joints", 1), ("joint_part", 2), ("joint_offset", 3)):
        observations[key] = np.ascontiguousarray(np.concatenate([observations[key]] + [e[column] for e in extra]))
    observations["joint_part"] = observations["joint_part"].astype(np.int64)
    observations["joint_frame"] = np.concatenate([observations["joint_frame"]] + [np.full(len(e[1]), e[0], np.int64) for e in extra])
    observations["joint_scale"] = np.ascontiguousarray(
        np.concatenate([observations["joint_scale"]] + [e[4] / TRACK_SIGMA_REFERENCE for e in extra])
    )
