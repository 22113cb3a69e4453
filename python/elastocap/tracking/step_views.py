"""The tracker's 2-D stage of a frame (issue 15, SPEC 7): every camera's views moved
from the previous frame (:func:`step_views`: the Rust step, templates weighted across depth
edges, the failed views searched again around their neighbours, the young views searched
coarse to fine), then corrected (:func:`correct_views`: by their anchors, the lost ones
rescued from them, and re-tied to one another across the cameras,
:mod:`elastocap.tracking.retie`)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from elastocap.tracking import settings
from elastocap.tracking.depth_weights import depth_edges, rust_step, track_step_by_depth
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.prediction import research_failed_views
from elastocap.tracking.pyramid_search import check_options as check_pyramid_options
from elastocap.tracking.pyramid_search import pyramid_search
from elastocap.tracking.retie import retie_views

if TYPE_CHECKING:
    from elastocap.tracking.step import FrameTracker

__all__ = ["ViewStep", "correct_views", "step_views"]


@dataclass(frozen=True)
class ViewStep:
    """One frame's views of the tracker's N points in its C cameras."""

    uv: NDArray[np.float64]
    """(N, C, 2) image positions, px; NaN where the view is not held."""
    flags2d: NDArray[np.uint8]
    """(N, C) :class:`~elastocap.tracking.flags.TrackFlag` per view (0 where tracked)."""
    cov2d: NDArray[np.float64]
    """(N, C, 2, 2) the match's covariance of ``uv``, px^2."""
    corr: NDArray[np.float64]
    """(N, C) the match's normalised cross-correlation."""
    researched: NDArray[np.bool_]
    """(N, C) found by a search wider than the step's (a blunder there must not end its point)."""
    wide: NDArray[np.bool_]
    """(N, C) found by the second search's wide box alone (held to a tighter residual)."""
    shift: NDArray[np.float64]
    """(N, C) how far the re-tie moved each view, px (NaN: not re-tied)."""

    @classmethod
    def untracked(cls, n: int, c: int) -> ViewStep:
        """No view held: a first frame, or nothing tracked yet."""
        return cls(uv=np.full((n, c, 2), np.nan), flags2d=np.full((n, c), TrackFlag.NOT_SEEDED, np.uint8),
                   cov2d=np.full((n, c, 2, 2), np.nan), corr=np.full((n, c), np.nan),
                   researched=np.zeros((n, c), bool), wide=np.zeros((n, c), bool), shift=np.full((n, c), np.nan))


def step_views(tracker: FrameTracker, grey: list[NDArray[np.float32]], masks: list[NDArray[np.bool_]],
               weights: list[NDArray[np.float32]] | None, before: NDArray[np.float64]) -> ViewStep:
    """The held views of the frame before moved to this frame's images ``grey`` (C of (H, W)
    float32); ``before`` (N, C, 2) the views' positions the Rust step predicts from
    (:meth:`FrameTracker._before`), ``weights`` the template weights of this frame's masks."""
    assert tracker.grey is not None, "the first frame has no step"
    n, c = tracker.uv.shape[:2]
    researched = np.zeros((n, c), bool)
    wide = np.zeros((n, c), bool)
    step = rust_step(tracker.grey, grey)
    pair = None if weights is None or tracker.weights is None else (tracker.weights, weights)
    options = dict(size=tracker.size, radius=tracker.radius,
                   min_correlation=min(tracker.min_correlation, settings.BOX_CORRELATION),
                   forward_backward=tracker.o["forward_backward"], min_texture=tracker.keep_texture,
                   max_iterations=settings.STEP_ITERATIONS, weighted_box=settings.WEIGHTED_BOX)
    edges = None
    if settings.DEPTH_WEIGHTS and tracker.masks is not None:
        # Templates that straddle a depth edge matched without the other surface.
        edges = depth_edges(tracker.cameras, tracker.uv, tracker.x_last, tracker.x_before, tracker.masks, masks,
                            reach=settings.DEPTH_WEIGHTS_REACH, tolerance=settings.DEPTH_WEIGHTS_TOLERANCE,
                            band=settings.DEPTH_WEIGHTS_BAND, current=settings.DEPTH_WEIGHTS_CURRENT)
        uv, flags2d, cov2d, corr = track_step_by_depth(step, tracker.uv, before, pair, edges, half=tracker.size // 2,
                                                       width=settings.DEPTH_WEIGHTS_BIN, **options)
    else:
        uv, flags2d, cov2d, corr = step(tracker.uv, before, weights=pair, **options)
    # The box search only has to find the start (it does not model rotation or
    # scale); the least-squares match, which does, must reach the threshold.
    weak = (flags2d == TrackFlag.TRACKED) & ~(corr >= tracker.min_correlation)
    flags2d[weak] = TrackFlag.LOW_CORRELATION
    uv = np.where(weak[..., None], np.nan, uv)
    if settings.RESEARCH:
        # The failed views searched again where their neighbours went (a fast
        # limb's, and a new point's, which has no velocity to predict from).
        reach = settings.RESEARCH_REACH * tracker.pixel_last()
        found = research_failed_views(
            tracker.grey, grey, tracker.uv, before, uv, flags2d, cov2d, corr, tracker.x_last, reach, size=settings.RESEARCH_SIZE or tracker.size,
            radius=tracker.radius, wide_radius=settings.RESEARCH_WIDE_RADIUS, min_correlation=tracker.min_correlation,
            box_correlation=min(tracker.min_correlation, settings.BOX_CORRELATION),
            forward_backward=tracker.o["forward_backward"], min_texture=tracker.keep_texture,
            max_iterations=settings.STEP_ITERATIONS,
            weights=None if weights is None or tracker.weights is None else (tracker.weights, weights),
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
        young = np.isfinite(tracker.uv[..., 0]) & ~np.isfinite(tracker.uv_last[..., 0])
        pool_reach = settings.PYRAMID_POOL_REACH * tracker.pixel_last()
        coarse = pyramid_search(
            tracker.grey, grey, tracker.uv, before, young, uv, flags2d, cov2d, corr, level=settings.PYRAMID_LEVEL,
            radius=settings.PYRAMID_RADIUS, coarse_size=settings.PYRAMID_SIZE,
            coarse_correlation=settings.PYRAMID_CORRELATION,
            exclusion=settings.PYRAMID_PEAK_EXCLUSION, margin=settings.PYRAMID_PEAK_MARGIN, size=tracker.size,
            fine_radius=tracker.radius, min_correlation=tracker.min_correlation,
            box_correlation=min(tracker.min_correlation, settings.BOX_CORRELATION),
            forward_backward=tracker.o["forward_backward"], min_texture=tracker.keep_texture,
            max_iterations=settings.STEP_ITERATIONS, weights=pair, weighted_box=settings.WEIGHTED_BOX,
            pool=settings.PYRAMID_POOL, x_last=tracker.x_last, reach=pool_reach, pyramids=tracker.pyramids)
        uv, flags2d, cov2d, corr = coarse.uv, coarse.flags2d, coarse.cov2d, coarse.corr
        # A blunder found this wide must not end its point (as the second search's).
        researched = researched | coarse.found
    return ViewStep(uv=uv, flags2d=flags2d, cov2d=cov2d, corr=corr, researched=researched, wide=wide,
                    shift=np.full((n, c), np.nan))


def correct_views(tracker: FrameTracker, frame: int, grey: list[NDArray[np.float32]],
                  weights: list[NDArray[np.float32]] | None, before: NDArray[np.float64], views: ViewStep) -> ViewStep:
    """The stepped ``views`` corrected by their anchors (and the lost ones rescued from them)
    and re-tied across the cameras; the tracker's anchors are cut again where stale."""
    n = len(views.uv)
    uv, flags2d, cov2d, corr, shift = views.uv, views.flags2d, views.cov2d, views.corr, views.shift
    if tracker.anchors is not None:
        uv, stale = tracker.anchors.correct(grey, uv, min_correlation=tracker.min_correlation, reach=settings.ANCHOR_REACH,
                                            min_texture=tracker.keep_texture)
        tracker.anchors.cut(grey, uv, stale, frame, weights=weights)
        if tracker.o["rescue"]:
            # Views lost by the frame-to-frame match (not at the border) found again
            # from their anchor at the linear prediction.
            lost = (np.isfinite(tracker.uv[..., 0]) & ~np.isfinite(uv[..., 0])
                    & np.isin(flags2d, settings.RESCUED))
            start = np.where(np.isfinite(before), 2 * tracker.uv - before, tracker.uv)
            rescued, rcov = tracker.anchors.rescue(grey, start, lost, min_correlation=tracker.min_correlation,
                                                   reach=settings.RESCUE_REACH, min_texture=tracker.keep_texture)
            back = np.isfinite(rescued[..., 0])
            uv = np.where(back[..., None], rescued, uv)
            cov2d = np.where(back[..., None, None], rcov, cov2d)
            flags2d[back] = TrackFlag.TRACKED
    if settings.RETIE:
        # The held views' disparity measured afresh (their chains drift apart).
        preference = np.nan_to_num(corr, nan=0.0)
        if settings.RETIE_REFERENCE == "anchor" and tracker.anchors is not None:
            # The view whose anchor is oldest (cut again fewest times: drifted
            # least), the correlation breaking ties. Frames apart, either way: a
            # backward pass (tracking/backward.py) steps to earlier frames.
            age = np.where(tracker.anchors.held[:n], np.abs(frame - tracker.anchors.frame[:n]), 0)
            preference = age / (frame + 1.0) + 1e-3 * preference
        uv, cov2d, removed, shift = retie_views(grey, uv, cov2d, preference, size=tracker.size, min_correlation=tracker.min_correlation,
                                         tolerance=settings.RETIE_TOLERANCE, drop=settings.RETIE_DROP,
                                         drop_failed=settings.RETIE_DROP_FAILED,
                                         min_texture=tracker.keep_texture, weights=weights)
        flags2d[removed] = TrackFlag.EPIPOLAR
    return replace(views, uv=uv, flags2d=flags2d, cov2d=cov2d, shift=shift)
