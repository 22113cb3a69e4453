"""Post-processing of disparity maps: left-right consistency, background filling along the
scanline, and the colour-guided weighted median.

Each step is plain numpy / OpenCV on whole images (no per-pixel Python loops). References:
the left-right check and the background fill are those of Hirschmueller's SGM paper
(2008, sections 3.3 and 4.3); the weighted median with guided-filter weights is Ma, He, Wei,
Sun and Wu, "Constant time weighted median filtering for stereo matching and beyond" (ICCV
2013), with He, Sun and Tang's guided filter (ECCV 2010) giving the weights.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["fill_from_background", "guided_filter", "left_right_consistent", "weighted_median", "window_correlation"]

# OpenCV 5 limits images to 128 channels; level indicator stacks are filtered in chunks.
CHANNEL_CHUNK = 64


def left_right_consistent(
    left: NDArray[np.float32], right: NDArray[np.float32], *, tolerance: float = 1.0
) -> NDArray[np.bool_]:
    """Pixels of the left disparity confirmed by the right one.

    Parameters
    ----------
    left, right : (H, W) float32
        Disparities of the left and of the right image (``u_left - u_right``, positive
        towards the camera), NaN where unmatched.
    tolerance : float, keyword-only
        Largest ``|d_left(u) - d_right(u - d_left(u))|``, pixels.

    Returns
    -------
    (H, W) bool
        Matched in the left image, its match inside the right image, and the right
        image's disparity there agrees within ``tolerance``.
    """
    height, width = left.shape
    matched = np.isfinite(left)
    target = np.arange(width)[None, :] - np.rint(np.where(matched, left, 0)).astype(np.int64)
    inside = (target >= 0) & (target < width)
    back = np.take_along_axis(right, np.clip(target, 0, width - 1), axis=1)
    with np.errstate(invalid="ignore"):
        return np.asarray(matched & inside & (np.abs(back - left) <= tolerance))


def fill_from_background(disparity: NDArray[np.float32], valid: NDArray[np.bool_]) -> NDArray[np.float32]:
    """Fill invalid pixels with the smaller of the nearest valid disparities to their left
    and right on the same row.

    Parameters
    ----------
    disparity : (H, W) float32
    valid : (H, W) bool

    Returns
    -------
    (H, W) float32
        ``disparity`` where valid; elsewhere the background (smaller-disparity) neighbour;
        NaN on rows without any valid pixel.

    Notes
    -----
    Most unmatched pixels are occluded in the right image, and occluded pixels belong to
    the farther surface, so the smaller neighbour is the better guess (Hirschmueller 2008,
    section 4.3, in its simplest, scanline form).
    """
    height, width = disparity.shape
    columns = np.arange(width)[None, :]
    last = np.maximum.accumulate(np.where(valid, columns, -1), axis=1)
    following = np.minimum.accumulate(np.where(valid, columns, width)[:, ::-1], axis=1)[:, ::-1]
    from_left = np.where(last >= 0, np.take_along_axis(disparity, np.clip(last, 0, width - 1), axis=1), np.inf)
    from_right = np.where(following < width, np.take_along_axis(disparity, np.clip(following, 0, width - 1), axis=1), np.inf)
    background = np.minimum(from_left, from_right)
    filled = np.where(valid, disparity, background)
    return np.where(np.isfinite(filled), filled, np.nan).astype(np.float32)


class _GuidedFilter:
    """He et al.'s guided filter with a fixed (colour or grey) guide, applied to many inputs.

    The guide's local means and inverse covariances are computed once; each input then
    costs eight box filters (colour guide) or four (grey).
    """

    def __init__(self, guide: NDArray[np.float32], radius: int, eps: float) -> None:
        self.size = (2 * radius + 1, 2 * radius + 1)
        I = guide if guide.ndim == 3 else guide[..., None]
        self.I = I
        self.mean_I = self._box(I)
        channels = I.shape[2]
        cov = np.empty(I.shape[:2] + (channels, channels), np.float32)
        for i in range(channels):
            for j in range(i, channels):
                c = self._box(I[..., i] * I[..., j]) - self.mean_I[..., i] * self.mean_I[..., j]
                cov[..., i, j] = c
                cov[..., j, i] = c
        cov += eps * np.eye(channels, dtype=np.float32)
        self.inverse = np.ascontiguousarray(np.linalg.inv(cov))

    def _box(self, x: NDArray[np.float32]) -> NDArray[np.float32]:
        # OpenCV returns (H, W) for a one-channel (H, W, 1) input: keep the input's shape.
        filtered = cv2.boxFilter(np.ascontiguousarray(x), -1, self.size, normalize=True, borderType=cv2.BORDER_REFLECT)
        return np.asarray(filtered, dtype=np.float32).reshape(x.shape)

    def __call__(self, p: NDArray[np.float32]) -> NDArray[np.float32]:
        """Filter ``(H, W, K)`` inputs (``K <= CHANNEL_CHUNK``) at once."""
        mean_p = self._box(p)
        channels = self.I.shape[2]
        # Per guide channel c: cov(I_c, p) over the window, (H, W, K) each.
        cov = [self._box(self.I[..., c : c + 1] * p) - self.mean_I[..., c : c + 1] * mean_p for c in range(channels)]
        # q = box(b) + sum_i box(a_i) I_i, a = Sigma^-1 cov(I, p), b = mean_p - a . mean_I.
        b = mean_p.copy()
        out = np.zeros_like(mean_p)
        for i in range(channels):
            a = self.inverse[..., i, 0, None] * cov[0]
            for j in range(1, channels):
                a += self.inverse[..., i, j, None] * cov[j]
            b -= a * self.mean_I[..., i : i + 1]
            out += self._box(a) * self.I[..., i : i + 1]
        out += self._box(b)
        return out


def guided_filter(guide: NDArray[np.float32], p: NDArray[np.float32], *, radius: int, eps: float) -> NDArray[np.float32]:
    """He et al.'s guided filter of ``p`` ``(H, W)`` or ``(H, W, K)`` by ``guide`` ``(H, W)``
    or ``(H, W, 3)`` float32 (0..1), window ``2 radius + 1``, regularisation ``eps``."""
    filt = _GuidedFilter(guide, radius, eps)
    stack = p[..., None] if p.ndim == 2 else p
    out = np.concatenate(
        [filt(np.ascontiguousarray(stack[..., k : k + CHANNEL_CHUNK])) for k in range(0, stack.shape[2], CHANNEL_CHUNK)], axis=2
    )
    return out[..., 0] if p.ndim == 2 else out


def weighted_median(
    guide: NDArray[np.float32],
    disparity: NDArray[np.float32],
    levels: NDArray[np.float64],
    *,
    radius: int,
    eps: float,
) -> NDArray[np.float32]:
    """The weighted median of ``disparity`` in each pixel's window, weights from the guided
    filter of ``guide``, to sub-level precision.

    Parameters
    ----------
    guide : (H, W) or (H, W, 3) float32
        Image in 0..1.
    disparity : (H, W) float32
        Finite everywhere (fill first).
    levels : (L,) float64
        Increasing disparity levels spanning the data.
    radius, eps : keyword-only
        Guided-filter window radius (pixels) and regularisation (guide units squared).

    Returns
    -------
    (H, W) float32

    Notes
    -----
    Ma et al. (2013): the guided filter of the indicator ``[d <= l]`` is, at each pixel,
    the weighted fraction of its window at or below level ``l``; the median is where that
    fraction reaches 1/2. Between two levels the fraction is interpolated linearly, which
    returns a continuous value rather than a level.
    """
    filt = _GuidedFilter(guide, radius, eps)
    height, width = disparity.shape
    result = np.full((height, width), np.nan, np.float32)
    previous_level = np.float32(levels[0])
    previous = np.zeros((height, width), np.float32)
    for start in range(0, len(levels), CHANNEL_CHUNK):
        chunk = levels[start : start + CHANNEL_CHUNK].astype(np.float32)
        fraction = filt(np.ascontiguousarray((disparity[..., None] <= chunk).astype(np.float32)))
        for k, level in enumerate(chunk):
            current = fraction[..., k]
            crossing = np.isnan(result) & (current >= 0.5)
            if crossing.any():
                low, high = previous[crossing], current[crossing]
                share = np.clip((0.5 - low) / np.maximum(high - low, 1e-6), 0.0, 1.0)
                result[crossing] = previous_level + share * (level - previous_level)
            previous, previous_level = current, level
    return np.where(np.isnan(result), np.float32(levels[-1]), result)


def window_correlation(
    left: NDArray[np.uint8], right: NDArray[np.uint8], disparity: NDArray[np.float32], *, radius: int = 3
) -> NDArray[np.float32]:
    """Zero-mean normalised cross-correlation between each left window and the right window
    its disparity points to.

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) uint8
    disparity : (H, W) float32
        NaN where there is none (the result is NaN there too).
    radius : int, keyword-only
        Half-size of the square window.

    Returns
    -------
    (H, W) float32 in [-1, 1]

    Notes
    -----
    The right image is resampled at ``u - d(u)`` once (each pixel by its own disparity), and
    the correlation's window sums are box filters. A surface outside the searched range
    still gets a disparity inside it, often the same in both directions (so the left-right
    check keeps it); its windows then do not correlate.
    """
    grey_left = (cv2.cvtColor(left, cv2.COLOR_RGB2GRAY) if left.ndim == 3 else left).astype(np.float32)
    grey_right = (cv2.cvtColor(right, cv2.COLOR_RGB2GRAY) if right.ndim == 3 else right).astype(np.float32)
    height, width = grey_left.shape
    rows, columns = np.mgrid[0:height, 0:width].astype(np.float32)
    has = np.isfinite(disparity)
    warped = np.asarray(
        cv2.remap(grey_right, columns - np.where(has, disparity, 0).astype(np.float32), rows, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
        dtype=np.float32,
    )
    size = (2 * radius + 1, 2 * radius + 1)

    def box(x: NDArray[np.float32]) -> NDArray[np.float32]:
        return np.asarray(cv2.boxFilter(x, -1, size, normalize=True, borderType=cv2.BORDER_REFLECT), dtype=np.float32)

    mean_l, mean_r = box(grey_left), box(warped)
    covariance = box(grey_left * warped) - mean_l * mean_r
    variance = np.maximum(box(grey_left * grey_left) - mean_l**2, 0) * np.maximum(box(warped * warped) - mean_r**2, 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        correlation = covariance / np.sqrt(variance)
    correlation = np.where(variance > 1e-6, correlation, 0.0)
    return np.where(has, np.clip(correlation, -1, 1), np.nan).astype(np.float32)
