"""``track_points``: surface points followed through a capture (SPEC 7, issue 15).

Per frame: every camera's points tracked from the previous frame in one Rust call
(prediction, NCC box search, temporal LSM, forward-backward check; parallel over points,
GIL released), the views of each point re-tied to its reference view by spatial LSM and
intersected (blunders rejected, residual threshold),
the 3-D trajectories filtered (velocity, acceleration, local uniformity), lost views
re-acquired by spatial LSM at the projection of the 3-D point, and new points seeded where
the textured mask has none. Each frame is written to ``OUT/tracks/<frame:06d>.npz`` before
the next starts, with the 2-D state, so that a run resumes.

This module holds the public call and the assembly of the frames into :class:`Tracks`; the
per-frame step is :mod:`elastocap.tracking.step`, the re-acquisition of lost views
:mod:`elastocap.tracking.reacquire`, the revival of lost points
:mod:`elastocap.tracking.revival`, the tuned constants :mod:`elastocap.tracking.settings`."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_positive
from elastocap.capture import Capture
from elastocap.tracking.backward import track_backward
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.step import FrameTracker
from elastocap.tracking.tracks import Tracks, frame_file, load_tracks, read_frame, write_frame

__all__ = ["track_points"]


def _frames(capture: Capture, frames: Any) -> list[int]:
    if frames is None:
        return list(capture.frames)
    chosen = [int(f) for f in np.atleast_1d(np.asarray(frames)).tolist()]
    missing = sorted(set(chosen) - set(capture.frames))
    if missing:
        raise InvalidInputError(f"frames {missing[:5]} are not in the capture (it has {len(capture.frames)} frames)")
    if chosen != sorted(set(chosen)):
        raise InvalidInputError("frames must be increasing and without repeats")
    return chosen


def track_points(
    capture: Capture,
    *,
    frames: Sequence[int] | None = None,
    out: str | Path | None = None,
    spacing: int = 10,
    size: int = 15,
    radius: int = 6,
    min_correlation: float = 0.75,
    forward_backward: float = 0.6,
    max_residual: float = 1.5,
    min_views: int = 2,
    reseed_every: int = 5,
    reseed_bare: int = 0,
    seed_margin: int | None = None,
    max_velocity: float = 40.0,
    max_acceleration: float = 12.0,
    uniformity: float = 4.0,
    neighbours: int = 8,
    anchor: bool = True,
    rescue: bool = True,
    mask_weights: bool = True,
    revive: bool = True,
    backward: int = 0,
    progress: Callable[[int], None] | None = None,
) -> Tracks:
    """Track surface points through a capture in every camera and in 3-D.

    Parameters
    ----------
    capture : Capture
        Images, masks and calibrated cameras.
    frames : sequence of int, optional, keyword-only
        Increasing capture frame numbers to track through (default: all). Tracking runs
        from one to the next whatever the gaps.
    out : str or Path, optional, keyword-only
        When given, each frame goes to ``OUT/tracks/<frame:06d>.npz`` as it is done, and a
        run finding some of them resumes after the last (memory stays flat: the result is
        read back with :func:`load_tracks`).
    spacing : int, default 10, keyword-only
        Seed density: one point per ``spacing x spacing`` pixel cell of textured mask area
        per camera (and at least one per mask region).
    size : int, default 15, keyword-only
        Side of the matched patches, pixels (odd): printed textures on clothes are smooth
        at 11 px.
    radius : int, default 6, keyword-only
        Half-side of the NCC search box around the linear prediction, pixels.
    min_correlation : float, default 0.75, keyword-only
        Least correlation of the box search, of each least-squares match and of the seeds.
    forward_backward : float, default 0.6, keyword-only
        Largest miss of the forward-backward check, pixels (the anchors keep the drift
        that a looser check lets through from adding up).
    max_residual : float, default 1.5, keyword-only
        Largest reprojection residual of a view in the forward intersection, pixels.
    min_views : int, default 2, keyword-only
        Cameras a new seed must be matched in. Two views cannot reveal a false match by
        their residual; the correlation peak along the epipolar line must then be unique.
    reseed_every : int, default 5, keyword-only
        Seed new points on the first frame and every this many frames after.
    reseed_bare : int, default 0, keyword-only
        On the frames between those, seed new points too, but only in the textured mask
        area with no tracked point within this many ``spacing`` cells (the areas the tracks
        left bare: a fast limb loses all its points within a frame or two, and waits bare
        for the next seeding otherwise). 0: off.
    seed_margin : int, optional, keyword-only
        Least distance of a seed from its mask's edge, pixels (default ``size // 2 + 2``:
        the whole patch on the figure). Forearms, hands and feet are a patch or two wide in
        the image: at the default they hold almost no seed.
    max_velocity, max_acceleration : float, default 40 and 12, keyword-only
        Trajectory thresholds, pixel equivalents per frame (per frame squared).
    uniformity : float, default 4, keyword-only
        Largest deviation of a point's velocity from the median of its ``neighbours``
        nearest tracked points, pixel equivalents per frame.
    neighbours : int, default 8, keyword-only
        Neighbouring trajectories of the uniformity filter.
    anchor : bool, default True, keyword-only
        Refine each frame-to-frame match against the view's first-appearance patch
        (replaced when it stops matching), which stops the random-walk drift of chained
        matches (:mod:`elastocap.tracking.anchors`).
    rescue : bool, default True, keyword-only
        Views the frame-to-frame match lost are matched again from their anchor patch.
    mask_weights : bool, default True, keyword-only
        Weigh each template patch by its frame's silhouette mask in the frame-to-frame,
        anchor and cross-camera matches (weighted least squares, pixels outside the mask
        weigh 0): a patch on the silhouette's edge then follows the surface, not the
        background in its corner. Most views of limbs lie within a patch of the edge.
    revive : bool, default True, keyword-only
        Look for lost points again, under their own id, for 15 frames after they were lost
        (they left two-camera visibility or all their views failed): their anchor patches
        are searched for around the projections of their position predicted from the
        rigid motion of tracked points of their own body part (the points near it when it
        was lost whose distance to it had kept since its seeding), and they come back when
        two views intersect within 4 pixel equivalents of the prediction
        (:mod:`elastocap.tracking.revival`; ``settings.REVIVE_REACH``,
        ``settings.REVIVE_OWN_PART``). Needs ``anchor``. On the textured capture's five
        tuning seeds it keeps 1.6 points more of the points through their visibility
        (mean 28.1 -> 29.7%) and takes the kept 3-D positions beyond 5 px-equivalents
        from 2.26 to 2.03%, but a revived point's views are off by more (median RMS image
        error of all points 0.44 -> 0.51 px); on the held-out seeds through +1.2 and +2.1
        points, the kept 3-D figure +0.12 and -0.12 point (benches/README.md, branch
        track15). ``False`` gives the tracker as it was before.
    backward : int, default 0, keyword-only
        After the forward pass, follow every point seeded after the first frame backward
        from its seeding frame through at most this many earlier frames (the same step on
        the frames in reverse, seeding nothing; :mod:`elastocap.tracking.backward`), so
        that its track starts where it was first seen, nearer the rest frame of a fit.
        0: off. With ``out``, the frame files are rewritten once all are written (a
        ``tracks/backward.json`` records it; such a folder is not resumed with more frames).
        Measured with the elastic fit (textured fast capture, the pipeline's fit tracks,
        60 frames, 640 x 480; benches/README.md, sessions 23-24): at 60 the fit's drift
        with / without tracks falls on average (0.418 -> 0.393 over sixteen seeds), but
        on two seeds of eighteen one frame loses a limb that forward tracks keep (tracks seeded
        on a fast limb slide along it in their first frames, and the backward pass makes
        those frames their anchors), for 150-200 CPU s per 60 frames on top of the
        forward pass's 40-60. Off in the pipeline for that reason.
    progress : callable, optional, keyword-only
        Called with each frame number once it is done.

    Returns
    -------
    Tracks
        ``positions`` NaN and ``flags`` the reason where a point is not tracked.

    Raises
    ------
    InvalidInputError
        Options out of range, frames not in the capture, a capture without masks; more
        frames asked of an ``out`` whose tracks were followed backward.
    """
    if not capture.has_masks or not capture.has_images:
        raise InvalidInputError("capture must have images and masks to track points")
    chosen = _frames(capture, frames)
    if not chosen:
        raise InvalidInputError("frames is empty")
    spacing = as_count("spacing", spacing, minimum=2)
    size = as_count("size", size, minimum=3)
    if size % 2 == 0:
        raise InvalidInputError(f"size must be odd, got {size}")
    radius = as_count("radius", radius, minimum=0)
    backward = as_count("backward", backward, minimum=0)
    if not -1 <= float(min_correlation) <= 1:
        raise InvalidInputError(f"min_correlation must lie in [-1, 1], got {min_correlation!r}")
    options: dict[str, Any] = dict(
        forward_backward=as_positive("forward_backward", forward_backward),
        max_residual=as_positive("max_residual", max_residual),
        min_views=as_count("min_views", min_views, minimum=2),
        reseed_every=as_count("reseed_every", reseed_every),
        reseed_bare=as_count("reseed_bare", reseed_bare, minimum=0),
        seed_margin=None if seed_margin is None else as_count("seed_margin", seed_margin, minimum=0),
        max_velocity=as_positive("max_velocity", max_velocity),
        max_acceleration=as_positive("max_acceleration", max_acceleration),
        uniformity=as_positive("uniformity", uniformity),
        neighbours=as_count("neighbours", neighbours, minimum=3),
        anchor=bool(anchor),
        rescue=bool(rescue),
        mask_weights=bool(mask_weights),
        revive=bool(revive) and bool(anchor),
    )
    tracker = FrameTracker(capture, spacing, size, radius, float(min_correlation), options)
    records: list[dict[str, NDArray[np.generic]]] = []
    start = 0
    marker = None if out is None else Path(out) / "tracks" / "backward.json"
    if out is not None:
        start = tracker.resume(out, chosen)
        if marker is not None and marker.exists() and start < len(chosen):
            # Its files hold positions before each point's seeding that the forward state
            # (seeding frames, the rigid fusion's history) does not know.
            raise InvalidInputError(f"the tracks in {out} were followed backward; track more frames into a fresh folder")
    for i in range(start, len(chosen)):
        record = tracker.step(chosen[i], first=i == 0, reseed=i % options["reseed_every"] == 0, bare=options["reseed_bare"])
        if out is not None:
            write_frame(out, chosen[i], record)
        else:
            records.append({k: record[k] for k in ("ids", "positions", "covariances", "flags", "uv")})
        if progress is not None:
            progress(chosen[i])

    def follow(tracks: Tracks) -> Tracks:
        return track_backward(capture, tracks, reach=backward, spacing=spacing, size=size, radius=radius,
                              min_correlation=float(min_correlation), options=options)

    if out is not None:
        tracks = load_tracks(out)
        keep = np.isin(tracks.frames, chosen)
        tracks = Tracks(tracks.frames[keep], tracks.ids, tracks.positions[keep], tracks.covariances[keep], tracks.flags[keep],
                        None if tracks.views is None else tracks.views[keep])
        if backward and marker is not None and not marker.exists():
            tracks = follow(tracks)
            _rewrite(out, tracks)
            marker.write_text(json.dumps({"backward": backward}))
        return tracks
    tracks = _assemble(np.array(chosen, np.int64), records)
    return follow(tracks) if backward else tracks


def _rewrite(out: str | Path, tracks: Tracks) -> None:
    """Each frame file of ``out`` with the positions, covariances, flags and views of
    ``tracks``, its ids extended by the points followed back to it (seeded later); its
    other arrays, the forward state, kept as they were."""
    for i, frame in enumerate(tracks.frames):
        arrays = dict(read_frame(frame_file(out, int(frame))))
        ids = np.union1d(arrays["ids"], tracks.ids[tracks.flags[i] != TrackFlag.NOT_SEEDED]).astype(np.int64)
        arrays["ids"] = ids
        cols = np.searchsorted(tracks.ids, ids)
        arrays["positions"], arrays["covariances"] = tracks.positions[i, cols], tracks.covariances[i, cols]
        arrays["flags"] = tracks.flags[i, cols]
        if tracks.views is not None:
            arrays["uv"] = tracks.views[i, cols]
        write_frame(out, int(frame), arrays)


def _assemble(frames: NDArray[np.int64], records: list[dict[str, NDArray[np.generic]]]) -> Tracks:
    n = max((len(r["ids"]) for r in records), default=0)
    f = len(records)
    positions = np.full((f, n, 3), np.nan)
    covariances = np.full((f, n, 3, 3), np.nan)
    flags = np.full((f, n), TrackFlag.NOT_SEEDED, np.uint8)
    c = records[0]["uv"].shape[1] if records else 0
    views = np.full((f, n, c, 2), np.nan)
    for i, r in enumerate(records):
        m = len(r["ids"])
        views[i, :m] = r["uv"]
        positions[i, :m] = r["positions"]
        covariances[i, :m] = r["covariances"]
        flags[i, :m] = r["flags"]
    ids = records[-1]["ids"].astype(np.int64) if records else np.zeros(0, np.int64)
    return Tracks(frames=frames, ids=ids, positions=positions, covariances=covariances, flags=flags, views=views)

