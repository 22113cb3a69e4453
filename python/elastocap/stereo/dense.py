"""Dense matching by region growing (SPEC 7, after Otto & Chau 1989 and the third body
paper): least-squares matches spread from a few seed points over a grid of template points,
each match predicted from an already matched neighbour.

The growth runs in waves: every wave matches, in one batched call of the Rust matcher
(:func:`~elastocap.stereo.match_patches`, parallel, GIL released), all grid points next to
the matched region, each started from the affine map of its neighbour (preferring the row
neighbours, then the column ones: the template "shifts along rows, then columns"). All seeds
grow at once, so each claims the grid points it reaches first: its (grid-geodesic) Voronoi
region. A failed point is tried again with a larger patch; when that fails too it waits for
the hole closing, which retries points surrounded by matches with the median of their
neighbours' maps. The Python work per wave is a few array operations on the grid, not a
per-pixel loop; the waves are few (the largest distance from a seed, in grid steps).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_float_array, as_positive
from elastocap.stereo.matching import _image, match_patches, noise_level

__all__ = ["DENSE_TEXTURE_OVER_NOISE", "DenseMatches", "grow_matches"]

# The least texture of a dense match, as a multiple of the template's noise level: lower than
# sparse matching's (2), because every dense point carries its covariance, so a weakly
# textured patch gives a point with a larger sigma rather than no point. At 2 the dark,
# shaded trousers of the textured synthetic capture (seeds 0-1) were a third unmatched; at
# 0.7 coverage is 95-98% of what both cameras see, median errors unchanged (benches/README).
DENSE_TEXTURE_OVER_NOISE = 0.7

# Grid neighbours in the order a prediction is taken from them: along the row, then the
# column ("shifting the template along rows then columns"), then the diagonals.
_NEIGHBOURS = ((0, -1), (0, 1), (-1, 0), (1, 0), (-1, -1), (-1, 1), (1, -1), (1, 1))

# Matches grid points (flat indices) from start maps (K, 1, 2, 3) with region labels (K,),
# accepting those within a distance (pixels) of their start; returns which were accepted.
_Run = Callable[[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64], float], NDArray[np.bool_]]

# States of a grid point.
_OUTSIDE, _OPEN, _MATCHED, _FAILED = 0, 1, 2, 3


class DenseMatches(NamedTuple):
    """Result of :func:`grow_matches`: M matched template points.

    Attributes
    ----------
    points : (M, 2) float64
        Template pixels ``(u, v)`` (grid points).
    positions : (M, 2) float64
        Their matches in the search image, pixels.
    affine : (M, 2, 3) float64
        The least-squares affine maps (as :attr:`~elastocap.stereo.Matches.affine`).
    covariance : (M, 2, 2) float64
        Covariance of ``positions``, pixels squared (least-squares matching's).
    sigma0, correlation : (M,) float64
        Per match (see :class:`~elastocap.stereo.Matches`).
    region : (M,) int64
        The seed each match grew from (index into the seeds given).
    size : (M,) int64
        Patch side used, pixels.
    grid : (rows, columns) int8
        Final state of every grid point: 0 outside the mask, 1 never matched (no matched
        neighbour reached it), 2 matched, 3 failed.
    waves : int
        Batched matcher calls made (growth waves and hole-closing rounds).
    """

    points: NDArray[np.float64]
    positions: NDArray[np.float64]
    affine: NDArray[np.float64]
    covariance: NDArray[np.float64]
    sigma0: NDArray[np.float64]
    correlation: NDArray[np.float64]
    region: NDArray[np.int64]
    size: NDArray[np.int64]
    grid: NDArray[np.int8]
    waves: int


def grow_matches(
    template: Any,
    search: Any,
    seeds: Any,
    seed_matches: Any,
    *,
    mask: Any = None,
    step: int = 2,
    size: int = 11,
    max_size: int = 23,
    min_correlation: float = 0.7,
    max_jump: float = 1.0,
    min_texture: float | None = None,
    interpolation: str = "bicubic",
    threads: int | None = None,
) -> DenseMatches:
    """Dense matches of ``template`` in ``search`` grown from seed correspondences.

    Parameters
    ----------
    template, search : (H, W) and (H_s, W_s) array_like
        Grey images (uint8, uint16 or float).
    seeds : (K, 2) array_like of float
        Seed points in the template, pixels; each is moved to its nearest grid point.
    seed_matches : (K, 2) array_like of float
        Their approximate matches in ``search`` (e.g. from a disparity map or sparse
        matching), pixels; least-squares matching refines them, and a seed whose match
        moves further than ``2 * step`` pixels or fails is dropped.
    mask : (H, W) array_like of bool, optional, keyword-only
        Grow only over these template pixels (e.g. a silhouette); default everywhere the
        patch fits.
    step : int, default 2, keyword-only
        Grid spacing of the template points, pixels.
    size : int, default 11, keyword-only
        Patch side, pixels (odd).
    max_size : int, default 23, keyword-only
        A failed point is retried with patches of ``size + 4``, ``size + 8``, ... up to this.
    min_correlation : float, default 0.7, keyword-only
        A match is accepted when it converged, its correlation is at least this (a patch
        of contrast ``s`` with noise ``n`` in both images correlates ``~s^2 / (s^2 + n^2)``
        at the right place: 0.7 keeps faint texture), and ...
    max_jump : float, default 1.0, keyword-only
        ... it lies within ``max_jump * step`` pixels of its prediction (the neighbour's map
        carried over): a larger jump is a depth discontinuity or a false match.
    min_texture : float, optional, keyword-only
        Least texture of a patch (see :func:`~elastocap.stereo.match_patches`); default
        :data:`DENSE_TEXTURE_OVER_NOISE` times the template's noise level.
    interpolation : {"bicubic", "bilinear"}, keyword-only
    threads : int, optional, keyword-only
        Matcher threads (default all cores).

    Returns
    -------
    DenseMatches

    Raises
    ------
    InvalidInputError
        Images or seeds of the wrong shape, a mask of another size than the template,
        options out of range.
    """
    image = _image("template", template)
    other = _image("search", search)
    seed_points = as_float_array("seeds", seeds).reshape(-1, 2) if np.size(seeds) else np.zeros((0, 2))
    seed_targets = as_float_array("seed_matches", seed_matches).reshape(-1, 2) if np.size(seed_matches) else np.zeros((0, 2))
    if seed_points.shape != seed_targets.shape or not np.isfinite(seed_points).all() or not np.isfinite(seed_targets).all():
        raise InvalidInputError(
            f"seeds and seed_matches must be finite (K, 2) arrays of the same shape, got {seed_points.shape} and {seed_targets.shape}"
        )
    step = as_count("step", step)
    size = as_count("size", size, minimum=3)
    max_size = as_count("max_size", max_size, minimum=3)
    if size % 2 == 0 or max_size % 2 == 0 or max_size < size:
        raise InvalidInputError(f"size and max_size must be odd with size <= max_size, got {size}, {max_size}")
    sizes = list(range(size, max_size + 1, 4))
    min_correlation = float(min_correlation)
    if not -1.0 <= min_correlation <= 1.0:
        raise InvalidInputError(f"min_correlation must be in [-1, 1], got {min_correlation}")
    jump = as_positive("max_jump", max_jump) * step
    texture = DENSE_TEXTURE_OVER_NOISE * noise_level(image) if min_texture is None else float(min_texture)
    if not (np.isfinite(texture) and texture >= 0):
        raise InvalidInputError(f"min_texture must be a finite number >= 0, got {min_texture!r}")
    height, width = image.shape

    # The grid of template points, and which of them may be matched.
    margin = max_size // 2 + 2
    columns = np.arange(margin, width - margin, step)
    rows = np.arange(margin, height - margin, step)
    state = np.full((len(rows), len(columns)), _OPEN, dtype=np.int8)
    if mask is not None:
        allowed = np.asarray(mask, dtype=bool)
        if allowed.shape != image.shape:
            raise InvalidInputError(f"mask must have the template's shape {image.shape}, got {allowed.shape}")
        state[~allowed[np.ix_(rows, columns)]] = _OUTSIDE
    shape = state.shape
    affine = np.full(shape + (2, 3), np.nan)
    covariance = np.full(shape + (2, 2), np.nan)
    sigma0 = np.full(shape, np.nan)
    correlation = np.full(shape, np.nan)
    region = np.full(shape, -1, dtype=np.int64)
    level = np.zeros(shape, dtype=np.int64)
    grid_u = columns[None, :].astype(np.float64) * np.ones((len(rows), 1))
    grid_v = rows[:, None].astype(np.float64) * np.ones((1, len(columns)))
    waves = 0

    def run(index: NDArray[np.int64], start: NDArray[np.float64], labels: NDArray[np.int64], limit: float) -> NDArray[np.bool_]:
        """Match grid points ``index`` (flat) from ``start`` maps, per patch level; store
        the accepted ones; return which were accepted."""
        nonlocal waves
        accepted = np.zeros(len(index), dtype=bool)
        for lv in np.unique(level.ravel()[index]):
            chosen = np.flatnonzero(level.ravel()[index] == lv)
            flat = index[chosen]
            points = np.stack([grid_u.ravel()[flat], grid_v.ravel()[flat]], axis=1)
            found = match_patches(
                image, points, other, size=sizes[lv], initial=start[chosen], min_texture=texture,
                interpolation=interpolation, threads=threads,
            )
            waves += 1
            moved = np.linalg.norm(found.positions[:, 0] - start[chosen, 0, :, 2], axis=1)
            ok = found.converged[:, 0] & (found.correlation[:, 0] >= min_correlation) & (moved <= limit)
            good = flat[ok]
            affine.reshape(-1, 2, 3)[good] = found.affine[ok, 0]
            covariance.reshape(-1, 2, 2)[good] = found.position_covariance()[ok]
            sigma0.ravel()[good] = found.sigma0[ok, 0]
            correlation.ravel()[good] = found.correlation[ok, 0]
            region.ravel()[good] = labels[chosen][ok]
            state.ravel()[good] = _MATCHED
            accepted[chosen[ok]] = True
        return accepted

    # Seeds: snapped to the grid, refined (with the larger patches where the first fails),
    # kept when they converge near where they were put.
    if len(seed_points) and len(rows) and len(columns):
        i = np.rint((seed_points[:, 1] - rows[0]) / step).astype(np.int64)
        j = np.rint((seed_points[:, 0] - columns[0]) / step).astype(np.int64)
        on_grid = np.flatnonzero((i >= 0) & (i < len(rows)) & (j >= 0) & (j < len(columns)))
        flat = i[on_grid] * shape[1] + j[on_grid]
        _, first = np.unique(flat, return_index=True)
        first = np.sort(first)
        first = first[state.ravel()[flat[first]] == _OPEN]
        nodes, which = flat[first], on_grid[first]
        start = np.zeros((len(nodes), 2, 3))
        start[:, 0, 0] = start[:, 1, 1] = 1.0
        start[:, :, 2] = seed_targets[which] + np.stack([grid_u.ravel()[nodes], grid_v.ravel()[nodes]], axis=1) - seed_points[which]
        for lv in range(len(sizes)):
            level.ravel()[nodes] = lv
            accepted = run(nodes, start[:, None], which.astype(np.int64), 2.0 * step)
            nodes, which, start = nodes[~accepted], which[~accepted], start[~accepted]
        # Seeds that failed stay open: growth may still reach them.
        level.ravel()[nodes] = 0

    offsets = np.array(_NEIGHBOURS)
    tried = np.zeros(shape, dtype=np.int64)  # matched neighbours at a point's last hole closing
    while True:
        grew = _grow(state, level, affine, region, grid_u, grid_v, offsets[:4], run, jump, len(sizes), waves_cap=100_000)
        closed = _close_holes(state, affine, region, grid_u, grid_v, offsets, level, len(sizes), run, jump, tried)
        if not grew and not closed:
            break

    matched = state == _MATCHED
    return DenseMatches(
        points=np.stack([grid_u[matched], grid_v[matched]], axis=1),
        positions=affine[matched][:, :, 2].copy(),
        affine=affine[matched],
        covariance=covariance[matched],
        sigma0=sigma0[matched],
        correlation=correlation[matched],
        region=region[matched],
        size=np.asarray(sizes)[level[matched]].astype(np.int64),
        grid=state,
        waves=waves,
    )


def _predict(
    affine: NDArray[np.float64], grid_u: NDArray[np.float64], grid_v: NDArray[np.float64],
    target: NDArray[np.int64], source: NDArray[np.int64],
) -> NDArray[np.float64]:
    """The maps of grid points ``target`` (flat) predicted from matched ``source`` points:
    the neighbour's linear part, its centre carried over by it."""
    maps = affine.reshape(-1, 2, 3)[source].copy()
    d = np.stack([grid_u.ravel()[target] - grid_u.ravel()[source], grid_v.ravel()[target] - grid_v.ravel()[source]], axis=1)
    maps[:, :, 2] += np.einsum("nij,nj->ni", maps[:, :, :2], d)
    return maps


def _shifted(array: NDArray[Any], di: int, dj: int, fill: Any) -> NDArray[Any]:
    """``out[i, j] = array[i + di, j + dj]`` (``fill`` beyond the edge)."""
    out = np.full_like(array, fill)
    rows, columns = array.shape[:2]
    out[max(0, -di) : rows - max(0, di), max(0, -dj) : columns - max(0, dj)] = array[
        max(0, di) : rows - max(0, -di), max(0, dj) : columns - max(0, -dj)
    ]
    return out


def _grow(
    state: NDArray[np.int8], level: NDArray[np.int64], affine: NDArray[np.float64], region: NDArray[np.int64],
    grid_u: NDArray[np.float64], grid_v: NDArray[np.float64], offsets: NDArray[np.int64], run: _Run, jump: float,
    levels: int, waves_cap: int,
) -> bool:
    """Waves until no open point touches the matched region; whether any point matched."""
    grew = False
    rows, columns = state.shape
    index = np.arange(rows * columns).reshape(rows, columns)
    for _ in range(waves_cap):
        source = np.full(state.shape, -1, dtype=np.int64)
        matched = state == _MATCHED
        for di, dj in offsets:
            neighbour = _shifted(matched, di, dj, False)
            take = (state == _OPEN) & neighbour & (source < 0)
            source[take] = _shifted(index, di, dj, 0)[take]
        target = np.flatnonzero(source.ravel() >= 0)
        if len(target) == 0:
            return grew
        src = source.ravel()[target]
        accepted = run(target, _predict(affine, grid_u, grid_v, target, src)[:, None], region.ravel()[src], jump)
        grew |= bool(accepted.any())
        failed = target[~accepted]
        level.ravel()[failed] += 1
        state.ravel()[failed[level.ravel()[failed] >= levels]] = _FAILED
    return grew


def _close_holes(
    state: NDArray[np.int8], affine: NDArray[np.float64], region: NDArray[np.int64], grid_u: NDArray[np.float64],
    grid_v: NDArray[np.float64], offsets: NDArray[np.int64], level: NDArray[np.int64], levels: int, run: _Run,
    jump: float, tried: NDArray[np.int64],
) -> bool:
    """One round of hole closing: failed (or unreached) points with at least three matched
    neighbours out of eight (more than when they were last tried), started from the median
    of the neighbours' predictions at the largest patch. Points that match reopen the
    growth around them."""
    rows, columns = state.shape
    index = np.arange(rows * columns).reshape(rows, columns)
    matched = state == _MATCHED
    count: NDArray[np.int64] = np.stack([_shifted(matched, di, dj, False) for di, dj in offsets]).sum(axis=0, dtype=np.int64)
    candidate = ((state == _FAILED) | (state == _OPEN)) & (count >= 3) & (count > tried)
    tried[candidate] = count[candidate]
    target = np.flatnonzero(candidate.ravel())
    if len(target) == 0:
        return False
    predictions = np.full((len(target), len(offsets), 2, 3), np.nan)
    labels = np.full(len(target), -1, dtype=np.int64)
    for k, (di, dj) in enumerate(offsets):
        neighbour = _shifted(matched, di, dj, False).ravel()[target]
        src = _shifted(index, di, dj, 0).ravel()[target]
        predictions[neighbour, k] = _predict(affine, grid_u, grid_v, target[neighbour], src[neighbour])
        labels = np.where(neighbour & (labels < 0), region.ravel()[src], labels)
    start = np.nanmedian(predictions, axis=1)
    level.ravel()[target] = levels - 1
    accepted = run(target, start[:, None], labels, jump)
    state.ravel()[target[~accepted]] = _FAILED
    # The new matches' open neighbours grow again with the first patch size.
    return bool(accepted.any())
