"""The subject's colours learned over frames: :class:`ColourModel` and
:func:`appearance_silhouette`.

Each contour's colour cut (:func:`~elastocap.silhouettes.band.refine_in_band`) learns the
subject's colours from the contour it is given, in that frame only: a strip of a near
distractor glued to the subject by stereo and the snake is learned as subject and kept,
and the next frame starts from it; a head in front of a background of nearly its colour is
cut away. A colour model kept over frames remembers what the subject looked like where the
silhouettes were trusted (the mask's core where the fitted body model agrees), and what lay
just around it, so that one frame's mistake does not teach it. Per pixel, the log ratio of
the two colour histograms (smoothed over a few pixels: single pixels of the subject's
texture look like anything) then drops what is clearly background and restores what is
clearly subject where the model and stereo allow it.

Measured on the clutter scene (``benches/README.md``, branch sil5): a strip of a green
distractor glued along a figure dressed in blue and grey, over 26 of 30 frames of one view,
is what this stage removes; the figure's colours barely change under the scene's lighting
change between frames, which the decay of the histograms follows.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError

__all__ = ["ColourModel", "appearance_silhouette"]


def _disk(radius: int) -> NDArray[np.uint8]:
    return np.asarray(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1)), dtype=np.uint8)


def _checked_image(image: Any) -> NDArray[np.uint8]:
    colour = np.asarray(image)
    if colour.ndim != 3 or colour.shape[2] != 3 or colour.dtype != np.uint8:
        raise InvalidInputError(f"image must be (H, W, 3) uint8, got {colour.shape} {colour.dtype}")
    return colour


def _checked_mask(name: str, mask: Any, shape: tuple[int, ...]) -> NDArray[np.bool_]:
    m = np.asarray(mask) != 0
    if m.shape != shape:
        raise InvalidInputError(f"{name} must have the image's shape {shape}, got {m.shape}")
    return m


class ColourModel:
    """Colour histograms of a subject and of the background just around it, in one view,
    accumulated over frames with exponential forgetting.

    Parameters
    ----------
    bits : int, keyword-only
        Bits kept per RGB channel: ``2 ** (3 * bits)`` bins (4: 16 levels a channel, wide
        enough for the image noise and the subject's shading).
    decay : float, keyword-only
        Weight of the past at each update, in [0, 1) (0.8: about the last five frames).
    inner : int, keyword-only
        Pixels: the subject's colours are learned from its mask eroded by this (the outline
        is where the mask is least sure).
    ring : (int, int), keyword-only
        Pixels: the background's colours are learned from the ring between these distances
        outside the mask (the background the outline must be told from, not the scene's).
    """

    def __init__(self, *, bits: int = 4, decay: float = 0.8, inner: int = 3, ring: tuple[int, int] = (3, 15)) -> None:
        if not 1 <= int(bits) <= 8:
            raise InvalidInputError(f"bits must be in 1..8, got {bits}")
        if not 0.0 <= float(decay) < 1.0:
            raise InvalidInputError(f"decay must be in [0, 1), got {decay}")
        lo, hi = (int(r) for r in ring)
        if not 0 <= lo < hi or int(inner) < 0:
            raise InvalidInputError(f"ring must be two distances 0 <= near < far and inner >= 0, got ring={ring}, inner={inner}")
        self.bits, self.decay, self.inner, self.ring = int(bits), float(decay), int(inner), (lo, hi)
        self.subject = np.zeros(1 << (3 * self.bits))
        self.background = np.zeros_like(self.subject)

    @property
    def trained(self) -> bool:
        """Whether both histograms hold colours."""
        return bool(self.subject.sum() > 0 and self.background.sum() > 0)

    def _codes(self, image: NDArray[np.uint8]) -> NDArray[np.intp]:
        q = (image >> (8 - self.bits)).astype(np.intp)
        return np.asarray((q[..., 0] << (2 * self.bits)) | (q[..., 1] << self.bits) | q[..., 2])

    def update(self, image: Any, mask: Any, *, trusted: Any = None, background_trusted: Any = None) -> None:
        """Learn one frame: ``mask`` (non-zero = subject) of ``image`` ((H, W, 3) uint8).

        ``trusted`` (optional, (H, W)): the subject's colours are learned only inside it
        (e.g. the fitted model's silhouette, slightly grown), so that clutter the mask
        wrongly holds away from the model does not teach the subject's histogram.
        ``background_trusted`` (optional, (H, W)): the background's colours are learned
        only inside it (e.g. outside the fitted model's silhouette grown by a few pixels),
        so that a part of the subject the mask lost (a shoe) does not teach the background's
        histogram, which would drop it again on the next frames.
        """
        colour = _checked_image(image)
        m = _checked_mask("mask", mask, colour.shape[:2]).astype(np.uint8)
        codes = self._codes(colour)
        subject = cv2.erode(m, _disk(self.inner)) != 0 if self.inner else m != 0
        if trusted is not None:
            subject &= _checked_mask("trusted", trusted, colour.shape[:2])
        background = (cv2.dilate(m, _disk(self.ring[1])) != 0) & ~(cv2.dilate(m, _disk(self.ring[0])) != 0 if self.ring[0] else m != 0)
        if background_trusted is not None:
            background &= _checked_mask("background_trusted", background_trusted, colour.shape[:2])
        n = len(self.subject)
        self.subject = self.decay * self.subject + np.bincount(codes[subject], minlength=n)
        self.background = self.decay * self.background + np.bincount(codes[background], minlength=n)

    def log_ratio(self, image: Any, *, sigma: float = 1.5) -> NDArray[np.float32]:
        """Per pixel, log P(colour | subject) - log P(colour | background) (add-one
        smoothed histograms), Gaussian-smoothed over ``sigma`` pixels (0: none).

        Raises
        ------
        InvalidInputError
            Before the model has learned a frame with both subject and background.
        """
        colour = _checked_image(image)
        if not self.trained:
            raise InvalidInputError("the colour model has not learned a frame yet (update it with a mask first)")
        n = len(self.subject)
        table = np.log((self.subject + 1.0) / (self.subject.sum() + n)) - np.log((self.background + 1.0) / (self.background.sum() + n))
        ratio = table.astype(np.float32)[self._codes(colour)]
        return np.asarray(cv2.GaussianBlur(ratio, (0, 0), float(sigma)) if sigma > 0 else ratio)


def appearance_silhouette(
    mask: Any,
    log_ratio: Any,
    *,
    model_mask: Any = None,
    disparity_mask: Any = None,
    drop: float = -1.0,
    add: float = 1.0,
    opening: int = 1,
    restore_opening: int = 2,
    min_area: int = 50,
) -> NDArray[np.bool_]:
    """``mask`` corrected by a colour model's ``log_ratio`` (:meth:`ColourModel.log_ratio`).

    Drop: pixels of ``mask`` whose log ratio is below ``drop`` (the background's colours),
    opened by a disc of radius ``opening`` (a lone pixel of the subject's texture is not
    dropped). Restore: pixels outside ``mask`` with a log ratio above ``add``, inside both
    the fitted body model's silhouette and this view's stereo (``model_mask``,
    ``disparity_mask``: colour alone would take any background of the subject's colours),
    opened by a disc of radius ``restore_opening``. Pieces of fewer than ``min_area``
    pixels are dropped from both.

    Parameters
    ----------
    mask : (H, W) array_like
        The silhouette, non-zero = subject.
    log_ratio : (H, W) array_like of float
    model_mask, disparity_mask : (H, W) array_like, optional, keyword-only
        Without both, nothing is restored.
    drop, add : float, keyword-only
        Log-ratio thresholds (natural log), ``drop < add``.
    opening, restore_opening, min_area : int, keyword-only

    Returns
    -------
    (H, W) bool

    Raises
    ------
    InvalidInputError
        Shapes that disagree, a non-finite log ratio, ``drop >= add``.
    """
    m = np.asarray(mask) != 0
    ratio = np.asarray(log_ratio, dtype=np.float32)
    if ratio.shape != m.shape:
        raise InvalidInputError(f"log_ratio must have the mask's shape {m.shape}, got {ratio.shape}")
    if not np.isfinite(ratio).all():
        raise InvalidInputError("log_ratio holds non-finite values")
    if not float(drop) < float(add):
        raise InvalidInputError(f"drop must be below add, got drop={drop}, add={add}")
    removed = m & (ratio < float(drop))
    if opening > 0:
        removed = cv2.morphologyEx(removed.astype(np.uint8), cv2.MORPH_OPEN, _disk(int(opening))) != 0
    out = _drop_small(m & ~removed, min_area)
    if model_mask is not None and disparity_mask is not None:
        model = _checked_mask("model_mask", model_mask, m.shape)
        near = _checked_mask("disparity_mask", disparity_mask, m.shape)
        near = cv2.morphologyEx(near.astype(np.uint8), cv2.MORPH_OPEN, _disk(2)) != 0
        restored = model & near & ~out & (ratio > float(add))
        if restore_opening > 0:
            restored = cv2.morphologyEx(restored.astype(np.uint8), cv2.MORPH_OPEN, _disk(int(restore_opening))) != 0
        out |= _drop_small(restored, min_area)
    return out


def _drop_small(mask: NDArray[np.bool_], area: int) -> NDArray[np.bool_]:
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = stats[:, cv2.CC_STAT_AREA] >= int(area)
    keep[0] = False
    return np.asarray(keep[labels])
