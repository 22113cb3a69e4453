"""From a camera pair's images to world points and the disparity mask, and the files the
silhouette stage reads: ``OUT/disparity/<pair>/<frame:06d>.png|.npz``.

The pair's name is ``"<left>-<right>"`` after :func:`~elastocap.stereo.rectify.rectify_pair`
has put the left camera on the left. The ``.png`` is the disparity mask in the ORIGINAL left
camera's pixels (0 / 255), ready to mask that camera's gradient image; the ``.npz`` holds the
rectified disparity, its validity, both masks and the rectified geometry (so the disparity
can be turned back into points without the rig).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._io import save_image, save_npz
from elastocap.stereo.disparity import DisparityMap, compute_disparity, disparity_range
from elastocap.stereo.rectify import RectifiedPair, volume_corners

__all__ = ["PairDisparity", "disparity_mask", "disparity_to_points", "pair_disparity", "write_disparity"]


def disparity_to_points(
    disparity: Any, pair: RectifiedPair, *, mask: Any = None
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """World points of a left rectified disparity map.

    Parameters
    ----------
    disparity : (H, W) float array
        ``u_left - u_right`` in the pair's rectified images, pixels; NaN = none.
    pair : RectifiedPair
    mask : (H, W) bool, keyword-only
        Only these pixels (default: all with a usable disparity).

    Returns
    -------
    points : (N, 3) float64
        World coordinates (the rig's units).
    pixels : (N, 2) int64
        ``(u, v)`` of each point in the left rectified image.

    Notes
    -----
    Depth ``Z = f B / (d - (cx_left - cx_right))`` in the rectified frame, ``X = (u - cx) Z
    / f``, ``Y = (v - cy) Z / f``, then ``X_world = R^T [X, Y, Z] + c_left`` (R the
    rectified rotation, c the left centre). Disparities at or below the offset (points at or
    beyond infinity) give no point.
    """
    d = np.asarray(disparity, dtype=np.float64)
    if d.shape != (pair.size[1], pair.size[0]):
        raise InvalidInputError(f"disparity must have the rectified shape {(pair.size[1], pair.size[0])}, got {d.shape}")
    K = pair.left_rectified.K
    f, B = pair.focal, pair.baseline
    with np.errstate(invalid="ignore"):
        usable = np.isfinite(d) & (d - pair.disparity_offset > 1e-6)
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != d.shape:
            raise InvalidInputError(f"mask must have shape {d.shape}, got {m.shape}")
        usable &= m
    v, u = np.nonzero(usable)
    Z = f * B / (d[v, u] - pair.disparity_offset)
    rectified = np.stack([(u - K[0, 2]) * Z / f, (v - K[1, 2]) * Z / f, Z], axis=1)
    points = rectified @ pair.rotation + pair.left.center
    return points, np.stack([u, v], axis=1).astype(np.int64)


def _inside(points: NDArray[np.float64], volume: Any) -> NDArray[np.bool_]:
    corners = volume_corners(volume)
    low, high = corners.min(axis=0), corners.max(axis=0)
    return np.asarray(((points >= low) & (points <= high)).all(axis=1))


def disparity_mask(
    disparity: DisparityMap,
    pair: RectifiedPair,
    volume: Any,
    *,
    opening: int = 1,
    closing: int = 3,
    min_area: float = 0.002,
) -> NDArray[np.bool_]:
    """The binarised, morphologically cleaned disparity mask of the left rectified image:
    where a checked match puts a surface inside the volume.

    Parameters
    ----------
    disparity : DisparityMap
    pair : RectifiedPair
    volume : Grid or (2, 3) bounds
        The capture volume; surfaces outside it (the background) are not foreground.
    opening, closing : int, keyword-only
        Radii (pixels) of the elliptic structuring elements: opening removes specks, closing
        fills gaps between matched patches.
    min_area : float, keyword-only
        Connected regions smaller than this share of the image are dropped.

    Returns
    -------
    (H, W) bool
    """
    points, pixels = disparity_to_points(disparity.disparity, pair, mask=disparity.valid)
    foreground: NDArray[np.uint8] = np.zeros(disparity.valid.shape, np.uint8)
    keep = _inside(points, volume)
    foreground[pixels[keep, 1], pixels[keep, 0]] = 1
    if opening > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * opening + 1, 2 * opening + 1))
        foreground = np.asarray(cv2.morphologyEx(foreground, cv2.MORPH_OPEN, kernel), dtype=np.uint8)
    if closing > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * closing + 1, 2 * closing + 1))
        foreground = np.asarray(cv2.morphologyEx(foreground, cv2.MORPH_CLOSE, kernel), dtype=np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(foreground, connectivity=8)
    smallest = min_area * foreground.size
    big = np.zeros(count, bool)
    big[1:] = stats[1:, cv2.CC_STAT_AREA] >= smallest
    return np.asarray(big[labels])


@dataclass(frozen=True)
class PairDisparity:
    """One frame of one camera pair, after :func:`pair_disparity`.

    Attributes
    ----------
    pair : RectifiedPair
    disparity : DisparityMap
        In the left rectified image.
    mask : (H, W) bool
        Disparity mask, left rectified image.
    mask_original : (h, w) bool
        The same mask in the original left camera's pixels.
    points : (N, 3) float64
        World points of the checked matches inside the mask.
    colours : (N, 3) uint8
        Their colour in the left image.
    """

    pair: RectifiedPair
    disparity: DisparityMap
    mask: NDArray[np.bool_]
    mask_original: NDArray[np.bool_]
    points: NDArray[np.float64]
    colours: NDArray[np.uint8]


def pair_disparity(
    pair: RectifiedPair, left_image: Any, right_image: Any, volume: Any, *, guard: int = 16, **options: Any
) -> PairDisparity:
    """Rectify, match within the volume's disparity range, and turn into points and a mask.

    Parameters
    ----------
    pair : RectifiedPair
    left_image, right_image : (H, W) or (H, W, 3) uint8
        Original images of ``pair.left`` and ``pair.right``.
    volume : Grid or (2, 3) bounds
        The capture volume (see :func:`~elastocap.stereo.disparity.disparity_range`).
    guard : int, keyword-only
        Disparities searched below the volume's range (a multiple of 16): surfaces just
        behind the volume match there and are then left out by position, instead of being
        pulled into the volume's range by SGBM's smoothness.
    **options
        Passed to :func:`~elastocap.stereo.disparity.compute_disparity`.

    Returns
    -------
    PairDisparity
    """
    left, right = pair.rectify(left_image, right_image)
    minimum, count = disparity_range(pair, volume)
    minimum, count = minimum - guard, count + guard
    width = pair.size[0]
    if count >= width:
        count = (width - 1) // 16 * 16
    dmap = compute_disparity(left, right, min_disparity=minimum, num_disparities=count, **options)
    mask = disparity_mask(dmap, pair, volume)
    points, pixels = disparity_to_points(dmap.disparity, pair, mask=mask & dmap.valid)
    colours = np.asarray(left)[pixels[:, 1], pixels[:, 0]]
    if colours.ndim == 1:
        colours = np.repeat(colours[:, None], 3, axis=1)
    original = pair.to_left_original(mask.astype(np.uint8)) > 0
    return PairDisparity(pair, dmap, mask, original, points, colours.astype(np.uint8))


def write_disparity(out: str | Path, result: PairDisparity, frame: int) -> tuple[Path, Path]:
    """Write ``OUT/disparity/<pair>/<frame:06d>.png`` (mask, original left pixels, 0/255)
    and ``.npz`` (``disparity``, ``valid``, ``mask``: rectified left; ``mask_original``;
    ``K_left``, ``K_right``, ``R``: rectified cameras, world -> rectified rotation;
    ``centre_left``, ``centre_right``; ``min_disparity``, ``num_disparities``; ``left``,
    ``right``: camera names), each atomically. Returns the two paths."""
    folder = Path(out) / "disparity" / result.pair.name
    png = folder / f"{int(frame):06d}.png"
    npz = folder / f"{int(frame):06d}.npz"
    pair = result.pair
    save_npz(
        npz,
        disparity=result.disparity.disparity,
        valid=result.disparity.valid,
        mask=result.mask,
        mask_original=result.mask_original,
        K_left=pair.left_rectified.K,
        K_right=pair.right_rectified.K,
        R=pair.rotation,
        centre_left=pair.left.center,
        centre_right=pair.right.center,
        min_disparity=result.disparity.min_disparity,
        num_disparities=result.disparity.num_disparities,
        left=pair.left.name,
        right=pair.right.name,
    )
    save_image(png, (result.mask_original.astype(np.uint8) * 255))
    return png, npz
