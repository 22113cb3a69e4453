"""The frame-to-frame match's failures searched again where their neighbours went (issue 15).

The step predicts each view linearly from its own last two positions: on a swinging limb
the prediction is pixels off (the limb accelerates), and on the first step after seeding
the point has no velocity at all, so a forearm moving 12+ px a frame is looked for where it
was and never found (the textured capture, seed 0: every one of 106 such first steps
lost, 73 of them to low correlation; benches/README.md, branch track13). A limb moves
together, so the views that were matched this frame say where their failed neighbours
went: each failed view is predicted from the median image displacement, in its own
camera, of the views of its nearest points in 3-D (taken in 3-D so that another limb
passing in front in the image lends no motion) and searched again there by the same
step; failures no neighbour can predict are searched in a wide box around their own
prediction, and their finds predict the rest in a last neighbour pass."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from elastocap.cameras import Camera
from elastocap.tracking.depth_weights import DepthEdges, rust_step, track_step_by_depth
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.views import intersect_views

__all__ = ["Research", "drop_breaking_views", "drop_far_views", "neighbour_predictions", "research_failed_views"]

# The frame-to-frame failures searched again (not the border: its box left the image).
RESEARCHED = (TrackFlag.LOW_CORRELATION, TrackFlag.FORWARD_BACKWARD, TrackFlag.MATCH_FAILED)


def neighbour_predictions(last: NDArray[np.float64], now: NDArray[np.float64], confident: NDArray[np.bool_],
                          x_last: NDArray[np.float64], reach: NDArray[np.float64], wanted: NDArray[np.bool_], *,
                          neighbours: int, min_neighbours: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Where the ``wanted`` views (N, C) went, from their neighbours' motion.

    Parameters
    ----------
    last, now : (N, C, 2) float64
        Views on the previous and the current frame, pixels (NaN where none).
    confident : (N, C) bool
        Views whose motion ``now - last`` is trusted (matched this frame).
    x_last : (N, 3) float64
        The points' 3-D positions on the previous frame (world; NaN where unknown): the
        neighbours are the ``neighbours`` nearest in 3-D with a confident view in the same
        camera, within ``reach`` (N,) world units of the point.
    wanted : (N, C) bool
        The views to predict.
    neighbours, min_neighbours : int
        How many neighbours are asked; fewer than ``min_neighbours`` predict nothing.

    Returns
    -------
    prediction : (N, C, 2) float64
        ``last`` plus the neighbours' median displacement; NaN where not predicted.
    spread : (N, C) float64
        The median distance of the neighbours' displacements from that median, pixels
        (how far the neighbourhood's motion is from a translation).
    """
    n, c = confident.shape
    prediction = np.full((n, c, 2), np.nan)
    spread = np.full((n, c), np.nan)
    known = np.isfinite(x_last).all(axis=1)
    motion = now - last
    for k in range(c):
        sources = np.flatnonzero(confident[:, k] & known & np.isfinite(motion[:, k]).all(axis=1))
        targets = np.flatnonzero(wanted[:, k] & known & np.isfinite(last[:, k]).all(axis=1) & np.isfinite(reach))
        if sources.size < min_neighbours or targets.size == 0:
            continue
        m = min(neighbours, sources.size)
        distance, near = cKDTree(x_last[sources]).query(x_last[targets], k=m)
        distance, near = distance.reshape(len(targets), m), near.reshape(len(targets), m)
        # The point itself is never a source (its view failed), so no self-match to drop.
        close = distance <= reach[targets, None]
        d = np.where(close[..., None], motion[sources[near], k], np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            median = np.nanmedian(d, axis=1)
            deviation = np.nanmedian(np.linalg.norm(d - median[:, None], axis=2), axis=1)
        ok = close.sum(axis=1) >= min_neighbours
        prediction[targets[ok], k] = last[targets[ok], k] + median[ok]
        spread[targets[ok], k] = deviation[ok]
    return prediction, spread


class Research(NamedTuple):
    """The step's outputs with the failed views searched again: ``uv`` (N, C, 2),
    ``flags2d`` (N, C), ``cov2d`` (N, C, 2, 2), ``corr`` (N, C); ``found`` (N, C) the
    views found by the search, and ``by_neighbours`` (N, C) those of them found at a
    neighbour prediction (the others in the wide box)."""

    uv: NDArray[np.float64]
    flags2d: NDArray[np.uint8]
    cov2d: NDArray[np.float64]
    corr: NDArray[np.float64]
    found: NDArray[np.bool_]
    by_neighbours: NDArray[np.bool_]


def research_failed_views(previous: list[NDArray[np.float32]], current: list[NDArray[np.float32]],
                          last: NDArray[np.float64], before: NDArray[np.float64], uv: NDArray[np.float64],
                          flags2d: NDArray[np.uint8], cov2d: NDArray[np.float64], corr: NDArray[np.float64],
                          x_last: NDArray[np.float64], reach: NDArray[np.float64], *, size: int, radius: int,
                          wide_radius: int, min_correlation: float, box_correlation: float, forward_backward: float,
                          min_texture: float, max_iterations: int,
                          weights: tuple[list[NDArray[np.float32]], list[NDArray[np.float32]]] | None,
                          neighbours: int, min_neighbours: int, edges: DepthEdges | None = None,
                          edge_width: float = 0.5, wide_correlation: float | None = None,
                          weighted_box: bool = False) -> Research:
    """The views the frame-to-frame step lost to a failed match (``RESEARCHED`` flags in
    ``flags2d``; ``last`` (N, C, 2) held) searched again by the same step
    (``_core.track_step``): first at their neighbours' prediction
    (:func:`neighbour_predictions`, box of ``radius`` plus the neighbours' spread), then
    those without one in a box of ``wide_radius`` around their own linear prediction (from
    ``before``), then the rest at the prediction of the neighbours found so far. A found
    view must reach ``min_correlation`` (the step's own check for the box's peak is
    ``box_correlation``). Inputs are not modified; ``radius`` 0 for ``wide_radius`` skips
    the wide box. With ``edges`` (:func:`elastocap.tracking.depth_weights.depth_edges`)
    templates that straddle a depth edge are matched without the other surface
    (:func:`~elastocap.tracking.depth_weights.track_step_by_depth`, bins of ``edge_width``).
    ``wide_correlation``: the least correlation of a find in the wide box (None:
    ``min_correlation``; a box that wide holds more look-alikes). ``weighted_box``: the box
    search weighs the template as the match does (``_core.track_step``'s option)."""
    uv, flags2d, cov2d, corr = uv.copy(), flags2d.copy(), cov2d.copy(), corr.copy()
    n, c = flags2d.shape
    found = np.zeros((n, c), bool)
    by_neighbours = np.zeros((n, c), bool)
    held = np.isfinite(last).all(axis=2)
    step = rust_step(previous, current)

    def failed() -> NDArray[np.bool_]:
        return held & np.isin(flags2d, RESEARCHED)

    def search(rows: NDArray[np.bool_], centre: NDArray[np.float64], box: int,
               least: float = min_correlation) -> NDArray[np.bool_]:
        # The step predicts 2 last - before: ``before`` set so that it predicts ``centre``.
        start = np.where(rows[..., None], last, np.nan)
        aim = np.where(rows[..., None], 2 * last - centre, np.nan)
        options = dict(size=size, radius=box, min_correlation=box_correlation, forward_backward=forward_backward,
                       min_texture=min_texture, max_iterations=max_iterations, weighted_box=weighted_box)
        if edges is None:
            pos, f2d, cv2d, cr = step(start, aim, weights=weights, **options)
        else:
            pos, f2d, cv2d, cr = track_step_by_depth(step, start, aim, weights, edges, half=size // 2, width=edge_width,
                                                     **options)
        good = rows & (f2d == TrackFlag.TRACKED) & (cr >= least)
        uv[good], cov2d[good], corr[good] = pos[good], cv2d[good], cr[good]
        flags2d[good] = TrackFlag.TRACKED
        found[good] = True
        return good

    def by_neighbour_motion() -> None:
        wanted = failed()
        if not wanted.any():
            return
        confident = flags2d == TrackFlag.TRACKED
        prediction, spread = neighbour_predictions(last, uv, confident, x_last, reach, wanted, neighbours=neighbours,
                                                   min_neighbours=min_neighbours)
        rows = wanted & np.isfinite(prediction[..., 0])
        if not rows.any():
            return
        # One call per box size: the neighbourhood's spread (a rotating limb's
        # displacements differ across it) widens the box, in whole pixels.
        extra = np.ceil(np.nan_to_num(spread, nan=0.0)).astype(int)
        for add in np.unique(extra[rows]):
            these = rows & (extra == add)
            by_neighbours[search(these, prediction, radius + min(int(add), radius))] = True

    by_neighbour_motion()
    if wide_radius > 0:
        rows = failed()
        if rows.any():
            own = np.where(np.isfinite(before).all(axis=2, keepdims=True), 2 * last - before, last)
            search(rows, own, wide_radius, min_correlation if wide_correlation is None else wide_correlation)
        by_neighbour_motion()
    return Research(uv, flags2d, cov2d, corr, found, by_neighbours)


def drop_breaking_views(cameras: Sequence[Camera], uv: NDArray[np.float64], cov2d: NDArray[np.float64],
                        flags2d: NDArray[np.uint8], researched: NDArray[np.bool_], x: NDArray[np.float64],
                        xcov: NDArray[np.float64], used: NDArray[np.bool_], rejected: NDArray[np.bool_], *,
                        max_residual: float,
                        floor: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]:
    """The points whose intersection (``x``, ``xcov``, ``used``, ``rejected`` of
    :func:`elastocap.tracking.views.intersect_views` on ``uv``, ``cov2d``) failed while they
    hold views found by the second search (``researched`` (N, C)) intersected again without
    those views: a blunder beyond the residual bound fails its whole point, and a point the
    step had kept on its other views must not end for a view searched again. The dropped
    views are set to NaN in ``uv`` and ``cov2d`` and flagged EPIPOLAR in ``flags2d`` (in
    place); returns the updated ``x``, ``xcov``, ``used`` and ``rejected``."""
    again = np.asarray(~np.isfinite(x).all(axis=1) & (researched & np.isfinite(uv[..., 0])).any(axis=1), dtype=bool)
    x, xcov, used, rejected = x.copy(), xcov.copy(), used.copy(), rejected.copy()
    if not again.any():
        return x, xcov, used, rejected
    drop = researched & again[:, None]
    uv[drop], cov2d[drop] = np.nan, np.nan
    flags2d[drop] = TrackFlag.EPIPOLAR
    rx, rcov, rused, rrejected = intersect_views(cameras, uv[again], cov2d[again], max_residual=max_residual, floor=floor)
    x[again], xcov[again], used[again], rejected[again] = rx, rcov, rused, rrejected | drop[again]
    return x, xcov, used, rejected


def drop_far_views(cameras: Sequence[Camera], uv: NDArray[np.float64], cov2d: NDArray[np.float64],
                   flags2d: NDArray[np.uint8], suspect: NDArray[np.bool_], x: NDArray[np.float64],
                   xcov: NDArray[np.float64], used: NDArray[np.bool_], rejected: NDArray[np.bool_], *, tolerance: float,
                   max_residual: float,
                   floor: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]:
    """The ``suspect`` views (N, C; e.g. found in the second search's wide box) that the
    intersection ``x`` used but that lie farther than ``tolerance`` pixels from its
    projection dropped (NaN in ``uv`` and ``cov2d``, flagged EPIPOLAR, in place), and their
    points intersected again from the rest: a look-alike found in a wide box and kept by
    the intersection's looser ``max_residual`` pulls its point off the surface. Returns the
    updated ``x``, ``xcov``, ``used`` and ``rejected``."""
    n, c = suspect.shape
    far = np.zeros((n, c), bool)
    rows = np.flatnonzero((suspect & used).any(axis=1) & np.isfinite(x).all(axis=1))
    for k, cam in enumerate(cameras):
        these = rows[(suspect & used)[rows, k]]
        if these.size:
            far[these, k] = np.linalg.norm(cam.project(x[these])[0] - uv[these, k], axis=1) > tolerance
    x, xcov, used, rejected = x.copy(), xcov.copy(), used.copy(), rejected.copy()
    again = far.any(axis=1)
    if not again.any():
        return x, xcov, used, rejected
    uv[far], cov2d[far] = np.nan, np.nan
    flags2d[far] = TrackFlag.EPIPOLAR
    rx, rcov, rused, rrejected = intersect_views(cameras, uv[again], cov2d[again], max_residual=max_residual, floor=floor)
    x[again], xcov[again], used[again], rejected[again] = rx, rcov, rused, rrejected | far[again]
    return x, xcov, used, rejected
