"""A young view's lost first step searched coarse to fine (issue 15).

A point seeded after frame 0 has no velocity: its first step is looked for where it was
(or where its neighbours' rigid motion carries it, when they have one). On a swinging limb
all the points are new together and move 35-47 px in that step (benches/README.md,
"Session 25, lead"), far beyond the step's 6 px box, so 87-97% of the fast limbs' late
tracks live one frame. Here the views that the frame-to-frame step lost on their first
step (no position on the frame before) are searched again on an image pyramid: the same
Rust step (:func:`elastocap._core.track_step`: box search, least-squares match,
forward-backward check) on both grey images reduced ``level`` times by ``cv2.pyrDown``,
positions scaled by ``2 ** -level``, with a box of ``radius`` coarse pixels (15 at level 2
reaches 60 px); then the full-resolution step from the coarse find as its prediction, with
the tracker's own box, correlation and forward-backward checks.

A box that wide holds look-alikes (a repeated print, the other leg): the coarse find is
kept only if its correlation peak stands out, i.e. every other local maximum of the coarse
correlation surface farther than ``exclusion`` coarse pixels from the find is at least
``margin`` lower (:func:`unique_peaks`). The tracker's later checks (the intersection's
residual across the cameras, the trajectory filter's uniformity against the 3-D
neighbours) apply to the finds as to any view."""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap import _core
from elastocap.tracking.depth_weights import rust_step
from elastocap.tracking.flags import TrackFlag

__all__ = ["PyramidFinds", "check_options", "pyramid", "pyramid_search", "unique_peaks"]

# The frame-to-frame failures searched again (not the border: its box left the image).
SEARCHED = (TrackFlag.LOW_CORRELATION, TrackFlag.FORWARD_BACKWARD, TrackFlag.MATCH_FAILED)


def check_options(*, level: int, radius: int, size: int, margin: float, exclusion: float) -> None:
    """Refuses settings the search cannot run with (ValueError): ``level`` 1 to 4,
    ``radius`` 1 to 64 coarse pixels, ``size`` an odd 3 to 31, ``margin`` in [0, 2),
    ``exclusion`` at least 1 and less than ``radius``."""
    if not (isinstance(level, (int, np.integer)) and 1 <= level <= 4):
        raise ValueError(f"PYRAMID_LEVEL must be an integer from 1 to 4, not {level!r}")
    if not (isinstance(radius, (int, np.integer)) and 1 <= radius <= 64):
        raise ValueError(f"PYRAMID_RADIUS must be an integer from 1 to 64 coarse pixels, not {radius!r}")
    if not (isinstance(size, (int, np.integer)) and 3 <= size <= 31 and size % 2 == 1):
        raise ValueError(f"PYRAMID_SIZE must be an odd integer from 3 to 31, not {size!r}")
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
        reduced = image
        for _ in range(level):
            reduced = cv2.pyrDown(reduced)
        out.append(np.ascontiguousarray(reduced, dtype=np.float32))
    return out


def unique_peaks(template: NDArray[np.float32], points: NDArray[np.float64], search: NDArray[np.float32],
                 centres: NDArray[np.float64], finds: NDArray[np.float64], *, size: int, radius: int,
                 exclusion: float, margin: float) -> NDArray[np.bool_]:
    """(M,) whether each find's correlation peak is unique in its box.

    Parameters
    ----------
    template, search : (H, W) float32
        The (coarse) images the templates are cut from and searched in.
    points : (M, 2) float64
        The templates' centres in ``template``, pixels.
    centres : (M, 2) float64
        The boxes' centres in ``search`` (the predictions), pixels.
    finds : (M, 2) float64
        The box search's finds in ``search``, pixels.
    size, radius : int
        Template side and box half-side, pixels.
    exclusion, margin : float
        A find is unique when every local maximum (3 x 3) of the correlation over the box's
        integer shifts farther than ``exclusion`` pixels from it is lower than the best
        correlation within ``exclusion`` of it by at least ``margin``.

    Returns
    -------
    (M,) bool; False where the template is flat or leaves its image.
    """
    m = len(points)
    if m == 0:
        return np.zeros(0, bool)
    side = 2 * radius + 1
    off = np.arange(-radius, radius + 1, dtype=np.float64)
    dv, du = np.meshgrid(off, off, indexing="ij")
    base = np.rint(centres)
    candidates = np.ascontiguousarray(base[:, None, :] + np.stack([du.ravel(), dv.ravel()], axis=1)[None])
    scores = _core.track_ncc_at(template, np.ascontiguousarray(points), search, candidates, size=size)
    grid = np.nan_to_num(scores.reshape(m, side, side), nan=-np.inf)
    near = np.hypot(candidates[..., 0] - finds[:, None, 0], candidates[..., 1] - finds[:, None, 1]).reshape(m, side, side) <= exclusion
    best = np.where(near, grid, -np.inf).max(axis=(1, 2))
    # Local maxima: not below any of the 8 neighbours (the box's edge counts as -inf).
    padded = np.pad(grid, ((0, 0), (1, 1), (1, 1)), constant_values=-np.inf)
    peak = np.ones(grid.shape, bool)
    for a in (-1, 0, 1):
        for b in (-1, 0, 1):
            if a or b:
                peak &= grid >= padded[:, 1 + a: 1 + a + side, 1 + b: 1 + b + side]
    other = np.where(peak & ~near & np.isfinite(grid), grid, -np.inf).max(axis=(1, 2))
    return np.isfinite(best) & (other <= best - margin)


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
                   level: int, radius: int, coarse_size: int, exclusion: float, margin: float, size: int,
                   fine_radius: int, min_correlation: float, box_correlation: float, forward_backward: float,
                   min_texture: float, max_iterations: int,
                   weights: tuple[list[NDArray[np.float32]], list[NDArray[np.float32]]] | None,
                   weighted_box: bool = False) -> PyramidFinds:
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
    exclusion, margin : float
        The peak guard (:func:`unique_peaks`), coarse pixels and correlation.
    size, fine_radius, min_correlation, box_correlation, forward_backward, min_texture, max_iterations
        The tracker's step: template side and box half-side at full resolution, pixels, the
        least correlation of the match and of the box's peak, the forward-backward miss,
        pixels (at the coarse level: coarse pixels), the least texture, the match's
        iterations.
    weights : (previous, current) C lists of (H, W) float32, or None
        The template weights (the masks), reduced with the images for the coarse step.
    weighted_box : bool
        The box search weighs the template as the match does.

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
    coarse_previous, coarse_current = pyramid(previous, level), pyramid(current, level)
    coarse_weights = None if weights is None else (pyramid(weights[0], level), pyramid(weights[1], level))
    # pyrDown centres coarse pixel p on full pixel 2p: positions divide by the scale.
    start = np.where(rows[..., None], last / scale, np.nan)
    aim = np.where(rows[..., None] & np.isfinite(before), before / scale, np.nan)
    coarse = rust_step(coarse_previous, coarse_current)
    pos, f2d, _, cr = coarse(start, aim, weights=coarse_weights, size=coarse_size, radius=radius,
                             min_correlation=box_correlation, forward_backward=forward_backward,
                             min_texture=min_texture, max_iterations=max_iterations, weighted_box=weighted_box)
    hit = rows & (f2d == TrackFlag.TRACKED) & np.isfinite(pos).all(axis=2)
    ambiguous = np.zeros((n, c), bool)
    centre = np.where(np.isfinite(aim), 2 * start - aim, start)
    for k in range(c):
        these = np.flatnonzero(hit[:, k])
        if these.size:
            unique = unique_peaks(coarse_previous[k], start[these, k], coarse_current[k], centre[these, k], pos[these, k],
                                  size=coarse_size, radius=radius, exclusion=exclusion, margin=margin)
            ambiguous[these[~unique], k] = True
    hit &= ~ambiguous
    if not hit.any():
        return PyramidFinds(uv, flags2d, cov2d, corr, nothing, rows, ambiguous)
    # The full-resolution step predicts the coarse find: ``before`` set to 2 last - find.
    fine_start = np.where(hit[..., None], last, np.nan)
    fine_aim = np.where(hit[..., None], 2 * last - pos * scale, np.nan)
    fine = rust_step(previous, current)
    fpos, ff2d, fcov, fcr = fine(fine_start, fine_aim, weights=weights, size=size, radius=fine_radius,
                                 min_correlation=box_correlation, forward_backward=forward_backward,
                                 min_texture=min_texture, max_iterations=max_iterations, weighted_box=weighted_box)
    good = hit & (ff2d == TrackFlag.TRACKED) & (fcr >= min_correlation)
    uv[good], cov2d[good], corr[good] = fpos[good], fcov[good], fcr[good]
    flags2d[good] = TrackFlag.TRACKED
    return PyramidFinds(uv, flags2d, cov2d, corr, good, rows, ambiguous)
