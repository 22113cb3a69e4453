"""Least-squares matching (Gruen 1985): sub-pixel, affine and radiometric correspondence of
image patches in one or several search images, with a precision estimate for every match.

The heavy loop runs in the Rust core (``elastocap._core.lsm_match_patches``), batched over
points in parallel with the GIL released; this module validates the input, picks defaults
from the data and wraps the arrays in :class:`Matches`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from enum import IntEnum
from typing import Any, NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap import _core
from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_float_array, as_positive

__all__ = ["MatchStatus", "Matches", "PARAMETERS", "Refined", "match_patches", "noise_level"]

#: Parameters per search image in :attr:`Matches.covariance`, in this order.
PARAMETERS = ("u", "v", "a11", "a12", "a21", "a22", "gain", "offset")

# The default least texture, as a multiple of the template image's noise level: pure noise
# has an RMS gradient of about 0.7 sigma along its weakest direction (central differences
# of white noise), so 2 sigma leaves a margin and still lets through patches whose shift
# is determined to about 0.1 px at size 11.
TEXTURE_OVER_NOISE = 2.0


class MatchStatus(IntEnum):
    """Why a match ended (the codes of :attr:`Matches.status`)."""

    #: The update of the matched centre fell below ``tolerance``.
    CONVERGED = 0
    #: The estimate ran away: it moved more than ``max_shift`` from its start, the affine
    #: map's scale left ``[1 / max_scale, max_scale]`` (or it turned into a reflection),
    #: the gain became non-positive, or a value became non-finite.
    DIVERGED = 1
    #: The template patch (with a one-pixel border for its gradients) or the warped search
    #: patch reaches outside its image.
    LEFT_IMAGE = 2
    #: Too little texture: the template patch's RMS gradient along its weakest direction is
    #: below ``min_texture``, or the normal equations are singular.
    LOW_TEXTURE = 3
    #: ``max_iterations`` ran out before convergence (the estimate and its covariance are
    #: still reported).
    MAX_ITERATIONS = 4
    #: Converged, but a poor match (SPEC 7's rejection): ``sigma0`` above ``max_sigma0`` or
    #: the correlation below ``min_correlation``. A Gauss-Newton run that settles on a false
    #: minimum stops as quietly as a good one; its residual gives it away (the estimate and
    #: its covariance are still reported).
    REJECTED = 5


class Refined(IntEnum):
    """What ``match_patches(refine=)``'s richer stage did for a match (:attr:`Matches.refined`)."""

    #: No richer stage: not asked for, an epipolar line, or the affine match did not converge.
    NO = 0
    #: The richer model ran; its outcome is reported.
    REPORTED = 1
    #: The richer model did not converge; the affine match is reported (``"fallback"``).
    FELL_BACK = 2
    #: Skipped: the affine match's correlation reached ``"skip_correlation"``; it is reported.
    SKIPPED = 3


class Matches(NamedTuple):
    """Result of :func:`match_patches` for N points and S search images.

    Attributes
    ----------
    status : (N, S) uint8
        :class:`MatchStatus` codes per point and search image.
    positions : (N, S, 2) float64
        The matched centres ``(u, v)`` in each search image, pixels. For matches that did
        not converge: the last estimate (or the start).
    affine : (N, S, 2, 3) float64
        The maps from template patch offsets to search pixels: offset ``(dx, dy)`` from the
        template point goes to ``affine[..., :2] @ (dx, dy) + affine[..., 2]``, so the last
        column equals ``positions``.
    gain, offset : (N, S) float64
        Radiometric parameters: ``template ≈ offset + gain * search`` (grey levels).
    sigma0 : (N, S) float64
        A posteriori standard deviation of unit weight: the RMS residual grey level with
        the redundancy (pixels - 8, + 1 with a line constraint) as divisor. NaN without an
        estimate.
    covariance : (N, 8S, 8S) float64
        Joint covariance of all search images' parameters, per point; search image ``s``
        occupies rows and columns ``8s .. 8s + 8`` in the order of :data:`PARAMETERS`
        (``u, v, a11, a12, a21, a22, gain, offset``). Blocks between search images are the
        correlation the shared template induces. It is the sandwich ``sigma0^2 B^-1 meat
        B^-T`` (``B = G^T H``, the template's gradients against the warped search patch's),
        which stays honest on faint texture where the template's noisy gradients made
        ``sigma0^2 (G^T G)^-1`` too small (benches/README). Rows and columns of matches
        without an estimate are NaN.
    correlation : (N, S) float64
        Normalised cross-correlation of the template patch and the resampled search patch
        at the final estimate.
    iterations : (N, S) uint32
        Gauss-Newton iterations run.
    affine_centre : (N, S, 2) float64
        With ``refine``: the converged affine match's centre the richer stage started from
        (the centre ``match_patches`` without ``refine`` reports), NaN where the affine
        match did not converge; NaN without ``refine``.
    refined : (N, S) uint8
        :class:`Refined` codes: what the richer stage did.
    """

    status: NDArray[np.uint8]
    positions: NDArray[np.float64]
    affine: NDArray[np.float64]
    gain: NDArray[np.float64]
    offset: NDArray[np.float64]
    sigma0: NDArray[np.float64]
    covariance: NDArray[np.float64]
    correlation: NDArray[np.float64]
    iterations: NDArray[np.uint32]
    affine_centre: NDArray[np.float64] | None = None
    refined: NDArray[np.uint8] | None = None

    @property
    def converged(self) -> NDArray[np.bool_]:
        """(N, S) bool: where the status is :attr:`MatchStatus.CONVERGED`."""
        return np.asarray(self.status == MatchStatus.CONVERGED)

    def position_covariance(self) -> NDArray[np.float64]:
        """(N, 2S, 2S) float64: the joint covariance of the matched centres, search image
        ``s`` at rows ``2s, 2s + 1`` (``u``, ``v``), pixels squared."""
        n, width, _ = self.covariance.shape
        rows = (np.arange(width // 8)[:, None] * 8 + np.arange(2)).ravel()
        return np.ascontiguousarray(self.covariance[:, rows[:, None], rows[None, :]]).reshape(n, len(rows), len(rows))


def match_patches(
    template: Any,
    points: Any,
    search_images: Any,
    *,
    size: int = 11,
    initial: Any = None,
    epipolar: Any = None,
    epipolar_sigma: float = 0.0,
    max_iterations: int = 30,
    tolerance: float = 0.01,
    max_shift: float | None = None,
    max_scale: float = 3.0,
    min_texture: float | None = None,
    max_sigma0: float | None = None,
    min_correlation: float | None = None,
    interpolation: str = "bicubic",
    threads: int | None = None,
    weights: Any = None,
    refine: Mapping[str, Any] | None = None,
) -> Matches:
    """Find the patch around each point of the template image in the search images by
    least-squares matching.

    Parameters
    ----------
    template : (H, W) array_like, uint8, uint16 or float
        The template image (grey levels).
    points : (N, 2) array_like of float
        Patch centres ``(u, v)`` in the template image, pixels (column, row; origin at
        the centre of the top-left pixel). Sub-pixel positions are resampled as the search
        images are (``interpolation``).
    search_images : (H_s, W_s) array_like, or a sequence of S of them
        The images to search (grey levels, any of the template's dtypes; their sizes may
        differ from the template's and from each other).
    size : int, optional, keyword-only
        Side of the square template patch, pixels; odd, 3 to 255. Default 11.
    initial : array_like of float, optional, keyword-only
        Where to start in each search image: ``(N, S, 2)`` centres ``(u, v)`` (the affine
        part starts as the identity), or ``(N, S, 2, 3)`` affine maps as in
        :attr:`Matches.affine`. With one search image ``(N, 2)`` and ``(N, 2, 3)`` are
        accepted. Default: the template point itself in every search image.
    epipolar : array_like of float, optional, keyword-only
        ``(N, S, 3)`` (or ``(N, 3)`` with one search image) line coefficients
        ``(a, b, c)``: the matched centre is held on ``a u + b v + c = 0`` in search
        pixels (geometrically constrained matching). A row that is NaN or has
        ``a = b = 0`` leaves that match free. The start is projected onto the line.
    epipolar_sigma : float, optional, keyword-only
        0 (default): the line is a hard constraint. Positive: a soft one, the distance to
        the line being an observation with this standard deviation (pixels).
    max_iterations : int, optional, keyword-only
        Gauss-Newton iterations per search image. Default 30.
    tolerance : float, optional, keyword-only
        Convergence: the update of the matched centre is shorter than this, pixels (SPEC 7),
        and no entry of the affine map's linear part changes by more than this (pixels per
        pixel; a small centre update alone can come by chance while the shape is still off).
        Default 0.01.
    max_shift : float, optional, keyword-only
        Diverged when the centre moves further than this from its start, pixels. Default
        ``size / 2``.
    max_scale : float, optional, keyword-only
        Diverged when a singular value of the affine map (relative to its start) leaves
        ``[1 / max_scale, max_scale]``. Default 3.
    min_texture : float, optional, keyword-only
        Least RMS gradient (grey levels per pixel) of the template patch along its
        weakest direction; below it a point is :attr:`MatchStatus.LOW_TEXTURE`. Default:
        twice the template image's noise level (Immerkær's estimator, a robust figure of
        the image's white-noise standard deviation).
    max_sigma0 : float, optional, keyword-only
        Converged matches whose ``sigma0`` (grey levels) exceeds this become
        :attr:`MatchStatus.REJECTED`. Default: no limit. A correct match leaves the two
        images' noise, ``sigma0 ~ sqrt(sigma_T^2 + gain^2 sigma_S^2)``; three times that
        (``3 * sqrt(2) * noise_level(template)`` for images from one sensor) keeps every
        correct match of the accuracy benchmark and drops every false minimum there (their
        ``sigma0`` is 7-11 times the noise; benches/README.md, "LSM: SPEC 7's rejection").
    min_correlation : float, optional, keyword-only
        Converged matches whose correlation is below this become
        :attr:`MatchStatus.REJECTED`. Default: no limit. It depends on the texture's
        contrast against the noise (faint texture at noise 2 correlates ~0.75 when right),
        so ``max_sigma0`` is the safer test.
    interpolation : {"bicubic", "bilinear"}, optional, keyword-only
        Resampling of the search images (and of sub-pixel template points). ``"bilinear"``
        is SPEC 7's; it damps and shifts the phase of texture near the Nyquist frequency,
        which biases positions by ~0.02 px on sharp texture (benches/README.md), so the
        default is ``"bicubic"`` (Keys' cubic convolution, a = -1/2; the patch must keep
        one more pixel inside the image).
    threads : int, optional, keyword-only
        Worker threads (default: all cores, or ``RAYON_NUM_THREADS``).
    weights : (H, W) array_like of float or bool, optional, keyword-only
        Per-pixel weights of the template image (its shape; values clamped to [0, 1],
        read bilinearly at the patch's pixels): weighted least squares,
        ``sum_x w(x) (T(x) - r0 - r1 S(A x + b))^2``. A silhouette mask as weights makes a
        patch on the edge of a moving body follow the body, not the background in its
        corner. The correlation, ``sigma0`` (redundancy ``sum w - 8``) and the texture
        measure are weighted too; a patch whose total weight is below 16 is
        :attr:`MatchStatus.LOW_TEXTURE`, one whose weights are all 1 is matched exactly as
        without weights. The covariance of a weighted patch is ``sigma0^2 (G^T W G)^-1``
        (the template's noise is not propagated). Default: every pixel weighs 1.
    refine : mapping, optional, keyword-only
        A richer model for matches that converged (ignored where an epipolar line
        applies): Gauss-Newton from the converged affine match (staged: the extra unknowns
        start at zero from a settled centre and shape) on
        ``sum_x w(x) (T(x) - r0 - G(x) S(W(x)))^2``. Keys (all optional):
        ``"iterations"`` (int >= 1, default 10), ``"warp"`` (``"affine"``,
        ``"projective"``: ``b + A x / (1 + p1 xi + p2 eta)``, or ``"quadratic"``:
        ``b + A x`` plus ``xi^2``, ``xi eta``, ``eta^2`` terms per coordinate; ``xi, eta``
        the offsets over the patch's half-width; default ``"quadratic"``),
        ``"gain_gradient"`` (bool, ``G = g0 + gx xi + gy eta``; default True),
        ``"warp_sigma"`` (px at the patch's edge) and ``"gain_sigma"`` (fraction of the
        gain): standard deviations of zero-mean priors on the extra terms, 0 = none
        (default 0), ``"fallback"`` (bool: where the richer model does not converge,
        report the affine match; default False), ``"jacobian"`` (``"search"``: the
        search image's gradients at the warped points, the update added; ``"template"``:
        the template's gradients, the update composed on the template side as in the
        affine loop; default ``"search"``), ``"skip_correlation"`` (no richer stage
        where the affine match's correlation is at least this, the affine match
        reported; default inf: never skipped). Every extra term vanishes at the
        template point, so the position keeps its meaning; :attr:`Matches.affine` holds
        the centre and linear part, ``gain`` is ``g0``, ``correlation`` that of ``T`` with
        ``G S(W)``, the covariance that of the richer model's normal equations. On a
        curved surface that turns (a limb) the affine model settles tenths of a pixel off
        the material point (benches/README.md, "track27", "lsm28"). Default: None (the
        affine match).

    Returns
    -------
    Matches
        Status, positions, affine maps, gain and offset, sigma0, the joint covariance,
        correlation and iterations per point and search image. A bad patch never raises:
        it gets its :class:`MatchStatus`.

    Raises
    ------
    InvalidInputError
        An image that is not 2-D, is smaller than 2x2, holds NaN or infinity, or has an
        unsupported dtype; points, starts or lines of the wrong shape or non-finite
        points and starts; a start whose linear part has a non-positive determinant;
        options out of range. The message names the argument.

    Notes
    -----
    SPEC section 7, after Gruen (1985, the matching of the third paper,
    ``papers/003_*.txt`` section 2): per search image the unknowns are the affine map
    ``(A, b)`` (6) and gain ``r1`` and offset ``r0`` (2), minimising
    ``sum_x (T(x) - r0 - r1 S(A x + b))^2`` over the template patch by Gauss-Newton with
    bilinear (or bicubic) resampling of ``S``. The update is composed on the template side, whose
    gradients stand in for the resampled search patch's (they agree where the patches
    match), so the geometric part of the normal equations is computed once per point.
    The first iteration solves for shift, gain and offset only. The epipolar line is
    the geometric constraint of Gruen & Baltsavias' multi-photo geometrically constrained
    matching, here one line per search image.

    The covariance is ``sigma0^2 Q`` per search image (``Q`` the inverse normal matrix,
    mapped to the parameters above). Between search images ``s != t`` it is
    ``sigma_T^2 Q_s G_s^T G_t Q_t``: the template's noise (variance ``sigma_T^2``,
    estimated from how the residuals of different search images co-vary) enters every
    search image's estimate. Bilinear resampling damps the search patch's contrast by
    about ``omega^2 / 12`` at angular frequency ``omega`` (rad/px), which the gain absorbs,
    and biases positions on textures with much energy near the Nyquist frequency.
    """
    template_image = _image("template", template)
    searches = _search_images(search_images)
    points_array = as_float_array("points", points)
    if points_array.ndim != 2 or points_array.shape[1] != 2:
        raise InvalidInputError(f"points must have shape (N, 2), got {points_array.shape}")
    n, s = points_array.shape[0], len(searches)
    starts = _starts(initial, points_array, s)
    lines = None if epipolar is None else _lines(epipolar, n, s)
    size = as_count("size", size, minimum=3)
    if size % 2 == 0 or size > 255:
        raise InvalidInputError(f"size must be an odd integer from 3 to 255, got {size}")
    sigma = float(epipolar_sigma)
    if not (np.isfinite(sigma) and sigma >= 0):
        raise InvalidInputError(f"epipolar_sigma must be a finite number >= 0, got {epipolar_sigma!r}")
    if min_texture is None:
        min_texture = TEXTURE_OVER_NOISE * noise_level(template_image)
    texture = float(min_texture)
    if not (np.isfinite(texture) and texture >= 0):
        raise InvalidInputError(f"min_texture must be a finite number >= 0, got {min_texture!r}")
    if threads is not None:
        threads = as_count("threads", threads)
    weight_image = None if weights is None else _weight_image(weights, template_image.shape)
    if max_sigma0 is not None:
        max_sigma0 = as_positive("max_sigma0", max_sigma0)
    if min_correlation is not None:
        limit = None if isinstance(min_correlation, (str, bytes)) else float(min_correlation)
        if limit is None or not (np.isfinite(limit) and -1.0 <= limit <= 1.0):
            raise InvalidInputError(f"min_correlation must be a number from -1 to 1, got {min_correlation!r}")
        min_correlation = limit
    extra = _refine_options(refine)
    return _run(template_image, points_array, searches, starts, lines, size=size,
                max_iterations=as_count("max_iterations", max_iterations), tolerance=as_positive("tolerance", tolerance),
                max_shift=as_positive("max_shift", size / 2 if max_shift is None else max_shift),
                max_scale=as_positive("max_scale", max_scale), min_texture=texture, line_sigma=sigma,
                interpolation=interpolation, threads=threads, weights=weight_image, extra=extra,
                max_sigma0=max_sigma0, min_correlation=min_correlation)


def match_checked(template: NDArray[np.float32], points: NDArray[np.float64], search_images: list[NDArray[np.float32]],
                  *, initial: NDArray[np.float64], size: int, min_texture: float, max_iterations: int,
                  weights: NDArray[np.float32] | None = None, epipolar: NDArray[np.float64] | None = None) -> Matches:
    """:func:`match_patches` (its other options at their defaults) on images already
    checked by :func:`checked_image` and weights by :func:`checked_weights`: a caller that
    matches many small batches in the same images (the tracker, per camera pair; the
    seeding, per camera and partner) checks each image once, not once per batch (a
    finiteness check and a copy of a 1024x768 image cost ~1-3 ms, the match of a few dozen
    patches about as much). ``points`` (N, 2), ``initial`` (N, S, 2) or (N, S, 2, 3) and
    ``epipolar`` (N, S, 3) or (N, 3) lines as in :func:`match_patches`."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    starts = _starts(initial, pts, len(search_images))
    lines = None if epipolar is None else _lines(epipolar, len(pts), len(search_images))
    return _run(template, pts, search_images, starts, lines, size=size, max_iterations=max_iterations, tolerance=0.01,
                max_shift=size / 2, max_scale=3.0, min_texture=float(min_texture), line_sigma=0.0,
                interpolation="bicubic", threads=None, weights=weights, extra={}, max_sigma0=None, min_correlation=None)


def match_checked_pairs(images: Sequence[NDArray[np.float32] | None], cameras: NDArray[np.int64],
                        points: NDArray[np.float64], initial: NDArray[np.float64], *, size: int, min_texture: float,
                        max_iterations: int, weights: Sequence[NDArray[np.float32] | None] | None = None,
                        max_shift: float | None = None) -> Matches:
    """:func:`match_checked` for many camera pairs in one core call: patch ``i`` around
    ``points[i]`` (N, 2) in ``images[cameras[i, 0]]`` matched into ``images[cameras[i, 1]]``
    (``cameras`` (N, 2) indices into the per-camera ``images``, checked by
    :func:`checked_image`, None for a camera no patch uses) from ``initial`` (N, 2, 3) affine
    maps, the template weighed by ``weights[cameras[i, 0]]`` (:func:`checked_weights`) where
    given; ``max_shift`` as in :func:`match_patches` (default ``size / 2``). The tracker's
    spatial matches of a frame (~80-100 camera pairs of a few dozen patches) run as one
    parallel batch instead of one call a pair; each patch's result is bit-identical to
    :func:`match_checked` (or :func:`match_patches` with the same options) on its pair
    alone. The "cameras" are any list of images: the anchors' mosaics and the frame's
    images together, say. Returns :class:`Matches` with S = 1 (the patch's one search
    image)."""
    n = len(points)
    status, affine, radiometry, sigma0, correlation, iterations, covariance = _core.lsm_match_pairs(
        list(images),
        np.ascontiguousarray(cameras, dtype=np.int64).reshape(n, 2),
        np.ascontiguousarray(points, dtype=np.float64),
        np.ascontiguousarray(initial, dtype=np.float64).reshape(n, 6),
        size=size,
        max_iterations=max_iterations,
        tolerance=0.01,
        max_shift=size / 2 if max_shift is None else as_positive("max_shift", max_shift),
        max_scale=3.0,
        min_texture=float(min_texture),
        interpolation="bicubic",
        weights=None if weights is None else list(weights),
    )
    return Matches(
        status=status[:, None],
        positions=affine[:, None, :, 2].copy(),
        affine=affine[:, None],
        gain=radiometry[:, None, 0].copy(),
        offset=radiometry[:, None, 1].copy(),
        sigma0=sigma0[:, None],
        covariance=covariance,
        correlation=correlation[:, None],
        iterations=iterations[:, None],
        affine_centre=np.full((n, 1, 2), np.nan),
        refined=np.zeros((n, 1), np.uint8),
    )


def _run(template: NDArray[np.float32], points: NDArray[np.float64], searches: list[NDArray[np.float32]],
         starts: NDArray[np.float64], lines: NDArray[np.float64] | None, *, size: int, max_iterations: int,
         tolerance: float, max_shift: float, max_scale: float, min_texture: float, line_sigma: float,
         interpolation: str, threads: int | None, weights: NDArray[np.float32] | None, extra: dict[str, Any],
         max_sigma0: float | None, min_correlation: float | None) -> Matches:
    """The core's match on checked arrays, wrapped in :class:`Matches`."""
    status, affine, radiometry, sigma0, correlation, iterations, covariance, centre, refined = _core.lsm_match_patches(
        template,
        points,
        searches,
        starts,
        lines,
        size=size,
        max_iterations=max_iterations,
        tolerance=tolerance,
        max_shift=max_shift,
        max_scale=max_scale,
        min_texture=min_texture,
        line_sigma=line_sigma,
        interpolation=interpolation,
        threads=threads,
        weights=weights,
        **extra,
    )
    status = _reject_poor(status, sigma0, correlation, max_sigma0, min_correlation)
    return Matches(
        status=status,
        positions=affine[..., 2].copy(),
        affine=affine,
        gain=radiometry[..., 0].copy(),
        offset=radiometry[..., 1].copy(),
        sigma0=sigma0,
        covariance=covariance,
        correlation=correlation,
        iterations=iterations,
        affine_centre=centre,
        refined=refined,
    )


def _reject_poor(
    status: NDArray[np.uint8],
    sigma0: NDArray[np.float64],
    correlation: NDArray[np.float64],
    max_sigma0: float | None,
    min_correlation: float | None,
) -> NDArray[np.uint8]:
    """``status`` with converged matches beyond the limits marked :attr:`MatchStatus.REJECTED`."""
    poor = np.zeros(status.shape, dtype=bool)
    if max_sigma0 is not None:
        poor |= ~(sigma0 <= max_sigma0)
    if min_correlation is not None:
        poor |= ~(correlation >= min_correlation)
    return np.where(poor & (status == MatchStatus.CONVERGED), np.uint8(MatchStatus.REJECTED), status).astype(np.uint8)


_REFINE_DEFAULTS: dict[str, Any] = {
    "iterations": 10, "warp": "quadratic", "gain_gradient": True, "warp_sigma": 0.0, "gain_sigma": 0.0,
    "fallback": False, "jacobian": "search", "skip_correlation": float("inf"),
}


def _refine_options(refine: Mapping[str, Any] | None) -> dict[str, Any]:
    """``match_patches(refine=)`` as the core's ``extra_*`` keywords, checked."""
    if refine is None:
        return {}
    if not isinstance(refine, Mapping):
        raise InvalidInputError(f"refine must be a mapping or None, got {type(refine).__name__}")
    unknown = sorted(set(refine) - set(_REFINE_DEFAULTS))
    if unknown:
        raise InvalidInputError(f"refine has unknown keys {unknown}; known: {sorted(_REFINE_DEFAULTS)}")
    given = {**_REFINE_DEFAULTS, **refine}
    if given["warp"] not in ("affine", "projective", "quadratic"):
        raise InvalidInputError(f"refine['warp'] must be 'affine', 'projective' or 'quadratic', got {given['warp']!r}")
    if given["jacobian"] not in ("search", "template"):
        raise InvalidInputError(f"refine['jacobian'] must be 'search' or 'template', got {given['jacobian']!r}")
    for key in ("gain_gradient", "fallback"):
        if not isinstance(given[key], (bool, np.bool_)):
            raise InvalidInputError(f"refine[{key!r}] must be a bool, got {given[key]!r}")
    sigmas = {}
    for key in ("warp_sigma", "gain_sigma"):
        value = given[key]
        number = None if isinstance(value, (str, bytes, bool)) else float(value)
        if number is None or not (np.isfinite(number) and number >= 0):
            raise InvalidInputError(f"refine[{key!r}] must be a finite number >= 0 (0: no prior), got {value!r}")
        sigmas[key] = number
    skip = given["skip_correlation"]
    skip_number = None if isinstance(skip, (str, bytes, bool)) else float(skip)
    if skip_number is None or np.isnan(skip_number):
        raise InvalidInputError(f"refine['skip_correlation'] must be a number (inf: never skipped), got {skip!r}")
    return {
        "extra_iterations": as_count("refine['iterations']", given["iterations"]),
        "extra_warp": given["warp"],
        "extra_gain_gradient": bool(given["gain_gradient"]),
        "extra_warp_sigma": sigmas["warp_sigma"],
        "extra_gain_sigma": sigmas["gain_sigma"],
        "extra_fallback": bool(given["fallback"]),
        "extra_skip_correlation": skip_number,
        "extra_jacobian": given["jacobian"],
    }


def noise_level(image: Any) -> float:
    """Standard deviation of an image's white noise, grey levels (Immerkær 1996).

    Parameters
    ----------
    image : (H, W) array_like of real numbers, at least 3x3

    Returns
    -------
    float
        ``sqrt(pi / 2) / (6 (W - 2) (H - 2)) * sum |I * N|`` with ``N`` the difference of
        two Laplacians ``[[1, -2, 1], [-2, 4, -2], [1, -2, 1]]``, which cancels smooth
        image structure and keeps the noise; edges inflate it somewhat.
    """
    grey = _image("image", image)
    if min(grey.shape) < 3:
        raise InvalidInputError(f"image must be at least 3x3 for a noise estimate, got {grey.shape}")
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    response = cv2.filter2D(grey, cv2.CV_32F, kernel, borderType=cv2.BORDER_ISOLATED)[1:-1, 1:-1]
    h, w = grey.shape
    return float(np.sqrt(np.pi / 2) * np.abs(response, dtype=np.float64).sum() / (6 * (w - 2) * (h - 2)))


# ------------------------------------------------------------------------------------------
# validation
# ------------------------------------------------------------------------------------------


def _image(name: str, value: Any) -> NDArray[np.float32]:
    """A grey image as C-contiguous float32, checked: 2-D, at least 2x2, real, finite."""
    array = np.asarray(value)
    if array.dtype.kind not in "fiu" or array.dtype.kind == "b":
        raise InvalidInputError(f"{name} must hold grey levels (uint8, uint16 or float), got dtype {array.dtype}")
    if array.ndim != 2:
        raise InvalidInputError(
            f"{name} must be a 2-D (H, W) grey image, got shape {array.shape}"
            + (" (convert colour images to grey first)" if array.ndim == 3 else "")
        )
    if array.shape[0] < 2 or array.shape[1] < 2:
        raise InvalidInputError(f"{name} must be at least 2x2 pixels, got shape {array.shape}")
    image = np.ascontiguousarray(array, dtype=np.float32)
    if array.dtype.kind == "f" and not np.isfinite(image).all():
        raise InvalidInputError(f"{name} holds NaN or infinity (or values beyond float32)")
    return image


def checked_image(value: Any) -> NDArray[np.float32]:
    """A grey image as :func:`match_checked` takes it (C-contiguous float32, checked)."""
    return _image("image", value)


def checked_weights(value: Any, shape: tuple[int, ...]) -> NDArray[np.float32]:
    """Template weights of ``shape`` as :func:`match_checked` takes them."""
    return _weight_image(value, shape)


def _weight_image(value: Any, shape: tuple[int, ...]) -> NDArray[np.float32]:
    """Template weights as C-contiguous float32 of the template's ``shape``, finite. A
    float32 image is taken as it is (the same values as through float64, without the
    two copies)."""
    given = np.asarray(value)
    if given.dtype == bool:
        given = given.astype(np.float32)
    elif given.dtype != np.float32:
        given = as_float_array("weights", given)
    weight_image = np.ascontiguousarray(given, dtype=np.float32)
    if weight_image.shape != shape:
        raise InvalidInputError(f"weights must have the template's shape {shape}, got {weight_image.shape}")
    if not np.isfinite(weight_image).all():
        raise InvalidInputError("weights must be finite")
    return weight_image


def _search_images(value: Any) -> list[NDArray[np.float32]]:
    if isinstance(value, np.ndarray) and value.ndim == 2:
        return [_image("search_images", value)]
    if isinstance(value, np.ndarray) and value.ndim == 3:
        items: Sequence[Any] = list(value)
    elif isinstance(value, Sequence) and not isinstance(value, (str, bytes)):
        items = value
    else:
        raise InvalidInputError(
            f"search_images must be an (H, W) image or a sequence of them, got {type(value).__name__}"
        )
    if len(items) == 0:
        raise InvalidInputError("search_images is empty: at least one search image is needed")
    return [_image(f"search_images[{i}]", item) for i, item in enumerate(items)]


def _starts(initial: Any, points: NDArray[np.float64], s: int) -> NDArray[np.float64]:
    n = len(points)
    identity = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    if initial is None:
        maps = np.broadcast_to(identity, (n, s, 2, 3)).copy()
        maps[..., 2] = points[:, None, :]
        return maps.reshape(n, s, 6)
    start = as_float_array("initial", initial)
    if s == 1 and start.shape in ((n, 2), (n, 2, 3)):
        start = start[:, None]
    if start.shape == (n, s, 2):
        maps = np.broadcast_to(identity, (n, s, 2, 3)).copy()
        maps[..., 2] = start
    elif start.shape == (n, s, 2, 3):
        maps = start
    else:
        raise InvalidInputError(
            f"initial must have shape ({n}, {s}, 2) (centres) or ({n}, {s}, 2, 3) (affine maps), "
            f"got {start.shape}"
        )
    return np.ascontiguousarray(maps.reshape(n, s, 6))


def _lines(epipolar: Any, n: int, s: int) -> NDArray[np.float64]:
    lines = as_float_array("epipolar", epipolar)
    if s == 1 and lines.shape == (n, 3):
        lines = lines[:, None]
    if lines.shape != (n, s, 3):
        raise InvalidInputError(f"epipolar must have shape ({n}, {s}, 3), got {lines.shape}")
    return np.ascontiguousarray(lines)
