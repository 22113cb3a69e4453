"""A young view's lost first step searched coarse to fine (issue 15).

A point seeded after frame 0 has no velocity: its first step is looked for where it was
(or where its neighbours' rigid motion carries it, when they have one). On a swinging limb
all the points are new together and move 35-47 px in that step (benches/README.md,
"Session 25, lead"), far beyond the step's 6 px box, so 87-97% of the fast limbs' late
tracks live one frame. Here the views that the frame-to-frame step lost on their first
step (no position on the frame before) are searched again on an image pyramid: the box
search's correlation (:func:`elastocap._core.track_ncc_at`, the step's box search at every
integer shift) on both grey images reduced ``level`` times by ``cv2.pyrDown``, positions
scaled by ``2 ** -level``, in a box of ``radius`` coarse pixels (15 at level 2 reaches 60
px); then the full-resolution Rust step (:func:`elastocap._core.track_step`: box search,
least-squares match, forward-backward check) from the coarse peak as its prediction, with
the tracker's own box, correlation and forward-backward checks. The coarse level runs no
least-squares match: on a limb 4-8 coarse pixels wide it fails to converge on two views
in three (tuning fit seed 14, frames 1-5), while its integer peak is within the fine box.

A box that wide holds look-alikes (a repeated print, the other leg): the coarse find is
kept only if its correlation peak stands out, i.e. every other local maximum of the coarse
correlation surface farther than ``exclusion`` coarse pixels from the find is at least
``margin`` lower (:func:`coarse_peaks`). The tracker's later checks (the intersection's
residual across the cameras, the trajectory filter's uniformity against the 3-D
neighbours) apply to the finds as to any view."""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from elastocap import _core
from elastocap.tracking.depth_weights import rust_step
from elastocap.tracking.flags import TrackFlag

__all__ = ["PyramidFinds", "Pyramids", "box_scores", "box_scores_cameras", "check_options", "coarse_peaks", "pooled", "pyramid",
           "pyramid_search"]

# The frame-to-frame failures searched again (not the border: its box left the image).
SEARCHED = (TrackFlag.LOW_CORRELATION, TrackFlag.FORWARD_BACKWARD, TrackFlag.MATCH_FAILED)


def check_options(*, level: int, radius: int, size: int, correlation: float, margin: float, exclusion: float,
                  pool: int = 1, reach: float = 30.0) -> None:
    """Refuses settings the search cannot run with (ValueError): ``level`` 1 to 4,
    ``radius`` 1 to 64 coarse pixels, ``size`` an odd 3 to 31, ``correlation`` in [-1, 1],
    ``margin`` in [0, 2), ``exclusion`` at least 1 and less than ``radius``, ``pool`` a
    positive integer, ``reach`` positive."""
    if not (isinstance(level, (int, np.integer)) and 1 <= level <= 4):
        raise ValueError(f"PYRAMID_LEVEL must be an integer from 1 to 4, not {level!r}")
    if not (isinstance(radius, (int, np.integer)) and 1 <= radius <= 64):
        raise ValueError(f"PYRAMID_RADIUS must be an integer from 1 to 64 coarse pixels, not {radius!r}")
    if not (isinstance(size, (int, np.integer)) and 3 <= size <= 31 and size % 2 == 1):
        raise ValueError(f"PYRAMID_SIZE must be an odd integer from 3 to 31, not {size!r}")
    if not (isinstance(pool, (int, np.integer)) and pool >= 1):
        raise ValueError(f"PYRAMID_POOL must be a positive integer, not {pool!r}")
    if not (np.isfinite(reach) and reach > 0):
        raise ValueError(f"PYRAMID_POOL_REACH must be positive and finite, not {reach!r}")
    if not (np.isfinite(correlation) and -1.0 <= correlation <= 1.0):
        raise ValueError(f"PYRAMID_CORRELATION must be in [-1, 1], not {correlation!r}")
    if not (np.isfinite(margin) and 0.0 <= margin < 2.0):
        raise ValueError(f"PYRAMID_PEAK_MARGIN must be in [0, 2), not {margin!r}")
    if not (np.isfinite(exclusion) and 1.0 <= exclusion < radius):
        raise ValueError(f"PYRAMID_PEAK_EXCLUSION must be at least 1 and below the radius, not {exclusion!r}")


def pyramid(images: list[NDArray[np.float32]], level: int) -> list[NDArray[np.float32]]:
    """Each (H, W) float32 image reduced ``level`` times by ``cv2.pyrDown`` (Gaussian blur,
    every second pixel): coarse pixel ``p`` is centred on full-resolution pixel
    ``p * 2 ** level``."""
    out = []
    for image in images:
        reduced: NDArray[np.floating] = image
        for _ in range(level):
            reduced = np.asarray(cv2.pyrDown(reduced), dtype=np.float32)
        out.append(np.ascontiguousarray(reduced, dtype=np.float32))
    return out


class Pyramids:
    """The last two frames' reduced images (:func:`pyramid`), kept so that a frame's
    current images, reduced for its search, serve the next frame as its previous ones
    (the tracker reduces each frame's images once, not twice). An entry is found by the
    identity of the image arrays (held here, so their ids are not reused) and the level."""

    def __init__(self) -> None:
        self._kept: list[tuple[list[NDArray[np.float32]], int, list[NDArray[np.float32]]]] = []

    def get(self, images: list[NDArray[np.float32]], level: int) -> list[NDArray[np.float32]]:
        """:func:`pyramid` of ``images`` at ``level``, computed once per list of arrays."""
        for kept, at, reduced in self._kept:
            if at == level and len(kept) == len(images) and all(a is b for a, b in zip(kept, images)):
                return reduced
        reduced = pyramid(images, level)
        self._kept = [*self._kept[-1:], (list(images), level, reduced)]
        return reduced


def _shifts(radius: int) -> NDArray[np.float64]:
    """(K, 2) the integer shifts of a box of half-side ``radius``, row-major (shift down,
    then right), as ``(du, dv)``."""
    off = np.arange(-radius, radius + 1, dtype=np.float64)
    dv, du = np.meshgrid(off, off, indexing="ij")
    return np.stack([du.ravel(), dv.ravel()], axis=1)


def box_scores_cameras(templates: list[NDArray[np.float32]], points: NDArray[np.float64],
                       searches: list[NDArray[np.float32]], centres: NDArray[np.float64], cameras: NDArray[np.int64], *,
                       size: int, radius: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`box_scores` of rows of several cameras in one core call (one parallel pass,
    :func:`elastocap._core.track_ncc_at_cameras`): row ``i`` is searched from
    ``templates[cameras[i]]`` into ``searches[cameras[i]]``; the same positions (M, K, 2)
    and correlations (M, K), row for row, as :func:`box_scores` of the row's camera."""
    shifts = _shifts(radius)
    candidates = np.ascontiguousarray(np.rint(centres)[:, None, :] + shifts[None])
    if len(points) == 0:
        return candidates, np.zeros((0, len(shifts)))
    scores = _core.track_ncc_at_cameras(templates, np.ascontiguousarray(points), searches, candidates,
                                        np.ascontiguousarray(cameras, dtype=np.int64), size=size)
    return candidates, np.nan_to_num(scores, nan=-np.inf)


def box_scores(template: NDArray[np.float32], points: NDArray[np.float64], search: NDArray[np.float32],
               centres: NDArray[np.float64], *, size: int,
               radius: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The box search's correlation (:func:`elastocap._core.track_ncc_at`) of the templates
    (side ``size``) around ``points`` (M, 2) in ``template`` at every integer shift up to
    ``radius`` around the rounded ``centres`` (M, 2) in ``search``: the shifts' positions
    (M, K, 2) and correlations (M, K), K = (2 radius + 1)^2, row-major (shift down, then
    right); -inf where a patch leaves its image or is flat."""
    shifts = _shifts(radius)
    candidates = np.ascontiguousarray(np.rint(centres)[:, None, :] + shifts[None])
    if len(points) == 0:
        return candidates, np.zeros((0, len(shifts)))
    scores = _core.track_ncc_at(template, np.ascontiguousarray(points), search, candidates, size=size)
    return candidates, np.nan_to_num(scores, nan=-np.inf)


def pooled(scores: NDArray[np.float64], x: NDArray[np.float64], pool: int, reach: NDArray[np.float64]) -> NDArray[np.float64]:
    """(M, K) each view's box correlations (``scores`` (M, K), every view's box centred on
    its own prediction) averaged with those of the views of its ``pool - 1`` nearest points
    in 3-D (``x`` (M, 3), within ``reach`` (M,) world units): a limb moves together, so its
    true shift adds up across the neighbourhood while each view's look-alikes (the
    background left behind, a repeated print) fall at different shifts. ``pool`` 1 or a
    point without neighbours: its own scores."""
    m = len(scores)
    if pool <= 1 or m < 2:
        return scores
    known = np.isfinite(x).all(axis=1)
    out = scores.copy()
    rows = np.flatnonzero(known)
    if rows.size < 2:
        return out
    k = min(pool, rows.size)
    distance, near = cKDTree(x[rows]).query(x[rows], k=k)
    close = distance <= np.nan_to_num(reach[rows], nan=0.0)[:, None]
    # -inf (a patch off the image) counts as no correlation in the mean.
    values = np.where(np.isfinite(scores), scores, 0.0)[rows[near]]
    weight = close[..., None] & np.isfinite(scores)[rows[near]]
    total = (values * weight).sum(axis=1)
    count = weight.sum(axis=1)
    out[rows] = np.where(count > 0, total / np.maximum(count, 1), -np.inf)
    return out


def coarse_peaks(candidates: NDArray[np.float64], scores: NDArray[np.float64], *, radius: int, exclusion: float,
                 margin: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """The best shift of each box and whether its peak is unique.

    Parameters
    ----------
    candidates, scores : (M, K, 2), (M, K) float64
        The shifts' positions and correlations (:func:`box_scores`), K = (2 radius + 1)^2.
    radius : int
        The box's half-side, pixels.
    exclusion, margin : float
        The peak is unique when every other local maximum (3 x 3) of the correlation farther
        than ``exclusion`` pixels from it is lower by at least ``margin``.

    Returns
    -------
    find : (M, 2) float64
        The best shift's position, pixels (NaN where none).
    score : (M,) float64
        Its correlation (-inf where every shift's is unknown).
    unique : (M,) bool
    """
    m = len(scores)
    if m == 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0, bool)
    side = 2 * radius + 1
    best_at = scores.argmax(axis=1)
    score = scores[np.arange(m), best_at]
    find = np.where(np.isfinite(score)[:, None], candidates[np.arange(m), best_at], np.nan)
    grid = scores.reshape(m, side, side)
    near = (np.hypot(candidates[..., 0] - find[:, None, 0], candidates[..., 1] - find[:, None, 1]) <= exclusion)
    near = near.reshape(m, side, side)
    # Local maxima: not below any of the 8 neighbours (the box's edge counts as -inf).
    padded = np.pad(grid, ((0, 0), (1, 1), (1, 1)), constant_values=-np.inf)
    peak = np.ones(grid.shape, bool)
    for a in (-1, 0, 1):
        for b in (-1, 0, 1):
            if a or b:
                peak &= grid >= padded[:, 1 + a: 1 + a + side, 1 + b: 1 + b + side]
    other = np.where(peak & ~near & np.isfinite(grid), grid, -np.inf).max(axis=(1, 2))
    return find, score, np.isfinite(score) & (other <= score - margin)


class PyramidFinds(NamedTuple):
    """The step's outputs with the young views searched coarse to fine: ``uv`` (N, C, 2),
    ``flags2d`` (N, C), ``cov2d`` (N, C, 2, 2), ``corr`` (N, C); ``found`` (N, C) the views
    found, ``searched`` (N, C) those searched, ``ambiguous`` (N, C) the coarse finds refused
    by the peak guard."""

    uv: NDArray[np.float64]
    flags2d: NDArray[np.uint8]
    cov2d: NDArray[np.float64]
    corr: NDArray[np.float64]
    found: NDArray[np.bool_]
    searched: NDArray[np.bool_]
    ambiguous: NDArray[np.bool_]


def pyramid_search(previous: list[NDArray[np.float32]], current: list[NDArray[np.float32]], last: NDArray[np.float64],
                   before: NDArray[np.float64], young: NDArray[np.bool_], uv: NDArray[np.float64],
                   flags2d: NDArray[np.uint8], cov2d: NDArray[np.float64], corr: NDArray[np.float64], *,
                   level: int, radius: int, coarse_size: int, coarse_correlation: float, exclusion: float, margin: float,
                   size: int,
                   fine_radius: int, min_correlation: float, box_correlation: float, forward_backward: float,
                   min_texture: float, max_iterations: int,
                   weights: tuple[list[NDArray[np.float32]], list[NDArray[np.float32]]] | None,
                   weighted_box: bool = False, pool: int = 1, x_last: NDArray[np.float64] | None = None,
                   reach: NDArray[np.float64] | None = None, pyramids: Pyramids | None = None) -> PyramidFinds:
    """The ``young`` views (N, C) that the step lost to a failed match (``SEARCHED`` flags
    in ``flags2d``) searched coarse to fine.

    Parameters
    ----------
    previous, current : C lists of (H, W) float32
        The grey images of the previous and the current frame.
    last, before : (N, C, 2) float64
        The views on the previous frame and what the step read as the frame before (it
        predicts ``2 last - before``, ``last`` where ``before`` is NaN), pixels.
    young : (N, C) bool
        The views that may be searched (the tracker's: no position on the frame before).
    uv, flags2d, cov2d, corr
        The step's outputs (N, C, 2), (N, C), (N, C, 2, 2), (N, C); not modified.
    level, radius, coarse_size : int
        Pyramid level (pixels ``2 ** level`` times larger), box half-side and template side
        there, coarse pixels.
    coarse_correlation : float
        The least correlation of the coarse peak.
    exclusion, margin : float
        The peak guard (:func:`coarse_peaks`), coarse pixels and correlation.
    size, fine_radius, min_correlation, box_correlation, forward_backward, min_texture, max_iterations
        The tracker's step at full resolution: template side and box half-side, pixels, the
        least correlation of the match and of the box's peak, the forward-backward miss,
        pixels, the least texture, the match's iterations.
    weights : (previous, current) C lists of (H, W) float32, or None
        The full-resolution step's template weights (the masks; the coarse correlation is
        unweighted).
    weighted_box : bool
        The box search weighs the template as the match does.
    pool, x_last, reach
        The coarse correlations pooled over the views of each point's ``pool`` nearest
        searched points in 3-D (:func:`pooled`; ``x_last`` (N, 3) the points on the previous
        frame, ``reach`` (N,) world units); 1: each view's own.
    pyramids : Pyramids, optional
        Where the reduced images are kept from frame to frame (the same images either way).

    Returns
    -------
    PyramidFinds
    """
    uv, flags2d, cov2d, corr = uv.copy(), flags2d.copy(), cov2d.copy(), corr.copy()
    n, c = flags2d.shape
    rows = young & np.isfinite(last).all(axis=2) & np.isin(flags2d, SEARCHED)
    nothing = np.zeros((n, c), bool)
    if not rows.any():
        return PyramidFinds(uv, flags2d, cov2d, corr, nothing, rows, nothing.copy())
    scale = float(2 ** level)
    if pyramids is None:
        coarse_previous, coarse_current = pyramid(previous, level), pyramid(current, level)
    else:
        coarse_previous, coarse_current = pyramids.get(previous, level), pyramids.get(current, level)
    # pyrDown centres coarse pixel p on full pixel 2p: positions divide by the scale.
    ahead = np.where(np.isfinite(before), 2 * last - before, last) / scale
    hit = np.zeros((n, c), bool)
    ambiguous = np.zeros((n, c), bool)
    find = np.full((n, c, 2), np.nan)
    # Every camera's boxes in one core call; the pooling is per camera (the neighbours'
    # views in the same image), the peaks per row.
    row, cam = np.nonzero(rows.T)[::-1]
    candidates, scores = box_scores_cameras(coarse_previous, last[row, cam] / scale, coarse_current, ahead[row, cam],
                                            cam, size=coarse_size, radius=radius)
    if pool > 1 and x_last is not None and reach is not None:
        # The shifts relative to each box's centre are the same for every view: the
        # neighbours' surfaces add up shift by shift.
        for k in np.unique(cam):
            mine = cam == k
            scores[mine] = pooled(scores[mine], x_last[row[mine]], pool, reach[row[mine]])
    at, score, unique = coarse_peaks(candidates, scores, radius=radius, exclusion=exclusion, margin=margin)
    strong = score >= coarse_correlation
    find[row, cam] = at
    hit[row, cam] = strong & unique
    ambiguous[row, cam] = strong & ~unique
    if not hit.any():
        return PyramidFinds(uv, flags2d, cov2d, corr, nothing, rows, ambiguous)
    # The full-resolution step predicts the coarse find: ``before`` set to 2 last - find.
    fine_start = np.where(hit[..., None], last, np.nan)
    fine_aim = np.where(hit[..., None], 2 * last - find * scale, np.nan)
    fine = rust_step(previous, current)
    fpos, ff2d, fcov, fcr = fine(fine_start, fine_aim, weights=weights, size=size, radius=fine_radius,
                                 min_correlation=box_correlation, forward_backward=forward_backward,
                                 min_texture=min_texture, max_iterations=max_iterations, weighted_box=weighted_box)
    good = hit & (ff2d == TrackFlag.TRACKED) & (fcr >= min_correlation)
    uv[good], cov2d[good], corr[good] = fpos[good], fcov[good], fcr[good]
    flags2d[good] = TrackFlag.TRACKED
    return PyramidFinds(uv, flags2d, cov2d, corr, good, rows, ambiguous)
