"""Each static camera's background learned by the silhouette loop itself:
:class:`LearnedBackground` and :func:`background_outline`.

The cameras do not move, so a pixel the loop has confirmed as background (outside the
fitted body model's silhouette, grown by a margin) shows the same thing on the next frames
unless something moves over it. Per pixel the model keeps a running mean of the colours
seen there while confirmed, and how many consecutive confirmations agreed with it: a
moving distractor passing over the pixel, or a limb the model missed, disagrees and
restarts the count, so only what stayed put is trusted. The light changes smoothly over the take (it dims, a band sweeps
across the views); the model stores colours under its own reference light and, per frame,
estimates a smooth gain field from the pixels confirmed now, by normalised convolution.

Near the silhouette's outline the colour models (:mod:`~elastocap.silhouettes.appearance`,
the band cut) cannot tell a dark-clad figure from dark clutter behind it: dark against
dark, the outline comes out 1-3 px too fat, and the colour model over frames then learns
the strip as the subject's (``benches/README.md``, branches sil6, sil7). Against the learned
background the question per pixel is not "subject-like or background-like colour" but "is
this the very colour this pixel shows when nothing is in front of it", which dark clutter
answers as well as bright. This is not the sequence's median image (which a slow
distractor and the light change defeat): only pixels the loop confirmed teach it, and a
pixel is used only once its colour held still over several confirmations.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError

__all__ = ["LearnedBackground", "background_outline"]


def _disk(radius: int) -> NDArray[np.uint8]:
    return np.asarray(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1)), dtype=np.uint8)


def _checked_image(image: Any, shape: tuple[int, int] | None) -> NDArray[np.float32]:
    colour = np.asarray(image)
    if colour.ndim != 3 or colour.shape[2] != 3 or colour.dtype != np.uint8:
        raise InvalidInputError(f"image must be (H, W, 3) uint8, got {colour.shape} {colour.dtype}")
    if shape is not None and colour.shape[:2] != shape:
        raise InvalidInputError(f"image must keep the view's shape {shape}, got {colour.shape[:2]}")
    return colour.astype(np.float32)


def _norm(x: NDArray[np.float32]) -> NDArray[np.float32]:
    """Per pixel, the length of an (H, W, 3) colour difference: the three channels summed
    in the order ``np.linalg.norm(x, axis=2)`` sums them (the same values), without its
    strided reduction over the last axis (most of this module's cost after the blurs)."""
    return np.asarray(np.sqrt(x[..., 0] * x[..., 0] + x[..., 1] * x[..., 1] + x[..., 2] * x[..., 2]), dtype=np.float32)


def _brightness(x: NDArray[np.float32]) -> NDArray[np.float32]:
    return np.asarray(x[..., 0] + x[..., 1] + x[..., 2], dtype=np.float32)


def _checked_mask(name: str, mask: Any, shape: tuple[int, ...]) -> NDArray[np.bool_]:
    m = np.asarray(mask) != 0
    if m.shape != shape:
        raise InvalidInputError(f"{name} must have the image's shape {shape}, got {m.shape}")
    return m


class LearnedBackground:
    """One static view's background, learned from the pixels confirmed as background.

    Parameters
    ----------
    tolerance : float, keyword-only
        RGB distance (0-255 units, under the reference light) within which a confirmed
        colour agrees with the pixel's mean; beyond it the pixel restarts from the new
        colour (something moved there). 20: a few times the sensor noise (3 a channel),
        well under the step of a distractor's edge.
    memory : int, keyword-only
        The mean averages at most this many confirmations (a running mean that keeps
        following slow changes the gain field does not explain).
    confirmations : int, keyword-only
        Consecutive agreeing confirmations before the pixel is trusted.
    gain_sigma : float, keyword-only
        Pixels: the light's gain field is smoothed over this (the light varies slowly
        across the view; the subject hides up to a few tens of pixels of it, filled from
        around). 12: a band of light ~40 px wide is followed (20 blurs it, 5 is noisy).
    gain_scale : int, keyword-only
        The gain field is estimated on a grid this many times coarser and interpolated
        back (1: at full resolution). 4: a coarse pixel is a third of ``gain_sigma``.
    """

    def __init__(self, *, tolerance: float = 20.0, memory: int = 8, confirmations: int = 3, gain_sigma: float = 12.0, gain_scale: int = 4) -> None:
        if not float(tolerance) > 0 or not int(memory) >= 1 or not int(confirmations) >= 1 or not float(gain_sigma) > 0 or not int(gain_scale) >= 1:
            raise InvalidInputError(f"tolerance and gain_sigma must be > 0, memory, confirmations and gain_scale >= 1; got tolerance={tolerance}, memory={memory}, confirmations={confirmations}, gain_sigma={gain_sigma}, gain_scale={gain_scale}")
        self.tolerance, self.memory, self.confirmations, self.gain_sigma = float(tolerance), int(memory), int(confirmations), float(gain_sigma)
        self.gain_scale = int(gain_scale)
        self.mean: NDArray[np.float32] | None = None
        self.count: NDArray[np.int32] | None = None

    @property
    def shape(self) -> tuple[int, int] | None:
        """(H, W) of the view once it has learned a frame."""
        return None if self.mean is None else (self.mean.shape[0], self.mean.shape[1])

    def trusted(self) -> NDArray[np.bool_]:
        """Pixels whose background colour held over :attr:`confirmations` confirmations."""
        if self.count is None:
            raise InvalidInputError("the learned background has not learned a frame yet (update it first)")
        return np.asarray(self.count >= self.confirmations)

    def gain(self, image: Any, support: Any) -> NDArray[np.float32]:
        """The light's gain field of ``image`` against the reference light, (H, W).

        Estimated where the pixel is trusted and in ``support`` (pixels known to show
        background in ``image``): the ratio of the summed brightness of image and mean,
        both blurred over :attr:`gain_sigma` (normalised convolution, so dark pixels weigh
        less and the subject's gap is filled from around it); pixels far off the first
        estimate (a distractor over them now) are left out of a second. Where no support
        is near, the median ratio of the whole view; 1 without any support.
        """
        colour = _checked_image(image, self.shape)
        return self._gain(colour, _checked_mask("support", support, colour.shape[:2]))

    def _gain(self, colour: NDArray[np.float32], support: NDArray[np.bool_]) -> NDArray[np.float32]:
        if self.mean is None:
            raise InvalidInputError("the learned background has not learned a frame yet (update it first)")
        use = self.trusted() & support
        now, ref = _brightness(colour), _brightness(self.mean)
        ok = use & (ref > 15.0)
        if ok.sum() < 50:
            return np.ones(colour.shape[:2], dtype=np.float32)
        overall = float(np.median(now[ok] / ref[ok]))
        field = np.full(colour.shape[:2], overall, dtype=np.float32)
        for _ in range(2):
            w = ok.astype(np.float32)
            num, den, weight = (self._blur(x) for x in (now * w, ref * w, w))
            # Where the support is too thin the blurred ratio is noise: the view's median.
            small = np.where(weight > 0.05, num / np.maximum(den, 1e-3), overall).astype(np.float32)
            field = self._full(small, colour.shape[:2])
            ok = ok & (np.abs(now / np.maximum(ref, 1e-3) / field - 1.0) < 0.15)
        return field

    def _blur(self, x: NDArray[np.float32]) -> NDArray[np.float32]:
        """``x`` blurred over :attr:`gain_sigma`, at 1 / :attr:`gain_scale` resolution.

        The field is smooth (sigma 12 px) so it is blurred on a grid ``gain_scale`` times
        coarser: each coarse pixel the mean of its block (an area average, so a sum over
        the support is kept), then a blur of ``gain_sigma / gain_scale`` there. The three
        full-size blurs were most of the loop's ~61 CPU ms per view and frame (sil7)."""
        s = self.gain_scale
        if s == 1:
            return np.asarray(cv2.GaussianBlur(x, (0, 0), self.gain_sigma))
        h, w = x.shape
        small = cv2.resize(x, (max(1, -(-w // s)), max(1, -(-h // s))), interpolation=cv2.INTER_AREA)
        return np.asarray(cv2.GaussianBlur(small, (0, 0), self.gain_sigma / s))

    def _full(self, field: NDArray[np.float32], shape: tuple[int, int]) -> NDArray[np.float32]:
        if field.shape == shape:
            return field
        return np.asarray(cv2.resize(field, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR), dtype=np.float32)

    def _checked_gain(self, gain: Any, shape: tuple[int, ...]) -> NDArray[np.float32]:
        g = np.asarray(gain, dtype=np.float32)
        if g.shape != shape or not (np.isfinite(g).all() and (g > 0).all()):
            raise InvalidInputError(f"gain must be a finite, positive (H, W) field of the image's shape {shape}, got shape {g.shape}")
        return g

    def distance(self, image: Any, support: Any, *, gain: Any = None) -> NDArray[np.float32]:
        """Per pixel, the RGB distance of ``image`` from the learned background under this
        frame's light (:meth:`gain` from ``support``, unless given: the loop computes it
        once a frame for this and :meth:`update`); ``inf`` where not trusted."""
        colour = _checked_image(image, self.shape)
        if gain is None:
            gain = self._gain(colour, _checked_mask("support", support, colour.shape[:2]))
        else:
            gain = self._checked_gain(gain, colour.shape[:2])
        assert self.mean is not None
        d = _norm(colour - gain[..., None] * self.mean)
        return np.where(self.trusted(), d, np.float32(np.inf))

    def update(self, image: Any, confirmed: Any, *, gain: Any = None) -> None:
        """Learn one frame: ``confirmed`` (H, W) marks the pixels known to show background.

        ``gain``: this frame's :meth:`gain` with ``confirmed`` as its support, when already
        computed (the same model and support give the same field).

        A confirmed pixel whose colour (under the reference light) lies within
        :attr:`tolerance` of its mean is averaged in and its count grows; otherwise it
        restarts from this colour with a count of 1. Unconfirmed pixels keep their model.
        """
        colour = _checked_image(image, self.shape)
        seen = _checked_mask("confirmed", confirmed, colour.shape[:2])
        if self.mean is None or self.count is None:
            self.mean = colour.copy()
            self.count = seen.astype(np.int32)
            return
        field = self._gain(colour, seen) if gain is None else self._checked_gain(gain, colour.shape[:2])
        x = colour / field[..., None]
        close = _norm(x - self.mean) < self.tolerance
        agree = seen & close & (self.count > 0)
        restart = seen & ~agree
        step = 1.0 / np.minimum(self.count + 1, self.memory).astype(np.float32)
        self.mean = np.where(agree[..., None], self.mean + step[..., None] * (x - self.mean), self.mean).astype(np.float32)
        self.mean[restart] = x[restart]
        self.count = np.where(agree, self.count + 1, np.where(restart, 1, self.count)).astype(np.int32)


def background_outline(
    mask: Any,
    distance: Any,
    *,
    band: int = 3,
    match: float = 15.0,
    sigma: float = 0.0,
) -> NDArray[np.bool_]:
    """``mask`` with the pixels of its outline that show the learned background removed.

    A pixel of ``mask`` within ``band`` pixels of its outline whose ``distance``
    (:meth:`LearnedBackground.distance`, smoothed over ``sigma`` pixels so that one noisy
    pixel does not decide) is below ``match`` is dropped. Only the outline: inside, a
    subject that happens to match the background at a few pixels is not holed, and what the
    mask holds far from the subject is the colour model's to judge.

    Parameters
    ----------
    mask : (H, W) array_like
        The silhouette, non-zero = subject.
    distance : (H, W) array_like of float
        ``inf`` where the background is not known.
    band : int, keyword-only
    match : float, keyword-only
        RGB distance, 0-255 units.
    sigma : float, keyword-only
        Pixels (0: none).

    Returns
    -------
    (H, W) bool

    Raises
    ------
    InvalidInputError
        Shapes that disagree, a NaN distance, ``band < 1`` or ``match <= 0``.
    """
    m = np.asarray(mask) != 0
    d = np.asarray(distance, dtype=np.float32)
    if d.shape != m.shape:
        raise InvalidInputError(f"distance must have the mask's shape {m.shape}, got {d.shape}")
    if np.isnan(d).any():
        raise InvalidInputError("distance holds NaN")
    if int(band) < 1 or not float(match) > 0:
        raise InvalidInputError(f"band must be >= 1 and match > 0, got band={band}, match={match}")
    known = np.isfinite(d)
    if sigma > 0:
        # Normalised smoothing over the known pixels only: an unknown neighbour must not
        # make a pixel look like (or unlike) the background.
        w = known.astype(np.float32)
        num = cv2.GaussianBlur(np.where(known, d, 0).astype(np.float32), (0, 0), float(sigma))
        den = cv2.GaussianBlur(w, (0, 0), float(sigma))
        d = np.where(known & (den > 1e-3), num / np.maximum(den, 1e-3), np.inf).astype(np.float32)
    inner = cv2.erode(m.astype(np.uint8), _disk(int(band))) != 0
    return np.asarray(m & ~(~inner & (d < float(match))))
