"""Graph-cut refinement of a silhouette in the band stereo allows: :func:`refine_in_band`.

A contour on edges alone cuts the concave parts of a silhouette (armpits, the gap between
the legs) and stops on the subject's own texture edges; at 480x360 a person's outline is
~1000 pixels long for ~14000 inside, so one pixel of error along it costs ~7% of IoU. This
stage labels each pixel of a band around a start silhouette (the snake's) by colour:
GrabCut (:func:`~elastocap.silhouettes.background.refine_silhouette`: Gaussian mixtures
of the subject's and the background's colours, an s-t cut with contrast-sensitive
smoothing) seeded by the start and
bounded by the stereo stage's disparity mask. Outside the (raw, not closed) disparity mask
grown by ``grow`` pixels, or farther than ``reach`` from the start, is background for
sure; the start's core is subject for sure.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.silhouettes.background import clean_mask, refine_silhouette

__all__ = ["refine_in_band"]


def _disk(radius: int) -> NDArray[np.uint8]:
    return np.asarray(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1)), dtype=np.uint8)


def refine_in_band(
    image: Any,
    start: Any,
    disparity_mask: Any = None,
    *,
    grow: int = 4,
    reach: int = 15,
    core: int = 8,
    iterations: int = 3,
    pad: int = 20,
) -> NDArray[np.bool_]:
    """The silhouette near ``start`` that the colours of ``image`` support.

    Parameters
    ----------
    image : (H, W, 3) uint8
        RGB.
    start : (H, W) array_like
        Non-zero inside the start silhouette (e.g. the snake's).
    disparity_mask : (H, W) array_like, optional
        The stereo stage's binarised disparity. Speckle is opened away and holes (poor
        texture) filled, but it is not closed: closing would fill the gaps between limbs.
        None: only ``reach`` bounds the band.
    grow : int, keyword-only
        Pixels the disparity mask is grown by before it bounds the subject (holes that
        open onto the outline).
    reach : int, keyword-only
        Pixels: nothing farther than this from ``start`` is subject.
    core : int, keyword-only
        Pixels: ``start`` (inside the disparity mask) eroded by this is subject for sure.
    iterations : int, keyword-only
        GrabCut iterations.
    pad : int, keyword-only
        Margin (pixels) of the crop the cut runs on, around the band.

    Returns
    -------
    (H, W) bool
        All False when ``start`` is empty.

    Raises
    ------
    InvalidInputError
        Shapes that disagree.
    """
    colour = np.asarray(image)
    if colour.ndim != 3 or colour.shape[2] != 3 or colour.dtype != np.uint8:
        raise InvalidInputError(f"image must be (H, W, 3) uint8, got {colour.shape} {colour.dtype}")
    seed = np.asarray(start) != 0
    if seed.shape != colour.shape[:2]:
        raise InvalidInputError(f"start must have the image's shape {colour.shape[:2]}, got {seed.shape}")
    if not seed.any():
        return seed
    allowed = cv2.dilate(seed.astype(np.uint8), _disk(reach)) != 0
    near = np.ones_like(seed)
    if disparity_mask is not None:
        raw = np.asarray(disparity_mask) != 0
        if raw.shape != seed.shape:
            raise InvalidInputError(f"disparity_mask must have the image's shape {seed.shape}, got {raw.shape}")
        if raw.any():
            near = clean_mask(raw, open_radius=2, close_radius=0, fill_holes=True, min_area=64)
            allowed &= cv2.dilate(near.astype(np.uint8), _disk(grow)) != 0
    sure = cv2.erode((seed & near).astype(np.uint8), _disk(core)) != 0
    rows, cols = np.nonzero(allowed)
    h, w = seed.shape
    y0, y1 = max(int(rows.min()) - pad, 0), min(int(rows.max()) + pad + 1, h)
    x0, x1 = max(int(cols.min()) - pad, 0), min(int(cols.max()) + pad + 1, w)
    crop = (slice(y0, y1), slice(x0, x1))
    # The cut runs on a crop around the band (the rest is background for sure anyway):
    # ~10x less work than the whole frame, and the crop's margin teaches the background's
    # colours near the subject rather than the whole scene's.
    out = np.zeros_like(seed)
    out[crop] = refine_silhouette(colour[crop], seed[crop], sure_foreground=sure[crop], region=allowed[crop], band=reach, iterations=iterations)
    return out
