"""``track_points``: surface points followed through a capture (SPEC 7, issue 15).

Per frame: every camera's points tracked from the previous frame in one Rust call
(prediction, NCC box search, temporal LSM, forward-backward check; parallel over points,
GIL released), the views of each point intersected (blunders rejected, residual threshold),
the 3-D trajectories filtered (velocity, acceleration, local uniformity), lost views
re-acquired by spatial LSM at the projection of the 3-D point, and new points seeded where
the textured mask has none. Each frame is written to ``OUT/tracks/<frame:06d>.npz`` before
the next starts, with the 2-D state, so that a run resumes."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap import _core
from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_positive
from elastocap.capture import Capture
from elastocap.stereo.matching import noise_level
from elastocap.tracking.anchors import Anchors
from elastocap.tracking.filters import pixel_size, trajectory_flags
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.revival import Lost
from elastocap.tracking.seeding import seed_points
from elastocap.tracking.tracks import Tracks, frame_file, load_tracks, read_frame, write_frame
from elastocap.tracking.views import (confirm_views, facing_normals, intersect_views, project_all, spatial_match, spatial_search,
                                      surface_normals)
from elastocap.tracking.visibility import predicted_visible

__all__ = ["track_points"]

# The matcher's covariance holds the noise of one match, not the drift of a chain of
# them: each view gets this standard deviation (pixels) on top in the intersection.
_FLOOR = 0.1
# Least RMS gradient of a patch along its weakest direction, in multiples of the image's
# noise level (smooth printed textures are weak at 11 px).
_TEXTURE_OVER_NOISE = 1.0
# The same floor for a view already tracked (hysteresis): a seed's patch turns and changes
# shading from frame to frame, and its weakest gradient wanders below the seeding floor
# without the match going wrong. Measured on the textured capture (seed 0, frame pairs
# started at the truth, views at least 12 px inside the silhouette): the floor at 1.0 x
# noise refuses 51% of them, at 0.5 x 12%, for a median error of 0.12 and 0.14 px.
_KEEP_TEXTURE_OVER_NOISE = 0.5
# Least correlation of the box search's peak (a start for least-squares matching).
_BOX_CORRELATION = 0.5
# Largest correction of a frame-to-frame match by its anchor, pixels.
_ANCHOR_REACH = 1.5
# Gauss-Newton iterations of the frame-to-frame match: from the box search's start a
# match that will converge does so in a few; the rest wander along the weak direction of a
# smooth texture (measured on the textured capture: 8 instead of 15 keeps 1.6% more views
# and costs 23% less CPU).
STEP_ITERATIONS = 8
# Largest distance of a rescued view from its linear prediction, pixels.
_RESCUE_REACH = 3.0
# A lost point is looked for again for this many frames after it was lost...
_REVIVE_FRAMES = 15
# ... by its anchors, in a box of this half-side (pixels) around the projections of its
# position predicted from its neighbours' motion; the intersection must land as near the
# prediction (pixel equivalents).
_REVIVE_RADIUS = 8
# Largest reprojection residual of a revived point's views, pixels (with two views, the
# distance from the epipolar line: a wrong match found far from the prediction).
_REVIVE_RESIDUAL = 1.5
_REVIVE_RECUT = False
# Least cosine between a lost point's predicted normal and the direction to a camera it is
# looked for in (a surface coming back into view is first seen at grazing angles).
_REVIVE_FACING = 0.0
# Largest distance of a re-acquired view from the projection of the point, pixels: a
# point held by one stereo pair has a poor depth, whose error shows in a camera 45-90
# degrees away as an offset of pixels along the epipolar line (the intersection with the
# new view then checks it and fixes the depth).
_REACQUIRE_TOLERANCE = 1.5
# The re-acquisition searches (NCC box of this half-side, pixels, with the patch warped by
# the neighbours' plane into the other camera) before its least-squares match; 0: the
# match alone, started at the projection. A found view may lie this far from the
# projection (the intersection with the view then checks it).
_REACQUIRE_RADIUS = 0
_REACQUIRE_SEARCH_TOLERANCE = 3.0
_REACQUIRE_ITERATIONS = 20
# Re-acquired views of a tracked point kept only when they intersect with its held ones.
_CONFIRM_REACQUIRED = True
# Start shapes of cross-camera matches from the plane of the neighbouring tracked points
# (else from the direction of the cameras that see the point).
_FITTED_NORMALS = True
# Re-acquire and revive a point only in the cameras predicted to see it
# (:mod:`elastocap.tracking.visibility`), not in every camera whose silhouette it falls in.
_PREDICT_VISIBILITY = True
# The frame-to-frame failures a view's anchor may rescue.
_RESCUED = (TrackFlag.LOW_CORRELATION, TrackFlag.FORWARD_BACKWARD, TrackFlag.MATCH_FAILED)


def _grey(image: NDArray[np.uint8]) -> NDArray[np.float32]:
    return np.ascontiguousarray(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32))


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
    max_velocity: float = 40.0,
    max_acceleration: float = 12.0,
    uniformity: float = 4.0,
    neighbours: int = 8,
    anchor: bool = True,
    rescue: bool = True,
    mask_weights: bool = True,
    revive: bool = False,
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
    revive : bool, default False, keyword-only
        Look for lost points again, under their own id, for 15 frames after they were lost
        (they left two-camera visibility or all their views failed): their anchor patches
        are searched for around the projections of their position predicted from the
        motion of the points tracked around them, and they come back when two views
        intersect near the prediction (:mod:`elastocap.tracking.revival`). Needs
        ``anchor``. Off by default: on the textured capture it keeps 1% more points through
        their visibility but its revived positions are less accurate (old anchors of a
        surface that turned), and 2% more kept 3-D positions lie beyond 5 px-equivalents
        (benches/README.md, branch track4).
    progress : callable, optional, keyword-only
        Called with each frame number once it is done.

    Returns
    -------
    Tracks
        ``positions`` NaN and ``flags`` the reason where a point is not tracked.

    Raises
    ------
    InvalidInputError
        Options out of range, frames not in the capture, a capture without masks.
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
    if not -1 <= float(min_correlation) <= 1:
        raise InvalidInputError(f"min_correlation must lie in [-1, 1], got {min_correlation!r}")
    options = dict(
        forward_backward=as_positive("forward_backward", forward_backward),
        max_residual=as_positive("max_residual", max_residual),
        min_views=as_count("min_views", min_views, minimum=2),
        reseed_every=as_count("reseed_every", reseed_every),
        max_velocity=as_positive("max_velocity", max_velocity),
        max_acceleration=as_positive("max_acceleration", max_acceleration),
        uniformity=as_positive("uniformity", uniformity),
        neighbours=as_count("neighbours", neighbours, minimum=3),
        anchor=bool(anchor),
        rescue=bool(rescue),
        mask_weights=bool(mask_weights),
        revive=bool(revive) and bool(anchor),
    )
    tracker = _Tracker(capture, spacing, size, radius, float(min_correlation), options)
    records: list[dict[str, NDArray[np.generic]]] = []
    start = 0
    if out is not None:
        start = tracker.resume(out, chosen)
    for i in range(start, len(chosen)):
        record = tracker.step(chosen[i], first=i == 0, reseed=i % options["reseed_every"] == 0)
        if out is not None:
            write_frame(out, chosen[i], record)
        else:
            records.append({k: record[k] for k in ("ids", "positions", "covariances", "flags", "uv")})
        if progress is not None:
            progress(chosen[i])
    if out is not None:
        tracks = load_tracks(out)
        keep = np.isin(tracks.frames, chosen)
        return Tracks(tracks.frames[keep], tracks.ids, tracks.positions[keep], tracks.covariances[keep], tracks.flags[keep],
                      None if tracks.views is None else tracks.views[keep])
    return _assemble(np.array(chosen, np.int64), records)


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


class _Tracker:
    """The state carried from frame to frame (all points, ids in order of seeding)."""

    def __init__(self, capture: Capture, spacing: int, size: int, radius: int, min_correlation: float,
                 options: dict[str, Any]) -> None:
        self.capture = capture
        self.names = capture.rig.names
        self.cameras = capture.rig.cameras
        self.spacing, self.size, self.radius, self.min_correlation = spacing, size, radius, min_correlation
        self.o = options
        c = len(self.cameras)
        self.uv = np.zeros((0, c, 2))
        self.uv_last = np.zeros((0, c, 2))
        self.x_last = np.zeros((0, 3))
        self.x_before = np.zeros((0, 3))
        self.point_flags = np.zeros(0, np.uint8)
        self.grey: list[NDArray[np.float32]] | None = None
        # The previous frame's template weights (its masks as 0/1 floats), when used.
        self.weights: list[NDArray[np.float32]] | None = None
        self.anchors = Anchors(c, size) if options["anchor"] else None
        self.lost = Lost(_REVIVE_FRAMES) if options["revive"] else None
        self.texture: list[float] = []
        self.keep_texture = 0.0

    def _read(self, frame: int) -> tuple[list[NDArray[np.float32]], list[NDArray[np.bool_]]]:
        grey = [_grey(self.capture.image(name, frame)) for name in self.names]
        masks = [self.capture.mask(name, frame) for name in self.names]
        if not self.texture:
            self.texture = [_TEXTURE_OVER_NOISE * noise_level(g) for g in grey]
            self.keep_texture = _KEEP_TEXTURE_OVER_NOISE / _TEXTURE_OVER_NOISE * min(self.texture)
        return grey, masks

    def _weights(self, masks: list[NDArray[np.bool_]]) -> list[NDArray[np.float32]] | None:
        if not self.o["mask_weights"]:
            return None
        return [np.ascontiguousarray(m, dtype=np.float32) for m in masks]

    def resume(self, out: str | Path, chosen: list[int]) -> int:
        """Restores the state after the longest prefix of ``chosen`` already written;
        returns the index to continue from."""
        done = 0
        while done < len(chosen) and frame_file(out, chosen[done]).exists():
            done += 1
        if done == 0:
            return 0
        last = read_frame(frame_file(out, chosen[done - 1]))
        before = read_frame(frame_file(out, chosen[done - 2])) if done >= 2 else None
        n = len(last["ids"])
        self.uv = last["uv"].astype(float)
        self.uv_last = np.full_like(self.uv, np.nan)
        self.x_last = last["positions"].astype(float)
        self.x_before = np.full((n, 3), np.nan)
        if before is not None:
            m = len(before["ids"])
            self.uv_last[:m] = before["uv"]
            self.x_before[:m] = before["positions"]
        self.point_flags = last["flags"].astype(np.uint8)
        if self.lost is not None:
            first = max(0, done - 1 - _REVIVE_FRAMES - 1)
            history = {chosen[j]: read_frame(frame_file(out, chosen[j]))["positions"] for j in range(first, done)}
            self.lost.restore(last, history)
        self.grey, masks = self._read(chosen[done - 1])
        self.weights = self._weights(masks)
        if self.anchors is not None and "anchor_frame" in last:
            where_frames = last["anchor_frame"]
            for source in np.unique(where_frames[where_frames >= 0]):
                if source == chosen[done - 1]:
                    grey, weights = self.grey, self.weights
                else:
                    grey, source_masks = self._read(int(source))
                    weights = self._weights(source_masks)
                self.anchors.cut(grey, last["anchor_uv"], where_frames == source, int(source), weights=weights)
        return done

    def step(self, frame: int, *, first: bool, reseed: bool) -> dict[str, NDArray[np.generic]]:
        grey, masks = self._read(frame)
        weights = self._weights(masks)
        n, c = self.uv.shape[:2]
        alive = np.isfinite(self.uv).all(axis=2).any(axis=1)
        if first or n == 0 or self.grey is None:
            uv = np.full((n, c, 2), np.nan)
            flags2d = np.full((n, c), TrackFlag.NOT_SEEDED, np.uint8)
            cov2d = np.full((n, c, 2, 2), np.nan)
            corr = np.full((n, c), np.nan)
        else:
            pos, f2d, cv2d, cr = _core.track_step(
                self.grey, grey, np.ascontiguousarray(self.uv.transpose(1, 0, 2)),
                np.ascontiguousarray(self.uv_last.transpose(1, 0, 2)), size=self.size, radius=self.radius,
                min_correlation=min(self.min_correlation, _BOX_CORRELATION), forward_backward=self.o["forward_backward"],
                min_texture=self.keep_texture, max_iterations=STEP_ITERATIONS,
                weights=None if weights is None or self.weights is None else (self.weights, weights))
            uv, flags2d, cov2d, corr = pos.transpose(1, 0, 2), f2d.T.copy(), cv2d.transpose(1, 0, 2, 3), cr.T
            # The box search only has to find the start (it does not model rotation or
            # scale); the least-squares match, which does, must reach the threshold.
            weak = (flags2d == TrackFlag.TRACKED) & ~(corr >= self.min_correlation)
            flags2d[weak] = TrackFlag.LOW_CORRELATION
            uv = np.where(weak[..., None], np.nan, uv)
            if self.anchors is not None:
                uv, stale = self.anchors.correct(grey, uv, min_correlation=self.min_correlation, reach=_ANCHOR_REACH,
                                                 min_texture=self.keep_texture)
                self.anchors.cut(grey, uv, stale, frame, weights=weights)
                if self.o["rescue"]:
                    # Views lost by the frame-to-frame match (not at the border) found again
                    # from their anchor at the linear prediction.
                    lost = (np.isfinite(self.uv[..., 0]) & ~np.isfinite(uv[..., 0])
                            & np.isin(flags2d, _RESCUED))
                    start = np.where(np.isfinite(self.uv_last), 2 * self.uv - self.uv_last, self.uv)
                    found, fcov = self.anchors.rescue(grey, start, lost, min_correlation=self.min_correlation,
                                                      reach=_RESCUE_REACH, min_texture=self.keep_texture)
                    back = np.isfinite(found[..., 0])
                    uv = np.where(back[..., None], found, uv)
                    cov2d = np.where(back[..., None, None], fcov, cov2d)
                    flags2d[back] = TrackFlag.TRACKED
        x, xcov, used, rejected = intersect_views(self.cameras, uv, cov2d, max_residual=self.o["max_residual"], floor=_FLOOR)
        flags2d[rejected] = TrackFlag.EPIPOLAR
        pixel = pixel_size(self.cameras, x, used)
        traj = trajectory_flags(x, self.x_last, self.x_before, pixel, max_velocity=self.o["max_velocity"],
                                max_acceleration=self.o["max_acceleration"], uniformity=self.o["uniformity"],
                                neighbours=self.o["neighbours"])
        x[traj > 0] = np.nan
        xcov[traj > 0] = np.nan
        tracked = np.isfinite(x).all(axis=1)
        # A point down to one view (occluded in the others) keeps it for a frame: its 3-D
        # position predicted from the last two is where the others are searched again.
        views = np.isfinite(uv[..., 0])
        single = ~tracked & (traj == 0) & (views.sum(axis=1) == 1) & np.isfinite(self.x_last).all(axis=1)
        keep = (used & tracked[:, None]) | (views & single[:, None])
        uv = np.where(keep[..., None], uv, np.nan)
        flags = _point_flags(flags2d, self.uv, traj, tracked, alive, self.point_flags)
        anchor = np.where(tracked[:, None], x, np.where(np.isfinite(self.x_before), 2 * self.x_last - self.x_before, self.x_last))
        anchor[~(tracked | single)] = np.nan
        found = tracked | single

        # Lost views re-acquired by spatial matching from the view of best correlation.
        if n and found.any():
            targets = project_all(self.cameras, anchor, margin=self.size)
            for k in range(c):
                iu = np.clip(np.round(np.nan_to_num(targets[:, k, 0])).astype(int), 0, masks[k].shape[1] - 1)
                iv = np.clip(np.round(np.nan_to_num(targets[:, k, 1])).astype(int), 0, masks[k].shape[0] - 1)
                wanted = found & ~np.isfinite(uv[:, k, 0]) & masks[k][iv, iu]
                targets[~wanted, k] = np.nan
            normals = np.full((n, 3), np.nan)
            normals[found] = self._normals(anchor[found], x, np.isfinite(uv[found, :, 0]))
            if _PREDICT_VISIBILITY:
                # Only the cameras that can see the point: its surface facing them and no
                # tracked point in front of it.
                asked = np.isfinite(targets).all(axis=2)
                targets[asked & ~predicted_visible(self.cameras, masks, anchor, normals, x, asked)] = np.nan
            score = np.where(np.isfinite(uv[..., 0]), np.nan_to_num(corr, nan=0.0) + 1.0, -1.0)
            reference = np.argmax(score, axis=1)
            rows = np.flatnonzero(np.isfinite(targets).all(axis=2).any(axis=1))
            if rows.size:
                matched, mcov = spatial_match(grey, reference[rows], uv[rows, reference[rows]], targets[rows],
                                              size=self.size, min_correlation=self.min_correlation,
                                              tolerance=_REACQUIRE_TOLERANCE + 2.0 * single[rows],
                                              min_texture=float(min(self.texture)), cameras=self.cameras,
                                              points=anchor[rows], normals=normals[rows],
                                              weights=weights)
                if _REACQUIRE_RADIUS:
                    # The views the match started at the projection did not find: searched for.
                    missed = np.where(np.isfinite(matched), np.nan, targets[rows])
                    searched, scov = spatial_search(
                        grey, reference[rows], uv[rows, reference[rows]], missed, cameras=self.cameras,
                        points=anchor[rows], normals=normals[rows], size=self.size, radius=_REACQUIRE_RADIUS,
                        min_correlation=self.min_correlation, box_correlation=min(self.min_correlation, _BOX_CORRELATION),
                        forward_backward=self.o["forward_backward"],
                        tolerance=_REACQUIRE_SEARCH_TOLERANCE + 2.0 * single[rows],
                        min_texture=float(min(self.texture)), max_iterations=_REACQUIRE_ITERATIONS, weights=weights)
                    matched = np.where(np.isfinite(searched), searched, matched)
                    mcov = np.where(np.isfinite(scov), scov, mcov)
                if _CONFIRM_REACQUIRED:
                    # A tracked point's new views are checked now with its held ones (one
                    # wrong view would fail the point's intersection on the next frame):
                    # kept, and the point intersected again, when every view agrees.
                    check = np.flatnonzero(tracked[rows])
                    matched[check], mcov[check], cx, ccov = confirm_views(
                        self.cameras, uv[rows[check]], cov2d[rows[check]], matched[check], mcov[check],
                        max_residual=self.o["max_residual"], floor=_FLOOR)
                    ok = np.isfinite(cx).all(axis=1)
                    x[rows[check[ok]]], xcov[rows[check[ok]]] = cx[ok], ccov[ok]
                uv[rows] = np.where(np.isfinite(matched), matched, uv[rows])
                cov2d[rows] = np.where(np.isfinite(mcov), mcov, cov2d[rows])
                # Points that were down to one view and got others back: intersect now.
                back = rows[single[rows] & (np.isfinite(uv[rows, :, 0]).sum(axis=1) >= 2)]
                if back.size:
                    bx, bcov, bused, _ = intersect_views(self.cameras, uv[back], cov2d[back],
                                                         max_residual=self.o["max_residual"], floor=_FLOOR)
                    ok = np.isfinite(bx).all(axis=1)
                    x[back[ok]], xcov[back[ok]], flags[back[ok]] = bx[ok], bcov[ok], TrackFlag.TRACKED
                    uv[back] = np.where((bused & ok[:, None])[..., None], uv[back], np.nan)
        lone = np.isfinite(uv[..., 0]).sum(axis=1) < 2
        uv[lone & ~single] = np.nan
        # A single view that found no partner is given up.
        uv[single & ~np.isfinite(x).all(axis=1) & lone] = np.nan
        # Keep the prediction of a point that waits on one view (its next frame predicts on).
        x_state = np.where((single & ~np.isfinite(x).all(axis=1))[:, None], anchor, x)

        if self.lost is not None and n:
            x, x_state = self._revive(frame, grey, masks, alive, uv, cov2d, x, xcov, x_state, flags, flags2d)

        # New points where the textured masks have none.
        if reseed:
            new = seed_points(grey, masks, self.cameras, uv, spacing=self.spacing, size=self.size,
                              min_correlation=self.min_correlation, min_views=self.o["min_views"],
                              min_texture=float(min(self.texture)), tolerance=self.o["max_residual"],
                              max_residual=self.o["max_residual"], floor=_FLOOR)
            if len(new):
                ncov = np.where(np.isfinite(new)[..., None], np.eye(2) * 0.01, np.nan)
                nx, nxcov, nused, _ = intersect_views(self.cameras, new, ncov, max_residual=self.o["max_residual"], floor=_FLOOR)
                ok = np.isfinite(nx).all(axis=1)
                new, nx, nxcov, nused = new[ok], nx[ok], nxcov[ok], nused[ok]
                new = np.where(nused[..., None], new, np.nan)
                m = len(new)
                uv = np.concatenate([uv, new])
                x = np.concatenate([x, nx])
                xcov = np.concatenate([xcov, nxcov])
                flags = np.concatenate([flags, np.zeros(m, np.uint8)])
                flags2d = np.concatenate([flags2d, np.where(nused, 0, TrackFlag.NOT_SEEDED).astype(np.uint8)])
                self.uv = np.concatenate([self.uv, np.full((m, c, 2), np.nan)])
                self.x_last = np.concatenate([self.x_last, np.full((m, 3), np.nan)])
                self.x_before = np.concatenate([self.x_before, np.full((m, 3), np.nan)])
        total = len(uv)
        if self.anchors is not None:
            views_now = np.isfinite(uv[..., 0])
            self.anchors.grow(total)
            # A lost point keeps the anchors it had while it may be revived.
            waiting = np.zeros(total, bool)
            if self.lost is not None:
                self.lost.grow(total)
                waiting = self.lost.since[:total] >= 0
            self.anchors.drop(~views_now & ~waiting[:, None])
            self.anchors.cut(grey, uv, views_now & ~self.anchors.held[:total], frame, weights=weights)
        self.uv_last, self.uv = self.uv, uv
        if len(x_state) < len(x):
            x_state = np.concatenate([x_state, x[len(x_state):]])
        self.x_before, self.x_last = self.x_last, x_state
        self.point_flags = flags
        if self.lost is not None:
            self.lost.remember(frame, x)
        self.grey = grey
        self.weights = weights
        return {
            "ids": np.arange(total, dtype=np.int64),
            "positions": x,
            "covariances": xcov,
            "flags": flags,
            "uv": uv,
            "flags2d": flags2d,
            **({} if self.lost is None else self.lost.state(total)),
            **({} if self.anchors is None else {
                "anchor_frame": np.where(self.anchors.held[:total], self.anchors.frame[:total], -1),
                "anchor_uv": self.anchors.uv[:total],
            }),
        }

    def _normals(self, points: NDArray[np.float64], cloud: NDArray[np.float64],
                 seen: NDArray[np.bool_]) -> NDArray[np.float64]:
        """Surface normals at ``points`` for the start shape of wide-baseline matches."""
        towards = facing_normals(self.cameras, points, seen)
        return surface_normals(points, cloud, towards) if _FITTED_NORMALS else towards

    def _revive(self, frame: int, grey: list[NDArray[np.float32]], masks: list[NDArray[np.bool_]],
                alive: NDArray[np.bool_], uv: NDArray[np.float64], cov2d: NDArray[np.float64], x: NDArray[np.float64],
                xcov: NDArray[np.float64], x_state: NDArray[np.float64], flags: NDArray[np.uint8],
                flags2d: NDArray[np.uint8]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Records the points lost on this frame and brings back lost ones whose anchors
        match again (``uv``, ``cov2d``, ``xcov``, ``flags`` and ``flags2d`` are updated in
        place); returns ``x`` and ``x_state``."""
        assert self.lost is not None and self.anchors is not None
        n, c = uv.shape[:2]
        self.lost.grow(n)
        left = np.isfinite(uv[..., 0]).any(axis=1)
        self.lost.record(alive & ~left, self.x_last, frame)
        self.lost.forget((self.lost.since[:n] >= 0) & (frame - self.lost.since[:n] > _REVIVE_FRAMES))
        rows = self.lost.candidates(frame)
        rows = rows[(rows < n) & ~left[rows]]
        if rows.size == 0:
            return x, x_state
        tracked = np.isfinite(x).all(axis=1)
        predicted = self.lost.predict(rows, np.where(tracked[:, None], x, np.nan))
        targets = project_all(self.cameras, predicted, margin=self.size)
        if _PREDICT_VISIBILITY:
            # The cameras that held the point and are predicted to see it again.
            asked = np.isfinite(targets).all(axis=2) & self.anchors.held[rows]
            normals = self._normals(predicted, x, self.anchors.held[rows])
            seen = predicted_visible(self.cameras, masks, predicted, normals, x, asked, facing=_REVIVE_FACING)
            targets[asked & ~seen] = np.nan
        where = np.zeros((n, c), bool)
        starts = np.full((n, c, 2), np.nan)
        for k in range(c):
            t = targets[:, k]
            seen = np.isfinite(t).all(axis=1)
            iu = np.clip(np.round(np.nan_to_num(t[:, 0])).astype(int), 0, masks[k].shape[1] - 1)
            iv = np.clip(np.round(np.nan_to_num(t[:, 1])).astype(int), 0, masks[k].shape[0] - 1)
            ok = seen & masks[k][iv, iu] & self.anchors.held[rows, k]
            where[rows[ok], k] = True
            starts[rows[ok], k] = t[ok]
        pairs = where[rows].sum(axis=1) >= 2
        rows, predicted = rows[pairs], predicted[pairs]
        if rows.size == 0:
            return x, x_state
        found, fcov = self.anchors.search(grey, starts, where, radius=_REVIVE_RADIUS, min_correlation=self.min_correlation,
                                          box_correlation=min(self.min_correlation, _BOX_CORRELATION),
                                          forward_backward=self.o["forward_backward"], min_texture=self.keep_texture,
                                          max_iterations=STEP_ITERATIONS)
        two = np.isfinite(found[rows, :, 0]).sum(axis=1) >= 2
        rows, predicted = rows[two], predicted[two]
        if rows.size == 0:
            return x, x_state
        bx, bcov, bused, _ = intersect_views(self.cameras, found[rows], fcov[rows],
                                             max_residual=min(self.o["max_residual"], _REVIVE_RESIDUAL), floor=_FLOOR)
        ok = np.isfinite(bx).all(axis=1)
        with np.errstate(invalid="ignore"):
            near = np.linalg.norm(bx - predicted, axis=1) <= _REVIVE_RADIUS * pixel_size(self.cameras, bx, bused)
        ok &= near
        back = rows[ok]
        uv[back] = np.where(bused[ok][..., None], found[back], np.nan)
        cov2d[back] = np.where(bused[ok][..., None, None], fcov[back], np.nan)
        flags2d[back] = np.where(bused[ok], TrackFlag.TRACKED, flags2d[back])
        x, x_state = x.copy(), x_state.copy()
        x[back], xcov[back], x_state[back] = bx[ok], bcov[ok], bx[ok]
        flags[back] = TrackFlag.TRACKED
        revived = np.zeros(n, bool)
        revived[back] = True
        self.lost.forget(revived)
        if _REVIVE_RECUT:
            # The anchors of a surface that turned away and back are old: the views found
            # now are cut again from this frame (at the end of the step).
            self.anchors.drop(revived[:, None] & np.ones(c, bool))
        return x, x_state


def _point_flags(flags2d: NDArray[np.uint8], previous: NDArray[np.float64], traj: NDArray[np.uint8],
                 tracked: NDArray[np.bool_], alive: NDArray[np.bool_], before: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """Per point: 0 where tracked; else the trajectory filter's flag; else the most common
    2-D reason among the cameras that held it; a point dead before keeps its flag."""
    n = len(tracked)
    flags = np.zeros(n, np.uint8)
    held = np.isfinite(previous).all(axis=2)
    counts = np.zeros((n, len(TrackFlag)), int)
    rows, cols = np.nonzero(held)
    np.add.at(counts, (rows, flags2d[rows, cols]), 1)
    counts[:, :2] = 0
    reason = np.where(counts.any(axis=1), np.argmax(counts, axis=1), TrackFlag.FEW_VIEWS)
    flags[~tracked] = reason[~tracked]
    flags[traj > 0] = traj[traj > 0]
    flags[~alive] = np.where(before[~alive] == 0, TrackFlag.NOT_SEEDED, before[~alive])
    return flags
