"""The disparity-filtered gradient image of SPEC 8 (paper 002, section 4.2):
:func:`filtered_gradient`.

The gradient magnitude of the image keeps only pixels that the stereo stage's disparity
mask (binarised: a disparity was found within the reconstruction volume) marks as near,
after a morphological clean-up of that mask; a hysteresis threshold (Canny's two levels)
then keeps strong edges and the weak ones connected to them. What remains attracts the
active contour (:func:`elastocap.silhouettes.snake.snake_silhouette`).
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from skimage.filters import apply_hysteresis_threshold

from elastocap._core import InvalidInputError
from elastocap.silhouettes.background import clean_mask

__all__ = ["filtered_gradient", "gradient_magnitude"]


def gradient_magnitude(image: Any) -> NDArray[np.float64]:
    """Sobel gradient magnitude ``(H, W) float64`` of a grey ``(H, W)`` or colour
    ``(H, W, 3)`` uint8 image (colour: the largest over the channels, so an edge between
    colours of equal brightness counts), in grey levels per pixel."""
    array = np.asarray(image)
    if array.ndim not in (2, 3) or (array.ndim == 3 and array.shape[2] != 3):
        raise InvalidInputError(f"image must have shape (H, W) or (H, W, 3), got {array.shape}")
    data = array.astype(np.float32)
    gx = cv2.Sobel(data, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(data, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    magnitude = np.sqrt(gx * gx + gy * gy)
    if magnitude.ndim == 3:
        magnitude = magnitude.max(axis=2)
    return magnitude.astype(np.float64)


def filtered_gradient(
    image: Any,
    disparity_mask: Any = None,
    *,
    low: float = 4.0,
    high: float = 12.0,
    open_radius: int = 2,
    close_radius: int = 4,
    grow: int = 3,
    blur: float = 2.0,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The attraction image of the model-based silhouette snake.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8
    disparity_mask : (H, W) array_like, optional
        Non-zero where stereo found a disparity inside the reconstruction volume (the
        stereo stage's binarised disparity). Cleaned by an opening and a closing, then grown
        by ``grow`` pixels (the outline itself lies on the mask's edge, where disparities
        are least reliable). None: no filtering (a clean background).
    low, high : float, keyword-only
        Hysteresis thresholds on the gradient magnitude (grey levels per pixel): pixels
        above ``high``, and pixels above ``low`` connected to them, are edges.
    open_radius, close_radius : int, keyword-only
        Clean-up of the disparity mask (see :func:`~elastocap.silhouettes.clean_mask`).
    grow : int, keyword-only
        Pixels.
    blur : float, keyword-only
        Gaussian sigma (pixels) of the returned attraction: it widens the basin from which
        the snake is pulled to an edge.

    Returns
    -------
    attraction : (H, W) float64
        The kept edges' magnitude, blurred, scaled to a maximum of 1.
    edges : (H, W) bool
        The kept edge pixels.

    Raises
    ------
    InvalidInputError
        A disparity mask of another size than the image, ``low > high``.

    Notes
    -----
    Plänkers and Fua 2002 (paper 002), section 4.2: "by binarizing of the disparity map and
    cleaning it up using morphological operators ... applying the filter to the gradient
    image eliminates most parts of the background ... a hysteresis thresholding comparable
    to the one used in Canny's edge detector". An all-empty disparity mask leaves no edges
    (and an all-zero attraction): the caller decides what to do with a view stereo missed.
    """
    magnitude = gradient_magnitude(image)
    if not low <= high:
        raise InvalidInputError(f"low must not exceed high, got low={low}, high={high}")
    if disparity_mask is not None:
        near = np.asarray(disparity_mask) != 0
        if near.shape != magnitude.shape:
            raise InvalidInputError(f"disparity_mask must have the image's shape {magnitude.shape}, got {near.shape}")
        if near.any():
            near = clean_mask(near, open_radius=open_radius, close_radius=close_radius, fill_holes=True, min_area=64)
            if grow > 0:
                kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1))
                near = cv2.dilate(near.astype(np.uint8), kernel) != 0
        magnitude = np.where(near, magnitude, 0.0)
    edges = apply_hysteresis_threshold(magnitude, low, high)
    attraction = np.where(edges, magnitude, 0.0).astype(np.float32)
    if blur > 0:
        attraction = np.asarray(cv2.GaussianBlur(attraction, (0, 0), blur), dtype=np.float32)
    top = float(attraction.max())
    if top > 0:
        attraction /= top
    return attraction.astype(np.float64), edges
