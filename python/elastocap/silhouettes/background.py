"""Silhouettes: background subtraction against an empty-scene frame, thresholding of a dark
background, GrabCut refinement of a coarse mask (and its use on dark backgrounds), and
morphological clean-up of masks.

Masks stored in a capture folder are read with :meth:`elastocap.Capture.mask`.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_count

__all__ = [
    "clean_mask",
    "refine_silhouette",
    "segment_dark_background",
    "subtract_background",
    "threshold_dark_background",
]

# The automatic background-subtraction threshold is the median colour difference plus this
# many robust standard deviations (1.4826 MAD) of it, both taken over the pixels below the
# previous threshold (sigma clipping, so that the foreground does not inflate them): pixels
# beyond it are not explained by sensor noise.
NOISE_SIGMAS = 6.0
# Sigma-clipping rounds; the threshold settles in two or three.
CLIPPING_ROUNDS = 5
# ... and never below this CIE76 colour difference, about one just-noticeable difference
# (2.3), so that a noise-free synthetic background does not turn every rounding into
# foreground.
MIN_THRESHOLD = 2.5
_MAD_TO_SIGMA = 1.4826
# GrabCut's k-means initialisation of its colour models draws from OpenCV's RNG; a fixed
# seed makes the same image and seeds give the same mask (unseeded, a few boundary pixels
# of a 640 x 480 view change from call to call).
GRABCUT_SEED = 0
# Gaussian components per colour model in OpenCV's GrabCut (fixed in its implementation).
GRABCUT_COMPONENTS = 5


def subtract_background(
    image: Any,
    background: Any,
    *,
    threshold: float | None = None,
    lightness_weight: float = 1.0,
    blur_sigma: float = 0.0,
    open_radius: int = 1,
    close_radius: int = 2,
    fill_holes: bool = True,
    min_area: int = 64,
) -> NDArray[np.bool_]:
    """Foreground mask by difference to a static empty-scene frame.

    Parameters
    ----------
    image : (H, W, 3) uint8
        The frame, RGB (as :meth:`Capture.image` returns it). ``(H, W)`` grey is accepted.
    background : (H, W, 3) uint8
        The empty scene from the same camera, same size and channel order.
    threshold : float, optional, keyword-only
        Colour difference (CIE76 Delta E, Lab units: about 2.3 is just noticeable) above
        which a pixel is foreground. Default: automatic, ``median + 6 sigma`` of the
        difference image with ``sigma = 1.4826 MAD``, iterated over the pixels below the
        previous value (sigma clipping: the statistics of the background's noise, robust
        while most of the image is background), at least 2.5.
    lightness_weight : float, default 1.0, keyword-only
        Weight of the lightness difference against the two chroma differences. Below 1
        it makes soft shadows (darker, same hue) less likely to count as foreground.
    blur_sigma : float, default 0, keyword-only
        Gaussian blur (pixels) of both images before the difference, for very noisy
        images. It also spreads high-contrast edges, widening the silhouette by about
        ``blur_sigma`` pixels, so it is off by default: the clean-up removes the isolated
        noise pixels instead.
    open_radius, close_radius, fill_holes, min_area
        Clean-up, as in :func:`clean_mask`.

    Returns
    -------
    (H, W) bool
        True on the foreground.

    Notes
    -----
    The capture method of Choi et al. (CVPR 2006, section 4) starts from silhouettes of
    segmented videos; their Camel sequence was segmented by background subtraction and its
    visual hulls were noisy (section 5), hence the clean-up after the threshold.

    A static-background difference suits captures with an empty-scene frame per camera
    (``background/`` in a capture folder). ``cv2.createBackgroundSubtractorMOG2`` learns
    the background from a video instead; it needs many frames and adapts to a subject
    that stands still, so it is not used here. The difference is taken in CIE Lab, where
    Euclidean distance follows perceived colour difference better than in RGB, so one
    threshold fits dark and bright regions alike.
    """
    picture = _as_image("image", image)
    empty = _as_image("background", background)
    if picture.shape != empty.shape:
        raise InvalidInputError(
            f"image and background must have the same shape, got {picture.shape} and {empty.shape}"
        )
    weight = _non_negative("lightness_weight", lightness_weight)
    sigma = _non_negative("blur_sigma", blur_sigma)
    difference = _lab(picture, sigma) - _lab(empty, sigma)
    difference[:, :, 0] *= weight
    distance = np.sqrt(np.einsum("ijk,ijk->ij", difference, difference))
    if threshold is None:
        level = _noise_threshold(distance)
    else:
        level = _non_negative("threshold", threshold)
    return clean_mask(
        distance > level,
        open_radius=open_radius,
        close_radius=close_radius,
        fill_holes=fill_holes,
        min_area=min_area,
    )


def threshold_dark_background(
    image: Any,
    threshold: float = 30.0,
    *,
    blur_sigma: float = 1.0,
    open_radius: int = 0,
    close_radius: int = 0,
    fill_holes: bool = False,
    min_area: int = 0,
) -> NDArray[np.bool_]:
    """Foreground mask of an object in front of a black background.

    Parameters
    ----------
    image : (H, W, 3) or (H, W) uint8
        The frame (RGB or grey).
    threshold : float, default 30
        Grey level (0 to 255) above which a pixel is foreground, after the blur.
    blur_sigma : float, default 1.0, keyword-only
        Gaussian blur (pixels) before thresholding, so that single noisy pixels do not
        decide; 0 disables it.
    open_radius, close_radius, fill_holes, min_area
        Clean-up, as in :func:`clean_mask`; off by default.

    Returns
    -------
    (H, W) bool
        True where the (blurred) grey level exceeds ``threshold``.

    Notes
    -----
    For data such as Middlebury's temple and dino, lit objects on black cloth. There the
    default (30 after a 1-pixel blur) keeps all of the object, including its shadowed
    parts, but also some of the dimly lit cloth near the image borders; a missing
    object pixel carves the true shape from a visual hull while an extra background
    pixel only loosens it, so err on the low side.
    """
    picture = _as_image("image", image)
    grey = picture if picture.ndim == 2 else cv2.cvtColor(picture, cv2.COLOR_RGB2GRAY)
    sigma = _non_negative("blur_sigma", blur_sigma)
    level = _non_negative("threshold", threshold)
    smooth = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), sigma) if sigma > 0 else grey
    return clean_mask(
        np.asarray(smooth > level),
        open_radius=open_radius,
        close_radius=close_radius,
        fill_holes=fill_holes,
        min_area=min_area,
    )


def refine_silhouette(
    image: Any,
    mask: Any,
    *,
    sure_foreground: Any = None,
    region: Any = None,
    band: int = 15,
    iterations: int = 5,
) -> NDArray[np.bool_]:
    """GrabCut refinement of a coarse silhouette: keep what looks like the object.

    Parameters
    ----------
    image : (H, W, 3) or (H, W) uint8
        The frame, RGB (as :meth:`Capture.image` returns it) or grey.
    mask : (H, W) array_like of bool or integer
        The coarse silhouette (non-zero = probably foreground), e.g. a threshold or a
        background difference.
    sure_foreground : (H, W) array_like of bool or integer, optional, keyword-only
        Pixels that are certainly the object; they stay foreground and teach the colour
        model of the object. Default: none.
    region : (H, W) array_like of bool or integer, optional, keyword-only
        Where the object can be (e.g. the projection of a known bounding box); outside it
        every pixel is background. Default: the whole image.
    band : int, default 15, keyword-only
        Pixels of ``region`` outside ``mask`` and within this many pixels of it are probable
        background: the boundary may move out through them where they look like the
        object. Farther ones are sure background. 0: everything outside ``mask`` is sure
        background and refinement only removes pixels.
    iterations : int, default 5, keyword-only
        GrabCut rounds (refit the colour models, cut again); at least 1.

    Returns
    -------
    (H, W) bool
        The refined silhouette: it holds ``sure_foreground``, lies within ``region`` and
        within ``band`` pixels of ``mask``. When ``mask | sure_foreground`` (within
        ``region``) holds, or leaves out, fewer pixels than a colour model has components
        (5), there is nothing to learn from and it is returned as it is.

    Notes
    -----
    GrabCut (Rother, Kolmogorov and Blake, SIGGRAPH 2004; ``cv2.grabCut``) fits a Gaussian
    mixture of five components to the colours of the foreground and another to those of the
    background,
    labels each pixel by a minimum graph cut of the mixtures' log-likelihoods plus a
    contrast-weighted smoothness term, and iterates. So a region that passes a threshold
    but has the colour of the background (a fold of a dark cloth touching the object, a
    soft shadow on the floor) is dropped, while dark parts of the object that keep its hue
    are kept, and the boundary moves to the strongest nearby edge. The colours are taken
    in CIE Lab (8-bit, ``cv2.COLOR_RGB2Lab``), where lightness is apart from chroma and
    distances follow perceived differences. Letting the boundary move out into ``band``
    matters: the object's blurred rim and darkest parts fall below any threshold that
    keeps the background out (on the temple data of ``tests/test_hull.py``, keeping the
    result inside ``mask`` lowered the worst view's hull reprojection IoU from 0.973 to
    0.965). OpenCV's RNG is seeded (``GRABCUT_SEED``) for reproducible results.
    """
    picture = _as_image("image", image)
    shape = picture.shape[:2]
    candidate = _as_mask("mask", mask, shape)
    sure = _as_mask("sure_foreground", sure_foreground, shape) if sure_foreground is not None else None
    allowed = _as_mask("region", region, shape) if region is not None else None
    reach = _radius("band", band)
    rounds = as_count("iterations", iterations, minimum=1)
    if allowed is not None:
        candidate = candidate & allowed
        sure = sure & allowed if sure is not None else None
    if sure is not None:
        candidate = candidate | sure
    labels = np.full(shape, cv2.GC_BGD, np.uint8)
    if reach:
        near = cv2.dilate(candidate.astype(np.uint8), _disc(reach)).astype(bool)
        labels[near if allowed is None else near & allowed] = cv2.GC_PR_BGD
    labels[candidate] = cv2.GC_PR_FGD
    if sure is not None:
        labels[sure] = cv2.GC_FGD
    # Each colour model is a mixture fitted by k-means: it needs at least as many pixels as
    # components (nothing to refine when the mask is empty or covers everything).
    background = int(np.count_nonzero(~candidate))
    if min(int(np.count_nonzero(candidate)), background) < GRABCUT_COMPONENTS:
        return candidate
    rgb = picture if picture.ndim == 3 else cv2.cvtColor(picture, cv2.COLOR_GRAY2RGB)
    lab = np.ascontiguousarray(cv2.cvtColor(rgb, cv2.COLOR_RGB2Lab))
    background_model = np.zeros((1, 65), np.float64)
    foreground_model = np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(GRABCUT_SEED)
    no_rectangle = (0, 0, 0, 0)  # the labels initialise the cut, not a rectangle
    cv2.grabCut(lab, labels, no_rectangle, background_model, foreground_model, rounds, cv2.GC_INIT_WITH_MASK)
    kept = (labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)
    return np.asarray(kept, dtype=bool)


def segment_dark_background(
    image: Any,
    threshold: float = 30.0,
    *,
    region: Any = None,
    blur_sigma: float = 1.0,
    sure_erosion: int = 2,
    band: int = 15,
    iterations: int = 5,
    open_radius: int = 0,
    close_radius: int = 0,
    fill_holes: bool = False,
    min_area: int = 0,
) -> NDArray[np.bool_]:
    """Silhouette of an object in front of a dark background that is not uniformly black
    (a cloth with folds, dim props): a threshold proposes, GrabCut decides.

    Parameters
    ----------
    image : (H, W, 3) or (H, W) uint8
        The frame (RGB or grey; colour separates far better).
    threshold : float, default 30
        Grey level (0 to 255, after the blur) above which a pixel may be the object: set it
        low enough to take the object's shadowed parts, the refinement removes the
        background that also passes.
    region : (H, W) array_like of bool or integer, optional, keyword-only
        Where the object can be (e.g. the projection of its bounding box); outside it is
        background, and the Otsu level below is computed inside it. Default: whole image.
    blur_sigma : float, default 1.0, keyword-only
        Gaussian blur (pixels) before both thresholds; 0 disables it.
    sure_erosion : int, default 2, keyword-only
        Radius (pixels) by which the pixels brighter than the Otsu level are eroded to give
        the sure foreground, so that their mixed boundary pixels do not count as sure.
    band, iterations
        As in :func:`refine_silhouette`.
    open_radius, close_radius, fill_holes, min_area
        Clean-up of the result, as in :func:`clean_mask`; off by default.

    Returns
    -------
    (H, W) bool
        True on the object.

    Notes
    -----
    Three steps. (1) Candidates: blurred grey level above ``threshold`` inside ``region``,
    as :func:`threshold_dark_background`. (2) Sure foreground: grey level above Otsu's
    level (the threshold that best separates the grey levels of ``region`` into two
    classes, ``cv2.THRESH_OTSU``; at least ``threshold``), eroded by ``sure_erosion``: on a
    dark background the bright class is the lit object. (3) :func:`refine_silhouette`
    with these seeds, which drops candidates whose colour belongs to the background.

    On Middlebury's templeSparseRing (plaster on black cloth, see
    ``tests/test_hull.py``) a threshold of 48 was needed to keep the cloth's folds out,
    and it still let one fold through while cutting into the temple's shadowed
    undersides; with this refinement a threshold of 30 takes the undersides and leaves
    the cloth out, and the visual hull explains every view's silhouette better.
    """
    picture = _as_image("image", image)
    shape = picture.shape[:2]
    allowed = _as_mask("region", region, shape) if region is not None else np.ones(shape, bool)
    sigma = _non_negative("blur_sigma", blur_sigma)
    level = _non_negative("threshold", threshold)
    erosion = _radius("sure_erosion", sure_erosion)
    grey = picture if picture.ndim == 2 else cv2.cvtColor(picture, cv2.COLOR_RGB2GRAY)
    smooth = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), sigma) if sigma > 0 else grey.astype(np.float32)
    candidate = (smooth > level) & allowed
    if not candidate.any():
        return candidate
    inside = np.clip(np.round(smooth[allowed]), 0, 255).astype(np.uint8).reshape(-1, 1)
    otsu, _ = cv2.threshold(inside, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    sure = (smooth > max(float(otsu), level)) & allowed
    if erosion:
        sure = cv2.erode(sure.astype(np.uint8), _disc(erosion)).astype(bool)
    refined = refine_silhouette(
        picture, candidate, sure_foreground=sure, region=allowed, band=band, iterations=iterations
    )
    return clean_mask(
        refined,
        open_radius=open_radius,
        close_radius=close_radius,
        fill_holes=fill_holes,
        min_area=min_area,
    )


def clean_mask(
    mask: Any,
    *,
    open_radius: int = 1,
    close_radius: int = 2,
    fill_holes: bool = True,
    min_area: int = 64,
) -> NDArray[np.bool_]:
    """Morphological clean-up of a silhouette.

    Parameters
    ----------
    mask : (H, W) array_like of bool or integer
        Non-zero = foreground.
    open_radius : int, default 1, keyword-only
        Radius (pixels) of the elliptical opening (erode, then dilate) that removes specks
        and hairlines thinner than about ``2 * open_radius + 1``; 0 disables it.
    close_radius : int, default 2, keyword-only
        Radius (pixels) of the elliptical closing (dilate, then erode) that bridges gaps
        and cracks narrower than about ``2 * close_radius + 1``; 0 disables it.
    fill_holes : bool, default True, keyword-only
        Fill background regions that do not touch the image border.
    min_area : int, default 64, keyword-only
        Drop foreground components (8-connected) of fewer pixels; 0 keeps all.

    Returns
    -------
    (H, W) bool
        The cleaned mask. The steps run in the order listed.

    Notes
    -----
    Hole filling floods the background from a one-pixel border added around the image
    (``cv2.floodFill``), so every background region connected to the border survives,
    whatever part of the border it touches. It also fills genuine holes of a shape (the
    space between an arm and the body when both touch); leave it off where they matter.
    """
    array = np.asarray(mask)
    if array.ndim != 2 or array.size == 0:
        raise InvalidInputError(f"mask must have shape (H, W), got {array.shape}")
    if array.dtype.kind not in "biu":
        raise InvalidInputError(f"mask must hold booleans or integers, got dtype {array.dtype}")
    opening = _radius("open_radius", open_radius)
    closing = _radius("close_radius", close_radius)
    smallest = _radius("min_area", min_area)
    current = (array != 0).astype(np.uint8)
    if opening:
        current = cv2.morphologyEx(current, cv2.MORPH_OPEN, _disc(opening))
    if closing:
        # Pad so that closing does not glue the silhouette to the image border.
        padded = cv2.copyMakeBorder(current, closing, closing, closing, closing, cv2.BORDER_CONSTANT, value=0)
        padded = cv2.morphologyEx(padded, cv2.MORPH_CLOSE, _disc(closing))
        current = np.ascontiguousarray(padded[closing:-closing, closing:-closing])
    if fill_holes:
        current = _fill_holes(current)
    if smallest > 1:
        _, labels, stats, _ = cv2.connectedComponentsWithStats(current, connectivity=8)
        keep = stats[:, cv2.CC_STAT_AREA] >= smallest
        keep[0] = False  # label 0 is the background
        current = keep[labels].astype(np.uint8)
    return np.asarray(current, dtype=bool)


def _noise_threshold(distance: NDArray[np.float32]) -> float:
    """``median + NOISE_SIGMAS * 1.4826 MAD`` of ``distance``, sigma-clipped, at least
    ``MIN_THRESHOLD``."""
    values = distance.ravel()
    level = float("inf")
    for _ in range(CLIPPING_ROUNDS):
        below = values[values <= level]
        if below.size == 0:
            break
        median = float(np.median(below))
        mad = float(np.median(np.abs(below - median)))
        updated = median + NOISE_SIGMAS * _MAD_TO_SIGMA * mad
        if updated == level:
            break
        level = updated
    return max(level, MIN_THRESHOLD)


def _fill_holes(mask: NDArray[np.uint8]) -> NDArray[np.uint8]:
    padded = cv2.copyMakeBorder(mask, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    flood = np.zeros((padded.shape[0] + 2, padded.shape[1] + 2), np.uint8)
    reached = padded.copy()
    cv2.floodFill(reached, flood, (0, 0), 1)
    # Reached = foreground or border-connected background; the rest are holes.
    holes = reached[1:-1, 1:-1] == 0
    return np.asarray(mask | holes, dtype=np.uint8)


def _disc(radius: int) -> NDArray[np.uint8]:
    return np.asarray(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1)))


def _lab(image: NDArray[np.uint8], sigma: float) -> NDArray[np.float32]:
    """CIE Lab (L in 0..100, a and b in about -128..127) of an RGB or grey uint8 image."""
    rgb = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
    scaled = rgb.astype(np.float32) / np.float32(255.0)
    if sigma > 0:
        scaled = np.asarray(cv2.GaussianBlur(scaled, (0, 0), sigma), dtype=np.float32)
    return np.asarray(cv2.cvtColor(scaled, cv2.COLOR_RGB2Lab), dtype=np.float32)


def _as_image(name: str, value: Any) -> NDArray[np.uint8]:
    array = np.asarray(value)
    if array.dtype != np.uint8:
        raise InvalidInputError(f"{name} must be uint8, got dtype {array.dtype}")
    if not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] == 3)) or array.size == 0:
        raise InvalidInputError(f"{name} must have shape (H, W, 3) or (H, W), got {array.shape}")
    return np.ascontiguousarray(array)


def _as_mask(name: str, value: Any, shape: tuple[int, ...]) -> NDArray[np.bool_]:
    array = np.asarray(value)
    if array.dtype.kind not in "biu":
        raise InvalidInputError(f"{name} must hold booleans or integers, got dtype {array.dtype}")
    if array.shape != shape:
        raise InvalidInputError(f"{name} must have the image's shape {shape}, got {array.shape}")
    return np.asarray(array != 0, dtype=bool)


def _non_negative(name: str, value: Any) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a number, got {value!r}") from None
    if not (np.isfinite(number) and number >= 0):
        raise InvalidInputError(f"{name} must be a non-negative finite number, got {value!r}")
    return number


def _radius(name: str, value: Any) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 0:
        raise InvalidInputError(f"{name} must be a non-negative integer, got {value!r}")
    return int(value)
