"""Dense disparity of a rectified pair: OpenCV's semi-global matching in both directions, a
left-right check, background filling and a colour-guided weighted median.

The stages and their defaults (SPEC section 7; figures in benches/README.md, section "Stereo
disparity"):

1. ``cv2.StereoSGBM`` on left->right and, on the mirrored images, right->left, over the
   disparity range of the capture volume (:func:`disparity_range`), so the far background is
   not searched;
2. the left-right check: a left match stands when the right image's match points back to
   within ``lr_tolerance`` pixels (:func:`~elastocap.stereo.disparity_filter.left_right_consistent`)
   and is not at an end of the range (where surfaces outside it pile up);
3. unmatched pixels take the smaller (background) of their nearest matched neighbours on the
   row (:func:`~elastocap.stereo.disparity_filter.fill_from_background`);
4. a weighted median with guided-filter weights on the left image aligns the disparity
   edges with the image edges and removes isolated mistakes
   (:func:`~elastocap.stereo.disparity_filter.weighted_median`);
5. optionally, the checked matches are refined to sub-pixel precision by windowed
   Gauss-Newton, which undoes SGBM's pull towards whole disparities
   (:func:`~elastocap.stereo.disparity_subpixel.refine_subpixel`).

The settings were tuned on rendered scenes with exact disparity
(:func:`~elastocap.stereo.disparity_scene.rectified_test_pair`, seeds 0-9, by
``python benches/sgbm_grid.py --tune``), except one: the SGBM mode, chosen among its three
values on Middlebury's Tsukuba (the rendered scenes preferred ``"hh"`` by 0.1 point; Tsukuba
gives 3.98% bad pixels with it and 3.46% with ``"3way"``). benches/README.md has the figures.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.stereo.disparity_filter import fill_from_background, left_right_consistent, weighted_median
from elastocap.stereo.disparity_subpixel import refine_subpixel
from elastocap.stereo.rectify import RectifiedPair, volume_corners

__all__ = ["DisparityMap", "DisparityWarning", "compute_disparity", "disparity_range", "sgbm_matcher"]

# An image whose grey levels vary by less than this (standard deviation) has nothing to
# match: all-black frames, lens caps, dropped frames.
BLANK_STD = 1.0
# Disparity levels of the weighted median, pixels apart (between levels it interpolates).
MEDIAN_STEP = 0.5
# Matches within this many pixels of either end of the searched range are not trusted.
RANGE_EDGE = 0.5
MODES = {
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "hh4": cv2.STEREO_SGBM_MODE_HH4,
}


class DisparityWarning(UserWarning):
    """A pair gave no disparity (blank images); the result is empty, not an error."""


@dataclass(frozen=True)
class DisparityMap:
    """Disparity of the left rectified image.

    Attributes
    ----------
    disparity : (H, W) float32
        Final disparity ``u_left - u_right``, pixels: matched, filled and filtered; NaN only
        where nothing was matched on the whole row (or the images were blank).
    valid : (H, W) bool
        Pixels whose match passed the left-right check (the others were filled).
    raw : (H, W) float32
        SGBM's left->right disparity, NaN where SGBM gave none.
    min_disparity, num_disparities : int
        The range searched: ``[min_disparity, min_disparity + num_disparities)``.
    """

    disparity: NDArray[np.float32]
    valid: NDArray[np.bool_]
    raw: NDArray[np.float32]
    min_disparity: int
    num_disparities: int


def disparity_range(pair: RectifiedPair, volume: Any, *, margin: float = 2.0) -> tuple[int, int]:
    """The disparities a volume can produce in a rectified pair.

    Parameters
    ----------
    pair : RectifiedPair
    volume : Grid or (2, 3) bounds
        The capture volume (world units).
    margin : float, keyword-only
        Pixels added on both sides.

    Returns
    -------
    (min_disparity, num_disparities) : (int, int)
        For ``cv2.StereoSGBM``: ``num_disparities`` a positive multiple of 16.

    Raises
    ------
    InvalidInputError
        When the volume is not in front of both cameras or projects outside either rectified
        image (the pair does not overlap on it).

    Notes
    -----
    Disparity ``f B / Z + (cx_left - cx_right)`` is monotonic in the depth ``Z`` of the
    rectified frame, and depth is linear in position, so its extremes over a box are at the
    box's corners. A box reaching behind the cameras (a camera inside the volume) is cut at
    the depth where disparity reaches the image width.
    """
    corners = volume_corners(volume)
    depth = (corners - pair.left.center) @ pair.rotation[2]
    f, B = pair.focal, pair.baseline
    width, height = pair.size
    for camera in (pair.left_rectified, pair.right_rectified):
        uv, z = camera.project(corners)
        ahead = z > 0
        if not ahead.any():
            raise InvalidInputError(f"the volume is behind camera {camera.name!r}: the pair does not see it")
        low, high = uv[ahead].min(axis=0), uv[ahead].max(axis=0)
        if (ahead.all() and (high[0] < -0.5 or low[0] > width - 0.5 or high[1] < -0.5 or low[1] > height - 0.5)):
            raise InvalidInputError(
                f"the volume projects outside camera {camera.name!r}'s rectified image: the pair {pair.name} "
                "does not overlap on it"
            )
    nearest = max(float(depth.min()), f * B / width)
    farthest = max(float(depth.max()), nearest)
    high = f * B / nearest + pair.disparity_offset + margin
    low = f * B / farthest + pair.disparity_offset - margin
    minimum = int(np.floor(low))
    count = int(np.ceil((high - minimum) / 16.0)) * 16
    return minimum, max(count, 16)


def sgbm_matcher(
    min_disparity: int,
    num_disparities: int,
    *,
    block_size: int = 3,
    channels: int = 3,
    p1: float = 8.0,
    p2: float = 32.0,
    mode: str = "hh",
    uniqueness: int = 5,
    speckle_window: int = 100,
    speckle_range: int = 2,
    pre_filter_cap: int = 63,
) -> Any:
    """A ``cv2.StereoSGBM`` with penalties ``P1 = p1 * channels * block_size^2`` and
    ``P2 = p2 * channels * block_size^2`` (OpenCV's documented scaling), no internal
    left-right check (done outside, in both directions)."""
    area = channels * block_size * block_size
    return cv2.StereoSGBM.create(
        minDisparity=int(min_disparity),
        numDisparities=int(num_disparities),
        blockSize=int(block_size),
        P1=int(round(p1 * area)),
        P2=int(round(p2 * area)),
        disp12MaxDiff=-1,
        preFilterCap=int(pre_filter_cap),
        uniquenessRatio=int(uniqueness),
        speckleWindowSize=int(speckle_window),
        speckleRange=int(speckle_range),
        mode=MODES[mode],
    )


def _images(left: Any, right: Any) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    out = []
    for name, image in (("left", left), ("right", right)):
        array = np.asarray(image)
        if array.dtype != np.uint8:
            raise InvalidInputError(f"{name} must be a uint8 image, got dtype {array.dtype}")
        if not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] == 3)):
            raise InvalidInputError(f"{name} must have shape (H, W) or (H, W, 3), got {array.shape}")
        out.append(np.ascontiguousarray(array))
    if out[0].shape != out[1].shape:
        raise InvalidInputError(f"left and right must have the same shape, got {out[0].shape} and {out[1].shape}")
    return out[0], out[1]


def compute_disparity(
    left: Any,
    right: Any,
    *,
    min_disparity: int = 0,
    num_disparities: int = 64,
    block_size: int = 3,
    mode: str = "3way",
    p1: float = 8.0,
    p2: float = 32.0,
    uniqueness: int = 10,
    speckle_window: int = 100,
    speckle_range: int = 2,
    pre_filter_cap: int = 63,
    lr_tolerance: float = 0.5,
    fill: bool = True,
    median_radius: int = 13,
    median_eps: float = 1e-4,
    subpixel_radius: int = 0,
) -> DisparityMap:
    """Disparity of the left image of a rectified pair.

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) uint8
        Rectified images (rows correspond); colour in RGB order.
    min_disparity, num_disparities : int, keyword-only
        Range searched, e.g. from :func:`disparity_range`; ``num_disparities`` a positive
        multiple of 16 smaller than the width.
    block_size, mode, p1, p2, uniqueness, speckle_window, speckle_range, pre_filter_cap : keyword-only
        ``cv2.StereoSGBM`` settings (see :func:`sgbm_matcher`); ``mode`` is ``"3way"`` (the
        default), ``"hh"`` (full 8-path dynamic programming), ``"sgbm"`` (5 paths) or
        ``"hh4"``.
    lr_tolerance : float, keyword-only
        Left-right check tolerance, pixels.
    fill : bool, keyword-only
        Fill unmatched pixels and apply the weighted median (default); False keeps NaN
        where unmatched and the checked SGBM disparity elsewhere.
    median_radius, median_eps : keyword-only
        Weighted-median window radius (pixels; 0 turns the median off) and guided-filter
        regularisation (squared 0..1 intensity).
    subpixel_radius : int, keyword-only
        Window radius of the sub-pixel refinement of the checked matches
        (:func:`~elastocap.stereo.disparity_subpixel.refine_subpixel`); 0 (the default)
        turns it off: it removes SGBM's pull to whole disparities on planes, but on the
        rendered scenes (curved, weakly textured) it did not lower the errors.

    Returns
    -------
    DisparityMap

    Warns
    -----
    DisparityWarning
        When either image is blank (grey-level standard deviation below 1): the result is
        empty (all NaN, nothing valid).

    Raises
    ------
    InvalidInputError
        Images of different shapes or not uint8 (H, W) / (H, W, 3); a bad range.
    """
    left_, right_ = _images(left, right)
    height, width = left_.shape[:2]
    if num_disparities <= 0 or num_disparities % 16 != 0:
        raise InvalidInputError(f"num_disparities must be a positive multiple of 16, got {num_disparities}")
    if num_disparities >= width:
        raise InvalidInputError(f"num_disparities ({num_disparities}) must be below the image width ({width})")
    if mode not in MODES:
        raise InvalidInputError(f"mode must be one of {sorted(MODES)}, got {mode!r}")
    empty = np.full((height, width), np.nan, np.float32)
    for name, image in (("left", left_), ("right", right_)):
        if float(image.std()) < BLANK_STD:
            warnings.warn(f"{name} image is blank (grey-level std {float(image.std()):.2f}): no disparity", DisparityWarning, stacklevel=2)
            return DisparityMap(empty, np.zeros((height, width), bool), empty.copy(), int(min_disparity), int(num_disparities))
    channels = 1 if left_.ndim == 2 else 3
    matcher = sgbm_matcher(
        min_disparity, num_disparities, block_size=block_size, channels=channels, p1=p1, p2=p2, mode=mode,
        uniqueness=uniqueness, speckle_window=speckle_window, speckle_range=speckle_range, pre_filter_cap=pre_filter_cap,
    )
    bgr = (lambda x: x) if channels == 1 else (lambda x: np.ascontiguousarray(x[..., ::-1]))
    invalid = (min_disparity - 1) * 16
    raw_left = matcher.compute(bgr(left_), bgr(right_))
    # The right image's disparity: match the mirrored pair (mirrored right as the reference).
    raw_right = matcher.compute(bgr(right_[:, ::-1]), bgr(left_[:, ::-1]))[:, ::-1]
    d_left = np.where(raw_left > invalid, raw_left / np.float32(16), np.nan).astype(np.float32)
    d_right = np.where(raw_right > invalid, raw_right / np.float32(16), np.nan).astype(np.float32)
    # A match at an end of the range is most often a surface outside the range (the far
    # background) pulled to the nearest disparity allowed, and both directions agree on it.
    inside = (d_left > min_disparity + RANGE_EDGE) & (d_left < min_disparity + num_disparities - 1 - RANGE_EDGE)
    valid = left_right_consistent(d_left, d_right, tolerance=lr_tolerance) & inside
    if not valid.any():
        warnings.warn("no pixel passed the left-right check: no disparity", DisparityWarning, stacklevel=2)
        return DisparityMap(empty, valid, d_left, int(min_disparity), int(num_disparities))
    if fill:
        result = fill_from_background(d_left, valid)
        if median_radius > 0:
            rows = np.isfinite(result)
            guide = left_.astype(np.float32) / 255.0
            levels = np.arange(min_disparity - MEDIAN_STEP, min_disparity + num_disparities + MEDIAN_STEP, MEDIAN_STEP)
            smoothed = weighted_median(guide, np.where(rows, result, min_disparity), levels, radius=median_radius, eps=median_eps)
            result = np.where(rows, smoothed, np.nan).astype(np.float32)
    else:
        result = np.where(valid, d_left, np.nan).astype(np.float32)
    if subpixel_radius > 0:
        result, _ = refine_subpixel(left_, right_, result, valid & np.isfinite(result), radius=subpixel_radius)
    return DisparityMap(result, valid, d_left, int(min_disparity), int(num_disparities))
