"""The tracker's per-frame step (issue 15): the state carried from frame to frame and one
frame's work on it. Every camera's points tracked from the previous frame in one Rust call
(prediction, NCC box search, temporal LSM, forward-backward check), corrected by their
anchors and rescued from them, re-tied to one another across the cameras
(:mod:`elastocap.tracking.retie`), intersected, filtered as trajectories;
then the lost views re-acquired (:mod:`elastocap.tracking.reacquire`), optionally handed over
to another stereo pair (:mod:`elastocap.tracking.handover`), lost points revived
(:mod:`elastocap.tracking.revival`) and new points seeded (:mod:`elastocap.tracking.seeding`).
The step returns the arrays that :func:`elastocap.tracking.tracks.write_frame` writes, with
the 2-D state that :meth:`FrameTracker.resume` reads back."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap.capture import Capture
from elastocap.stereo.matching import noise_level
from elastocap.tracking import settings
from elastocap.tracking.anchors import Anchors
from elastocap.tracking.depth_weights import depth_edges, rust_step, track_step_by_depth
from elastocap.tracking.filters import pixel_size, trajectory_flags
from elastocap.tracking.drift import drift_covariance, not_positive_definite, weakest_sd
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.handover import hand_over
from elastocap.tracking.hidden import end_hidden_views
from elastocap.tracking.prediction import drop_breaking_views, drop_far_views, research_failed_views
from elastocap.tracking.pyramid_search import check_options as check_pyramid_options
from elastocap.tracking.pyramid_search import pyramid_search
from elastocap.tracking.reacquire import reacquire
from elastocap.tracking.retie import retie_views
from elastocap.tracking.revival import Lost, revive
from elastocap.tracking.rigid_prediction import predicting_before, rigid_predictions
from elastocap.tracking.rigidity import rigid_fusion, rigid_residuals
from elastocap.tracking.seeding import seed_points
from elastocap.tracking.silhouette import outside_silhouettes
from elastocap.tracking.tracks import frame_file, read_frame
from elastocap.tracking.views import facing_normals, intersect_views, surface_normals

__all__ = ["FrameTracker", "point_flags"]


def _grey(image: NDArray[np.uint8]) -> NDArray[np.float32]:
    return np.ascontiguousarray(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32))


class FrameTracker:
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
        # The previous frame's masks (the depth edges' images, settings.DEPTH_WEIGHTS).
        self.masks: list[NDArray[np.bool_]] | None = None
        self.anchors = Anchors(c, size) if options["anchor"] else None
        self.lost = Lost(settings.REVIVE_FRAMES) if options["revive"] else None
        # Per point and camera: consecutive frames its held view was predicted hidden.
        self.hidden = np.zeros((0, c), np.int64)
        # Per point: the frame it was first tracked on (-1: not yet), and the positions
        # reported on such frames, for the neighbours' rigid motion since (settings.RIGID).
        self.seeded_at = np.zeros(0, np.int64)
        self.history: dict[int, NDArray[np.float64]] = {}
        # Per point: found slid off its neighbours' rigid map (settings.SLIDE); withheld
        # from then on.
        self.slid = np.zeros(0, bool)
        self.texture: list[float] = []
        self.keep_texture = 0.0

    def _read(self, frame: int) -> tuple[list[NDArray[np.float32]], list[NDArray[np.bool_]]]:
        grey = [_grey(self.capture.image(name, frame)) for name in self.names]
        masks = [self.capture.mask(name, frame) for name in self.names]
        if not self.texture:
            self.texture = [settings.TEXTURE_OVER_NOISE * noise_level(g) for g in grey]
            self.keep_texture = settings.KEEP_TEXTURE_OVER_NOISE / settings.TEXTURE_OVER_NOISE * min(self.texture)
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
        # The state is the intersections (the reported positions are fused and may be
        # withheld); files written before they were recorded hold only the positions.
        self.x_last = _intersections(last)
        self.x_before = np.full((n, 3), np.nan)
        if before is not None:
            m = len(before["ids"])
            self.uv_last[:m] = before["uv"]
            self.x_before[:m] = _intersections(before)
        self.point_flags = last["flags"].astype(np.uint8)
        self.seeded_at = np.full(n, -1, np.int64)
        for frame in chosen[:done]:
            written = read_frame(frame_file(out, frame))
            # Seeded where first intersected, as the step counts it: a position withheld
            # on its seeding frame (OUTSIDE) is not written but was seeded there.
            crossed = _intersections(written)
            new = np.flatnonzero(np.isfinite(crossed).all(axis=1) & (self.seeded_at[: len(crossed)] < 0))
            if new.size:
                self.seeded_at[new] = frame
                self.history[frame] = crossed
            found = np.flatnonzero(written["flags"] == TrackFlag.SLID)
            if found.size:
                self.slid = np.concatenate([self.slid, np.zeros(max(0, found.max() + 1 - len(self.slid)), bool)])
                self.slid[found] = True
        if self.lost is not None:
            first = max(0, done - 1 - settings.REVIVE_FRAMES - 1)
            history = {chosen[j]: _intersections(read_frame(frame_file(out, chosen[j]))) for j in range(first, done)}
            self.lost.restore(last, history)
        self.grey, masks = self._read(chosen[done - 1])
        self.weights = self._weights(masks)
        self.masks = masks
        if self.anchors is not None and "anchor_frame" in last:
            where_frames = np.asarray(last["anchor_frame"], np.int64)
            for source in np.unique(where_frames[where_frames >= 0]):
                if source == chosen[done - 1]:
                    grey, weights = self.grey, self.weights
                else:
                    grey, source_masks = self._read(int(source))
                    weights = self._weights(source_masks)
                self.anchors.cut(grey, np.asarray(last["anchor_uv"], np.float64), where_frames == source, int(source), weights=weights)
            if "anchor_cuts" in last:
                # The cuts again drive the drift covariance, which weighs the fusion.
                self.anchors.grow(len(where_frames))
                self.anchors.cuts[: len(where_frames)] = last["anchor_cuts"]
        self._forget()
        return done
    def _before(self) -> NDArray[np.float64]:
        """(N, C, 2) the views' positions on the frame before as the Rust step reads them
        (it predicts ``2 uv - before``, ``uv`` without one): ``uv_last``, or with
        ``settings.RIGID_PREDICTION`` set so that the chosen views are predicted by their
        neighbourhood's rigid 3-D motion (:mod:`elastocap.tracking.rigid_prediction`)."""
        if settings.RIGID_PREDICTION is None or len(self.uv) == 0:
            return self.uv_last
        held = np.isfinite(self.uv[..., 0])
        pixel = pixel_size(self.cameras, self.x_last, held)
        prediction = rigid_predictions(self.cameras, self.uv, self.x_last, self.x_before, pixel,
                                       neighbours=settings.RIGID_PREDICTION_NEIGHBOURS,
                                       min_neighbours=settings.RIGID_PREDICTION_MIN_NEIGHBOURS,
                                       reach=settings.RIGID_PREDICTION_REACH)
        if settings.RIGID_PREDICTION == "all":
            use = held
        elif settings.RIGID_PREDICTION == "new":
            use = held & ~np.isfinite(self.uv_last[..., 0])
        else:
            raise ValueError(f"RIGID_PREDICTION must be None, 'new' or 'all', not {settings.RIGID_PREDICTION!r}")
        return predicting_before(self.uv, self.uv_last, prediction, use)

    def step(self, frame: int, *, first: bool, reseed: bool, bare: int = 0) -> dict[str, NDArray[np.generic]]:
        grey, masks = self._read(frame)
        weights = self._weights(masks)
        n, c = self.uv.shape[:2]
        alive = np.any(np.all(np.isfinite(self.uv), axis=2), axis=1)
        if first or n == 0 or self.grey is None:
            uv = np.full((n, c, 2), np.nan)
            flags2d = np.full((n, c), TrackFlag.NOT_SEEDED, np.uint8)
            cov2d = np.full((n, c, 2, 2), np.nan)
            corr = np.full((n, c), np.nan)
        shift = np.full((n, c), np.nan)
        researched = np.zeros((n, c), bool)
        wide = np.zeros((n, c), bool)
        if not (first or n == 0 or self.grey is None):
            step = rust_step(self.grey, grey)
            before = self._before()
            pair = None if weights is None or self.weights is None else (self.weights, weights)
            options = dict(size=self.size, radius=self.radius,
                           min_correlation=min(self.min_correlation, settings.BOX_CORRELATION),
                           forward_backward=self.o["forward_backward"], min_texture=self.keep_texture,
                           max_iterations=settings.STEP_ITERATIONS, weighted_box=settings.WEIGHTED_BOX)
            edges = None
            if settings.DEPTH_WEIGHTS and self.masks is not None:
                # Templates that straddle a depth edge matched without the other surface.
                edges = depth_edges(self.cameras, self.uv, self.x_last, self.x_before, self.masks, masks,
                                    reach=settings.DEPTH_WEIGHTS_REACH, tolerance=settings.DEPTH_WEIGHTS_TOLERANCE,
                                    band=settings.DEPTH_WEIGHTS_BAND, current=settings.DEPTH_WEIGHTS_CURRENT)
                uv, flags2d, cov2d, corr = track_step_by_depth(step, self.uv, before, pair, edges, half=self.size // 2,
                                                               width=settings.DEPTH_WEIGHTS_BIN, **options)
            else:
                uv, flags2d, cov2d, corr = step(self.uv, before, weights=pair, **options)
            # The box search only has to find the start (it does not model rotation or
            # scale); the least-squares match, which does, must reach the threshold.
            weak = (flags2d == TrackFlag.TRACKED) & ~(corr >= self.min_correlation)
            flags2d[weak] = TrackFlag.LOW_CORRELATION
            uv = np.where(weak[..., None], np.nan, uv)
            if settings.RESEARCH:
                # The failed views searched again where their neighbours went (a fast
                # limb's, and a new point's, which has no velocity to predict from).
                held = np.isfinite(self.uv[..., 0])
                reach = settings.RESEARCH_REACH * pixel_size(self.cameras, self.x_last, held)
                found = research_failed_views(
                    self.grey, grey, self.uv, before, uv, flags2d, cov2d, corr, self.x_last, reach, size=settings.RESEARCH_SIZE or self.size,
                    radius=self.radius, wide_radius=settings.RESEARCH_WIDE_RADIUS, min_correlation=self.min_correlation,
                    box_correlation=min(self.min_correlation, settings.BOX_CORRELATION),
                    forward_backward=self.o["forward_backward"], min_texture=self.keep_texture,
                    max_iterations=settings.STEP_ITERATIONS,
                    weights=None if weights is None or self.weights is None else (self.weights, weights),
                    neighbours=settings.RESEARCH_NEIGHBOURS, min_neighbours=settings.RESEARCH_MIN_NEIGHBOURS,
                    edges=edges if settings.DEPTH_WEIGHTS_RESEARCH else None, edge_width=settings.DEPTH_WEIGHTS_BIN,
                    wide_correlation=settings.RESEARCH_WIDE_CORRELATION, weighted_box=settings.WEIGHTED_BOX)
                uv, flags2d, cov2d, corr = found.uv, found.flags2d, found.cov2d, found.corr
                researched = found.found
                wide = found.found & ~found.by_neighbours
            if settings.PYRAMID_SEARCH:
                # A young view (no position on the frame before: a new seed's first step,
                # predicted at no motion) lost by the match searched coarse to fine.
                check_pyramid_options(level=settings.PYRAMID_LEVEL, radius=settings.PYRAMID_RADIUS,
                                      size=settings.PYRAMID_SIZE, correlation=settings.PYRAMID_CORRELATION,
                                      margin=settings.PYRAMID_PEAK_MARGIN, exclusion=settings.PYRAMID_PEAK_EXCLUSION,
                                      pool=settings.PYRAMID_POOL, reach=settings.PYRAMID_POOL_REACH)
                young = np.isfinite(self.uv[..., 0]) & ~np.isfinite(self.uv_last[..., 0])
                held_now = np.isfinite(self.uv[..., 0])
                pool_reach = settings.PYRAMID_POOL_REACH * pixel_size(self.cameras, self.x_last, held_now)
                coarse = pyramid_search(
                    self.grey, grey, self.uv, before, young, uv, flags2d, cov2d, corr, level=settings.PYRAMID_LEVEL,
                    radius=settings.PYRAMID_RADIUS, coarse_size=settings.PYRAMID_SIZE,
                    coarse_correlation=settings.PYRAMID_CORRELATION,
                    exclusion=settings.PYRAMID_PEAK_EXCLUSION, margin=settings.PYRAMID_PEAK_MARGIN, size=self.size,
                    fine_radius=self.radius, min_correlation=self.min_correlation,
                    box_correlation=min(self.min_correlation, settings.BOX_CORRELATION),
                    forward_backward=self.o["forward_backward"], min_texture=self.keep_texture,
                    max_iterations=settings.STEP_ITERATIONS, weights=pair, weighted_box=settings.WEIGHTED_BOX,
                    pool=settings.PYRAMID_POOL, x_last=self.x_last, reach=pool_reach)
                uv, flags2d, cov2d, corr = coarse.uv, coarse.flags2d, coarse.cov2d, coarse.corr
                # A blunder found this wide must not end its point (as the second search's).
                researched = researched | coarse.found
            if self.anchors is not None:
                uv, stale = self.anchors.correct(grey, uv, min_correlation=self.min_correlation, reach=settings.ANCHOR_REACH,
                                                 min_texture=self.keep_texture)
                self.anchors.cut(grey, uv, stale, frame, weights=weights)
                if self.o["rescue"]:
                    # Views lost by the frame-to-frame match (not at the border) found again
                    # from their anchor at the linear prediction.
                    lost = (np.isfinite(self.uv[..., 0]) & ~np.isfinite(uv[..., 0])
                            & np.isin(flags2d, settings.RESCUED))
                    start = np.where(np.isfinite(before), 2 * self.uv - before, self.uv)
                    rescued, rcov = self.anchors.rescue(grey, start, lost, min_correlation=self.min_correlation,
                                                        reach=settings.RESCUE_REACH, min_texture=self.keep_texture)
                    back = np.isfinite(rescued[..., 0])
                    uv = np.where(back[..., None], rescued, uv)
                    cov2d = np.where(back[..., None, None], rcov, cov2d)
                    flags2d[back] = TrackFlag.TRACKED
            if settings.RETIE:
                # The held views' disparity measured afresh (their chains drift apart).
                preference = np.nan_to_num(corr, nan=0.0)
                if settings.RETIE_REFERENCE == "anchor" and self.anchors is not None:
                    # The view whose anchor is oldest (cut again fewest times: drifted
                    # least), the correlation breaking ties. Frames apart, either way: a
                    # backward pass (tracking/backward.py) steps to earlier frames.
                    age = np.where(self.anchors.held[:n], np.abs(frame - self.anchors.frame[:n]), 0)
                    preference = age / (frame + 1.0) + 1e-3 * preference
                uv, cov2d, removed, shift = retie_views(grey, uv, cov2d, preference, size=self.size, min_correlation=self.min_correlation,
                                                 tolerance=settings.RETIE_TOLERANCE, drop=settings.RETIE_DROP,
                                                 drop_failed=settings.RETIE_DROP_FAILED,
                                                 min_texture=self.keep_texture, weights=weights)
                flags2d[removed] = TrackFlag.EPIPOLAR
        x, xcov, used, rejected = intersect_views(self.cameras, uv, cov2d, max_residual=self.o["max_residual"], floor=settings.FLOOR)
        if researched.any():
            x, xcov, used, rejected = drop_breaking_views(self.cameras, uv, cov2d, flags2d, researched, x, xcov, used, rejected,
                                                          max_residual=self.o["max_residual"], floor=settings.FLOOR)
        if np.isfinite(settings.RESEARCH_WIDE_RESIDUAL) and wide.any():
            # The wide box's finds held to a tighter residual than the intersection's.
            x, xcov, used, rejected = drop_far_views(self.cameras, uv, cov2d, flags2d, wide, x, xcov, used, rejected,
                                                     tolerance=settings.RESEARCH_WIDE_RESIDUAL,
                                                     max_residual=self.o["max_residual"], floor=settings.FLOOR)
        flags2d[rejected] = TrackFlag.EPIPOLAR
        set_aside = np.zeros((n, c), bool)
        if settings.HIDDEN_FRAMES and n:
            uv, cov2d, x, xcov, used, set_aside = end_hidden_views(self, masks, uv, cov2d, x, xcov, used, corr, shift, flags2d)
        pixel = pixel_size(self.cameras, x, used)
        traj = trajectory_flags(x, self.x_last, self.x_before, pixel, max_velocity=self.o["max_velocity"],
                                max_acceleration=self.o["max_acceleration"], uniformity=self.o["uniformity"],
                                neighbours=self.o["neighbours"])
        x[traj > 0] = np.nan
        xcov[traj > 0] = np.nan
        tracked = np.all(np.isfinite(x), axis=1)
        # A point down to one view (occluded in the others) keeps it for a frame: its 3-D
        # position predicted from the last two is where the others are searched again.
        views = np.isfinite(uv[..., 0])
        single = ~tracked & (traj == 0) & (views.sum(axis=1) == 1) & np.all(np.isfinite(self.x_last), axis=1)
        keep = ((used | set_aside) & tracked[:, None]) | (views & single[:, None])
        uv = np.where(keep[..., None], uv, np.nan)
        flags = point_flags(flags2d, self.uv, traj, tracked, alive, self.point_flags)
        anchor = np.where(tracked[:, None], x, np.where(np.isfinite(self.x_before), 2 * self.x_last - self.x_before, self.x_last))
        anchor[~(tracked | single)] = np.nan

        # Lost views re-acquired by spatial matching from the view of best correlation.
        reacquire(self, grey, masks, weights, uv, cov2d, corr, x, xcov, flags, tracked, single, anchor)
        if settings.HANDOVER:
            # The other stereo pairs that see a tracked point take it on before its pair
            # loses it.
            hand_over(self, grey, masks, weights, uv, cov2d, x, xcov, tracked & np.all(np.isfinite(x), axis=1))
        lone = np.isfinite(uv[..., 0]).sum(axis=1) < 2
        uv[lone & ~single] = np.nan
        # A single view that found no partner is given up.
        uv[single & ~np.isfinite(x).all(axis=1) & lone] = np.nan
        # Keep the prediction of a point that waits on one view (its next frame predicts on).
        x_state = np.where((single & ~np.isfinite(x).all(axis=1))[:, None], anchor, x)

        if self.lost is not None and n:
            x, x_state = revive(self, frame, grey, masks, alive, uv, cov2d, x, xcov, x_state, flags, flags2d)

        # New points where the textured masks have none (with ``bare`` alone: only where
        # none lies within ``bare`` cells, seeding.seed_candidates).
        if reseed or bare > 0:
            new = seed_points(grey, masks, self.cameras, uv, spacing=self.spacing, size=self.size,
                              min_correlation=self.min_correlation, min_views=self.o["min_views"],
                              min_texture=float(min(self.texture)), tolerance=self.o["max_residual"],
                              max_residual=self.o["max_residual"], floor=settings.FLOOR, bare=0 if reseed else bare,
                              margin=self.o.get("seed_margin"))
            if len(new):
                ncov = np.where(np.isfinite(new)[..., None], np.eye(2) * 0.01, np.nan)
                nx, nxcov, nused, _ = intersect_views(self.cameras, new, ncov, max_residual=self.o["max_residual"], floor=settings.FLOOR)
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
        self.masks = masks
        self.seeded_at = np.concatenate([self.seeded_at, np.full(total - len(self.seeded_at), -1, np.int64)])
        new = (self.seeded_at < 0) & np.all(np.isfinite(x), axis=1)
        self.seeded_at[new] = frame
        if new.any():
            # The intersections, not the fused positions: what the neighbours' motion is
            # measured from then does not depend on the fusion or on withheld positions.
            self.history[frame] = x.copy()
        x_out, xcov, flags_out = self._reported(uv, x, xcov, flags)
        self._forget()
        return {
            "ids": np.arange(total, dtype=np.int64),
            "positions": x_out,
            "intersections": x,
            "covariances": xcov,
            "flags": flags_out,
            "uv": uv,
            "flags2d": flags2d,
            **({} if self.lost is None else self.lost.state(total)),
            **({} if self.anchors is None else {
                "anchor_frame": np.where(self.anchors.held[:total], self.anchors.frame[:total], -1),
                "anchor_uv": self.anchors.uv[:total],
                "anchor_cuts": self.anchors.cuts[:total],
            }),
        }

    def _reported(self, uv: NDArray[np.float64], x: NDArray[np.float64], xcov: NDArray[np.float64],
                  flags: NDArray[np.uint8]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.uint8]]:
        """The positions, covariances and flags written out: the covariance with the drift
        of the views (``settings.DRIFT``), the positions fused with their neighbours' rigid
        prediction (``settings.RIGID``), and withheld (the state the next frame starts from
        keeps them): slid off that prediction (``settings.SLIDE``), outside a camera's
        silhouette (``settings.OUTSIDE``), too uncertain before the fusion
        (``settings.UNCERTAIN_DRIFT_SD``) or after it (``settings.UNCERTAIN_SD``), and
        where the intersection's covariance is not positive definite."""
        broken = np.isfinite(x).all(axis=1) & not_positive_definite(xcov)
        if broken.any():
            x, xcov, flags = x.copy(), xcov.copy(), flags.copy()
            x[broken], xcov[broken], flags[broken] = np.nan, np.nan, TrackFlag.UNCERTAIN
        if not settings.DRIFT:
            return x, xcov, flags
        views = np.isfinite(uv[..., 0])
        recuts = self.anchors.recuts(views) if self.anchors is not None else np.zeros(len(x), np.int64)
        pixel = pixel_size(self.cameras, x, views)
        xcov = drift_covariance(xcov, pixel, recuts, scale=settings.DRIFT_SCALE, variance=settings.DRIFT_VARIANCE)
        x_in, cov_in = x, xcov
        if settings.RIGID:
            x, xcov = rigid_fusion(x, xcov, pixel, self.seeded_at, self.history, neighbours=settings.RIGID_NEIGHBOURS,
                                   sigma=settings.RIGID_SIGMA, both_frames=settings.RIGID_BOTH_FRAMES,
                                   candidates=settings.RIGID_CANDIDATES, stretch=settings.RIGID_STRETCH)
        if np.isfinite(settings.SLIDE):
            x, xcov, flags = self._withhold_slid(x_in, cov_in, x, xcov, flags, pixel, views)
        if np.isfinite(settings.OUTSIDE) and self.masks is not None:
            outside = outside_silhouettes(self.cameras, self.masks, x, settings.OUTSIDE)
            if outside.any():
                x, xcov, flags = x.copy(), xcov.copy(), flags.copy()
                x[outside], xcov[outside], flags[outside] = np.nan, np.nan, TrackFlag.OUTSIDE
        if np.isfinite(settings.UNCERTAIN_DRIFT_SD):
            # The drift covariance before the fusion: the fusion shrinks it by the
            # neighbours' prediction, which drifted with the point when the whole
            # neighbourhood did.
            with np.errstate(invalid="ignore"):
                unsure = (weakest_sd(cov_in, pixel) > settings.UNCERTAIN_DRIFT_SD) & np.isfinite(x).all(axis=1)
            if unsure.any():
                x, xcov, flags = x.copy(), xcov.copy(), flags.copy()
                x[unsure], xcov[unsure], flags[unsure] = np.nan, np.nan, TrackFlag.UNCERTAIN
        if settings.COVARIANCE_SCALE != 1.0:
            xcov = xcov * settings.COVARIANCE_SCALE
        if not np.isfinite(settings.UNCERTAIN_SD):
            return x, xcov, flags
        with np.errstate(invalid="ignore"):
            unsure = weakest_sd(xcov, pixel) > settings.UNCERTAIN_SD
        x, xcov, flags = x.copy(), xcov.copy(), flags.copy()
        x[unsure], xcov[unsure], flags[unsure] = np.nan, np.nan, TrackFlag.UNCERTAIN
        return x, xcov, flags

    def _withhold_slid(self, x_in: NDArray[np.float64], cov_in: NDArray[np.float64], x: NDArray[np.float64],
                       xcov: NDArray[np.float64], flags: NDArray[np.uint8], pixel: NDArray[np.float64],
                       views: NDArray[np.bool_]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.uint8]]:
        """Positions withheld as SLID (``settings.SLIDE``): the intersection ``x_in`` (N, 3)
        farther across its rays from its neighbours' rigid map since its seeding frame
        (fitted to the reported ``x``) than ``SLIDE + SLIDE_SCALE`` times the neighbours'
        own held-out residual, pixel equivalents; with ``SLIDE_STICKY`` on every later
        frame too (a slide does not come back)."""
        towards = facing_normals(self.cameras, np.nan_to_num(x_in), views)
        res = rigid_residuals(x_in, x, cov_in, pixel, towards, self.seeded_at, self.history,
                              neighbours=settings.RIGID_NEIGHBOURS, both_frames=settings.RIGID_BOTH_FRAMES,
                              candidates=settings.RIGID_CANDIDATES, stretch=settings.RIGID_STRETCH)
        with np.errstate(invalid="ignore"):
            slid = res.across > settings.SLIDE + settings.SLIDE_SCALE * np.nan_to_num(res.held_out)
        if len(self.slid) < len(x):
            self.slid = np.concatenate([self.slid, np.zeros(len(x) - len(self.slid), bool)])
        if settings.SLIDE_STICKY:
            slid |= self.slid[: len(x)]
            self.slid[: len(x)] |= slid
        slid &= np.isfinite(x).all(axis=1)
        if not slid.any():
            return x, xcov, flags
        x, xcov, flags = x.copy(), xcov.copy(), flags.copy()
        x[slid], xcov[slid], flags[slid] = np.nan, np.nan, TrackFlag.SLID
        return x, xcov, flags

    def _forget(self) -> None:
        """Drops the reported positions of seeding frames no live point was seeded on."""
        live = np.any(np.all(np.isfinite(self.uv), axis=2), axis=1)
        if self.lost is not None:
            since = self.lost.since[: len(live)]
            live[: len(since)] |= since >= 0
        keep = set(np.unique(self.seeded_at[: len(live)][live]).tolist())
        for key in [k for k in self.history if k not in keep]:
            del self.history[key]

    def normals(self, points: NDArray[np.float64], cloud: NDArray[np.float64],
                 seen: NDArray[np.bool_]) -> NDArray[np.float64]:
        """Surface normals at ``points`` for the start shape of wide-baseline matches."""
        towards = facing_normals(self.cameras, points, seen)
        return surface_normals(points, cloud, towards) if settings.FITTED_NORMALS else towards


def _intersections(record: dict[str, NDArray[np.generic]]) -> NDArray[np.float64]:
    """A frame file's intersected positions (its positions, in files without them)."""
    return np.asarray(record["intersections"] if "intersections" in record else record["positions"], dtype=np.float64)


def point_flags(flags2d: NDArray[np.uint8], previous: NDArray[np.float64], traj: NDArray[np.uint8],
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
