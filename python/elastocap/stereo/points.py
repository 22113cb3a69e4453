"""Dense 3-D points of a camera pair: SGBM disparity for seeds, least-squares matches grown
from them over the left image (:mod:`elastocap.stereo.dense`), forward intersection through
the full camera model with each match's covariance (:mod:`elastocap.stereo.intersection`).

Matching runs in the ORIGINAL images (no resampling by the rectification: the affine maps of
least-squares matching absorb the local lens distortion), so the points carry the precision
of the matches; the rectified pair only serves SGBM, which gives the seeds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.stereo.dense import DenseMatches, grow_matches
from elastocap.stereo.disparity_stage import PairDisparity, pair_disparity
from elastocap.stereo.disparity_stage import _inside as _in_volume
from elastocap.stereo.intersection import intersect, match_observations
from elastocap.stereo.rectify import RectifiedPair

__all__ = ["PairPoints", "pair_points", "seeds_from_disparity"]

# Seeds are taken from the checked disparity on a grid of this spacing (rectified pixels).
SEED_SPACING = 8


@dataclass(frozen=True)
class PairPoints:
    """Dense points of one camera pair in one frame.

    Attributes
    ----------
    pair : RectifiedPair
    points : (M, 3) float64
        World coordinates.
    covariance : (M, 3, 3) float64
        Their covariance from the matches' covariance, world units squared.
    sigma : (M,) float64
        ``sqrt`` of the largest eigenvalue of ``covariance``: the standard deviation along
        the worst direction (for a short baseline, the depth), world units.
    colours : (M, 3) uint8
        RGB of the left image at the template points.
    pixels : (M, 2) float64
        The template points in the ORIGINAL left image, pixels.
    matches : DenseMatches
        The dense matches (``matches.points`` are ``pixels`` before the intersection's
        rejection; rows of ``points`` follow the rows kept, see ``kept``).
    kept : (M,) int64
        Row of ``matches`` each point came from.
    disparity : PairDisparity
        The SGBM stage that gave the seeds.
    """

    pair: RectifiedPair
    points: NDArray[np.float64]
    covariance: NDArray[np.float64]
    sigma: NDArray[np.float64]
    colours: NDArray[np.uint8]
    pixels: NDArray[np.float64]
    matches: DenseMatches
    kept: NDArray[np.int64]
    disparity: PairDisparity


def seeds_from_disparity(
    result: PairDisparity, *, spacing: int = SEED_SPACING, in_volume: bool = True
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Seed correspondences in the ORIGINAL images from a checked disparity map.

    Rectified left pixels on a grid of ``spacing`` where the left-right check passed (and,
    with ``in_volume``, the disparity mask holds: the point lies in the capture volume);
    their rectified right positions ``(u - d, v)``; both mapped back to the original
    cameras through the rectification tables.

    Returns
    -------
    left, right : (K, 2) float64
        Original pixels of the seed in the left and right images.
    """
    d = result.disparity.disparity
    usable = result.disparity.valid & np.isfinite(d)
    if in_volume:
        usable &= result.mask
    rows, columns = np.mgrid[spacing // 2 : d.shape[0] : spacing, spacing // 2 : d.shape[1] : spacing]
    keep = usable[rows, columns]
    if not keep.any():
        # No checked disparity in the volume (cv2.remap refuses empty maps).
        return np.empty((0, 2)), np.empty((0, 2))
    v, u = rows[keep].astype(np.float64), columns[keep].astype(np.float64)
    ur = u - d[rows[keep], columns[keep]]
    (lx, ly), (rx, ry) = result.pair.maps
    left = np.stack([lx[rows[keep], columns[keep]], ly[rows[keep], columns[keep]]], axis=1).astype(np.float64)
    query_u, query_v = ur.astype(np.float32)[:, None], v.astype(np.float32)[:, None]
    right = np.stack([
        cv2.remap(rx, query_u, query_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1e6)[:, 0],
        cv2.remap(ry, query_u, query_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1e6)[:, 0],
    ], axis=1).astype(np.float64)
    inside = _inside(left, result.pair.left.size) & _inside(right, result.pair.right.size)
    return left[inside], right[inside]


def _inside(uv: NDArray[np.float64], size: tuple[int, int]) -> NDArray[np.bool_]:
    return np.asarray(np.isfinite(uv).all(axis=1) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] <= size[0] - 1) & (uv[:, 1] <= size[1] - 1))


def _grey(image: NDArray[Any]) -> NDArray[np.float32]:
    array = np.asarray(image)
    if array.ndim == 3:
        array = cv2.cvtColor(np.ascontiguousarray(array), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(array, dtype=np.float32)


def pair_points(
    pair: RectifiedPair,
    left_image: Any,
    right_image: Any,
    volume: Any,
    *,
    mask: Any = None,
    seed_spacing: int = SEED_SPACING,
    disparity_options: dict[str, Any] | None = None,
    **grow_options: Any,
) -> PairPoints:
    """Dense points of a pair: seeds from SGBM, region growing, forward intersection.

    Parameters
    ----------
    pair : RectifiedPair
    left_image, right_image : (H, W, 3) or (H, W) uint8
        Original images of ``pair.left`` and ``pair.right`` (RGB).
    volume : Grid or (2, 3) bounds
        The capture volume (disparity range and mask).
    mask : (H, W) bool, optional, keyword-only
        Where to grow in the original left image (e.g. the capture's silhouette). Default:
        the SGBM disparity mask (surfaces inside the volume), dilated by 4 pixels.
    seed_spacing : int, keyword-only
        Grid spacing of the seeds taken from the disparity map, rectified pixels.
    disparity_options : dict, optional, keyword-only
        Passed to :func:`~elastocap.stereo.disparity_stage.pair_disparity`; default
        ``fill=False``.
    **grow_options
        Passed to :func:`~elastocap.stereo.dense.grow_matches` (``step``, ``size``,
        ``min_correlation``, ...).

    Returns
    -------
    PairPoints
        Points that intersect validly in front of both cameras and inside the volume.
    """
    # Seeds need only the checked matches: no hole filling nor weighted median (which cost
    # ~30x the SGBM itself at 1024 x 768 over a 350-disparity range).
    result = pair_disparity(pair, left_image, right_image, volume, **{"fill": False, **(disparity_options or {})})
    if mask is None:
        grow_mask = cv2.dilate(result.mask_original.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    else:
        grow_mask = np.asarray(mask, dtype=bool)
        if grow_mask.shape != (pair.left.height, pair.left.width):
            raise InvalidInputError(f"mask must have the left camera's shape {(pair.left.height, pair.left.width)}, got {grow_mask.shape}")
    # With a given mask (a silhouette) it alone says what is foreground.
    seeds_left, seeds_right = seeds_from_disparity(result, spacing=seed_spacing, in_volume=mask is None)
    keep_seed = grow_mask[np.rint(seeds_left[:, 1]).astype(int), np.rint(seeds_left[:, 0]).astype(int)]
    left_grey, right_grey = _grey(left_image), _grey(right_image)
    matches = grow_matches(left_grey, right_grey, seeds_left[keep_seed], seeds_right[keep_seed], mask=grow_mask, **grow_options)
    # One search image: the matches' (M, 2, 2) position covariance is the (M, 2S, 2S) block.
    uv, cov = match_observations(matches.points, matches.positions[:, None], matches.covariance)
    solved = intersect([pair.left, pair.right], uv, covariance=cov, reject=False)
    ok = solved.valid & np.isfinite(solved.covariance).all(axis=(1, 2))
    ok[ok] &= _in_volume(solved.points[ok], volume)
    kept = np.flatnonzero(ok)
    point_cov = solved.covariance[kept]
    sigma = np.sqrt(np.maximum(np.linalg.eigvalsh(point_cov)[:, -1], 0.0)) if len(kept) else np.zeros(0)
    pixels = matches.points[kept]
    colour_image = np.asarray(left_image)
    if colour_image.ndim == 2:
        colour_image = np.repeat(colour_image[:, :, None], 3, axis=2)
    iu, iv = np.rint(pixels[:, 0]).astype(int), np.rint(pixels[:, 1]).astype(int)
    colours = colour_image[iv, iu].astype(np.uint8)
    return PairPoints(pair, solved.points[kept], point_cov, sigma, colours, pixels, matches, kept.astype(np.int64), result)
