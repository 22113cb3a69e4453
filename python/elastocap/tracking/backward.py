"""Tracks followed backward in time from the frame they were seeded on (issue 15).

The forward tracker seeds new points every few frames where the textured masks hold no
tracked point (points that came into view, and points whose tracks were lost). Such a
track starts at its seeding frame; a fit that attaches tracks at their frame nearest the
rest frame (:mod:`elastocap.elastic.tracks`) then attaches it where its already-drifted
fit of that frame puts it, and the track holds that drift (benches/README.md, trackfit4:
a track anchored at frame 40 is tied 5-6% of the diagonal from its own material point).
Followed backward, from its views at the seeding frame through the earlier frames by the
same per-frame step as forward (:class:`elastocap.tracking.step.FrameTracker` on the
frames in reverse, seeding nothing), the point gets the part of its trajectory before
it was seeded, so its frame nearest the rest frame is earlier.

The backward part keeps the track's id; frames where it was not followed back stay NaN
and ``NOT_SEEDED`` (or the backward step's reason once it was lost going back)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.capture import Capture
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.step import FrameTracker
from elastocap.tracking.tracks import Tracks

__all__ = ["track_backward"]


def track_backward(capture: Capture, tracks: Tracks, *, reach: int, spacing: int, size: int, radius: int,
                   min_correlation: float, options: dict[str, Any]) -> Tracks:
    """``tracks`` with every track first tracked after the first frame followed backward
    from its first tracked frame, through at most ``reach`` earlier frames of
    ``tracks.frames`` (the tracker's own options, as :func:`elastocap.track_points` checked
    them; revival is not used backward).

    Each seeding frame's new tracks are followed as one batch, from their views at that
    frame (``tracks.views``) until none is left or ``reach`` frames are done. Positions,
    covariances, flags and views are filled only where the track was not tracked forward
    (before its first tracked frame), so the forward part is unchanged.

    Raises
    ------
    InvalidInputError
        ``tracks`` without views; ``reach`` negative.
    """
    if tracks.views is None:
        raise InvalidInputError("tracks must hold their views (track_points writes them) to be followed backward")
    if isinstance(reach, bool) or not isinstance(reach, (int, np.integer)) or reach < 0:
        raise InvalidInputError(f"reach must be a non-negative int, got {reach!r}")
    positions, covariances = tracks.positions.copy(), tracks.covariances.copy()
    flags, views = tracks.flags.copy(), tracks.views.copy()
    tracked = flags == TrackFlag.TRACKED
    first = np.where(tracked.any(axis=0), tracked.argmax(axis=0), -1)
    options = dict(options, revive=False)
    for start in np.unique(first[first > 0]):
        batch = np.flatnonzero(first == start)
        stop = max(0, int(start) - int(reach))
        if stop == start:
            continue
        tracker = _started(capture, tracks, tracks.views, int(start), batch, spacing, size, radius, min_correlation, options)
        for row in range(int(start) - 1, stop - 1, -1):
            record = tracker.step(int(tracks.frames[row]), first=False, reseed=False)
            # Only where the forward pass has nothing (it never does before `start`).
            free = flags[row, batch] == TrackFlag.NOT_SEEDED
            got = record["flags"] == TrackFlag.TRACKED
            fill = batch[free & got]
            positions[row, fill] = record["positions"][free & got]
            covariances[row, fill] = record["covariances"][free & got]
            flags[row, fill] = TrackFlag.TRACKED
            views[row, fill] = record["uv"][free & got]
            # Lost going back: the reason, where the point had been followed to the frame after.
            lost = free & ~got & (record["flags"] != TrackFlag.NOT_SEEDED)
            flags[row, batch[lost]] = record["flags"][lost]
            if not np.isfinite(tracker.uv).all(axis=2).any():
                break
    return Tracks(frames=tracks.frames, ids=tracks.ids, positions=positions, covariances=covariances, flags=flags,
                  views=views)


def _started(capture: Capture, tracks: Tracks, views: NDArray[np.float64], row: int, batch: NDArray[np.int64], spacing: int,
             size: int, radius: int, min_correlation: float, options: dict[str, Any]) -> FrameTracker:
    """A tracker whose state is the ``batch`` of tracks at frame row ``row``, as if it had
    just stepped there: their ``views`` (``tracks.views``), their 3-D positions, anchor
    patches cut there."""
    tracker = FrameTracker(capture, spacing, size, radius, min_correlation, options)
    frame = int(tracks.frames[row])
    grey, masks = tracker._read(frame)
    weights = tracker._weights(masks)
    uv = views[row, batch].copy()
    n, c = uv.shape[:2]
    tracker.uv = uv
    tracker.uv_last = np.full_like(uv, np.nan)
    tracker.x_last = tracks.positions[row, batch].copy()
    tracker.x_before = np.full((n, 3), np.nan)
    tracker.point_flags = tracks.flags[row, batch].astype(np.uint8)
    tracker.hidden = np.zeros((n, c), np.int64)
    tracker.seeded_at = np.full(n, frame, np.int64)
    tracker.history = {frame: tracker.x_last.copy()}
    tracker.grey, tracker.weights = grey, weights
    if tracker.anchors is not None:
        tracker.anchors.cut(grey, uv, np.isfinite(uv[..., 0]), frame, weights=weights)
    return tracker
