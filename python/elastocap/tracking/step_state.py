"""The tracker's state on disk and in memory (issue 15, SPEC 7): a run resumed from the
frames it wrote (the 2-D views, the intersections, the seeding frames, the revival's
history, the anchors cut again, the hidden views' frame counts), and the reported positions of seeding frames dropped
once no live point needs them."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from elastocap.tracking import settings
from elastocap.tracking.depth_slide import along_slid
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.tracks import frame_file, read_frame

if TYPE_CHECKING:
    from elastocap.tracking.step import FrameTracker

__all__ = ["forget_history", "intersections", "resume_state"]


def resume_state(tracker: FrameTracker, out: str | Path, chosen: list[int]) -> int:
    """Restores ``tracker``'s state after the longest prefix of the frames ``chosen``
    already written in ``out``; returns the index in ``chosen`` to continue from."""
    done = 0
    while done < len(chosen) and frame_file(out, chosen[done]).exists():
        done += 1
    if done == 0:
        return 0
    last = read_frame(frame_file(out, chosen[done - 1]))
    before = read_frame(frame_file(out, chosen[done - 2])) if done >= 2 else None
    n = len(last["ids"])
    tracker.uv = last["uv"].astype(float)
    tracker.uv_last = np.full_like(tracker.uv, np.nan)
    # The state is the intersections (the reported positions are fused and may be
    # withheld); files written before they were recorded hold only the positions.
    tracker.x_last = intersections(last)
    tracker.x_before = np.full((n, 3), np.nan)
    if before is not None:
        m = len(before["ids"])
        tracker.uv_last[:m] = before["uv"]
        tracker.x_before[:m] = intersections(before)
    tracker.point_flags = last["flags"].astype(np.uint8)
    if "hidden_run" in last:
        # Files written before it was recorded restart the counts at zero.
        tracker.hidden = np.asarray(last["hidden_run"], np.int64)
    if "along_run" in last:
        tracker.along_run = np.asarray(last["along_run"], np.int64)
    tracker.seeded_at = np.full(n, -1, np.int64)
    for frame in chosen[:done]:
        written = read_frame(frame_file(out, frame))
        # Seeded where first intersected, as the step counts it: a position withheld
        # on its seeding frame (OUTSIDE) is not written but was seeded there.
        crossed = intersections(written)
        new = np.flatnonzero(np.isfinite(crossed).all(axis=1) & (tracker.seeded_at[: len(crossed)] < 0))
        if new.size:
            tracker.seeded_at[new] = frame
            tracker.history[frame] = crossed
        if "along_run" in written:
            tracker.depth_slid = along_slid(tracker.depth_slid, np.asarray(written["along_run"], np.int64))
        found = np.flatnonzero(written["flags"] == TrackFlag.SLID)
        if found.size:
            tracker.slid = np.concatenate([tracker.slid, np.zeros(max(0, found.max() + 1 - len(tracker.slid)), bool)])
            tracker.slid[found] = True
    if tracker.lost is not None:
        first = max(0, done - 1 - settings.REVIVE_FRAMES - 1)
        history = {chosen[j]: intersections(read_frame(frame_file(out, chosen[j]))) for j in range(first, done)}
        tracker.lost.restore(last, history)
    tracker.grey, masks = tracker._read(chosen[done - 1])
    tracker.weights = tracker._weights(masks)
    tracker.masks = masks
    if tracker.anchors is not None and "anchor_frame" in last:
        where_frames = np.asarray(last["anchor_frame"], np.int64)
        for source in np.unique(where_frames[where_frames >= 0]):
            if source == chosen[done - 1]:
                grey, weights = tracker.grey, tracker.weights
            else:
                grey, source_masks = tracker._read(int(source))
                weights = tracker._weights(source_masks)
            tracker.anchors.cut(grey, np.asarray(last["anchor_uv"], np.float64), where_frames == source, int(source), weights=weights)
        if "anchor_cuts" in last:
            # The cuts again drive the drift covariance, which weighs the fusion.
            tracker.anchors.grow(len(where_frames))
            tracker.anchors.cuts[: len(where_frames)] = last["anchor_cuts"]
    forget_history(tracker)
    return done

def forget_history(tracker: FrameTracker) -> None:
    """Drops the reported positions of seeding frames no live point was seeded on."""
    live = np.any(np.all(np.isfinite(tracker.uv), axis=2), axis=1)
    if tracker.lost is not None:
        since = tracker.lost.since[: len(live)]
        live[: len(since)] |= since >= 0
    keep = set(np.unique(tracker.seeded_at[: len(live)][live]).tolist())
    for key in [k for k in tracker.history if k not in keep]:
        del tracker.history[key]


def intersections(record: dict[str, NDArray[np.generic]]) -> NDArray[np.float64]:
    """A frame file's intersected positions (its positions, in files without them)."""
    return np.asarray(record["intersections"] if "intersections" in record else record["positions"], dtype=np.float64)
