"""OpenCV's lens distortion of normalised image coordinates: radial (k1 k2 k3), rational
(k4 k5 k6), tangential (p1 p2) and thin prism (s1 s2 s3 s4); the forward map, the radius
where it folds over, and its inverse by Newton's method.

Coefficients are in OpenCV's order ``k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tauX tauY]]]]``
(4, 5, 8, 12 or 14 of them). With ``r^2 = a^2 + b^2``::

    radial = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
    a' = a radial + 2 p1 a b + p2 (r^2 + 2 a^2) + s1 r^2 + s2 r^4
    b' = b radial + p1 (r^2 + 2 b^2) + 2 p2 a b + s3 r^2 + s4 r^4

which is ``cv::projectPoints`` without the tilted-sensor terms (tauX, tauY), which
elastocap refuses unless they are zero.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.polynomial import polynomial as P
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_float_array

__all__ = ["FULL_LENGTH", "as_coefficients", "distort", "fold_radius", "padded", "undistort"]

# OpenCV's coefficient counts; elastocap keeps the shortest of CANONICAL_LENGTHS that holds
# every non-zero coefficient, so that 5-coefficient cameras stay what they were.
OPENCV_LENGTHS = (4, 5, 8, 12, 14)
CANONICAL_LENGTHS = (5, 8, 12)
FULL_LENGTH = 12
NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tauX", "tauY")

# Newton's method on the distortion map stops when the step is below this (normalised image
# coordinates, i.e. about 1e-15 focal lengths: rounding level) ...
UNDISTORT_STEP_TOL = 1e-15
# ... or after this many iterations; a point whose distortion residual is then still above
# UNDISTORT_RESIDUAL_TOL lies where the distortion map folds over and has no unique ray.
UNDISTORT_MAX_ITERATIONS = 50
UNDISTORT_RESIDUAL_TOL = 1e-10
# A root of the fold polynomial counts as real when its imaginary part is below this
# (relative to its size): np.roots returns real roots with rounding-level imaginary parts.
REAL_ROOT_RTOL = 1e-12


def as_coefficients(value: Any) -> NDArray[np.float64]:
    """``value`` as elastocap's distortion vector: 4, 5, 8, 12 or 14 OpenCV coefficients
    (``None``: none; fewer than 4 are padded, as short ``dist_`` entries in files are),
    returned as the shortest of 5, 8 or 12 that holds every non-zero one. Non-zero tilt
    terms (tauX, tauY) are refused: elastocap does not model tilted sensors."""
    if value is None:
        return np.zeros(5)
    dist = as_float_array("dist", value)
    if dist.ndim > 2 or (dist.ndim == 2 and 1 not in dist.shape):
        raise InvalidInputError(f"dist must be a vector of OpenCV coefficients, got shape {dist.shape}")
    dist = dist.ravel()
    if dist.size > 4 and dist.size not in OPENCV_LENGTHS:
        raise InvalidInputError(
            f"dist must hold 4, 5, 8, 12 or 14 coefficients (OpenCV's k1 k2 p1 p2 [k3 [k4 k5 k6 "
            f"[s1 s2 s3 s4 [tauX tauY]]]]), got {dist.size}"
        )
    if not np.isfinite(dist).all():
        raise InvalidInputError(f"dist must be finite, got {dist.tolist()}")
    if dist.size == 14 and np.any(dist[12:] != 0):
        raise InvalidInputError(
            f"dist: the tilted-sensor terms tauX, tauY = {dist[12:].tolist()} are not supported "
            "(elastocap models k1-k6, p1 p2, s1-s4); only zero tilt is accepted"
        )
    dist = dist[:FULL_LENGTH]
    nonzero = np.flatnonzero(dist)
    needed = int(nonzero[-1]) + 1 if nonzero.size else 0
    length = next(n for n in CANONICAL_LENGTHS if n >= needed)
    out = np.zeros(length)
    kept = min(length, dist.size)
    out[:kept] = dist[:kept]
    return out


def padded(dist: NDArray[np.float64], length: int = FULL_LENGTH) -> NDArray[np.float64]:
    """``dist`` with zeros appended up to ``length`` coefficients."""
    out = np.zeros(length)
    out[: dist.size] = dist
    return out


# The coefficients as Python floats, by the bytes of the array they came from: a tracked
# frame projects ~200 times through a handful of cameras, and the conversion cost more
# than the small projections' arithmetic (the same floats either way).
_SPLIT: dict[tuple[str, tuple[int, ...], bytes], tuple[float, ...]] = {}


def _split(dist: NDArray[np.float64]) -> tuple[float, ...]:
    key = (dist.dtype.str, dist.shape, dist.tobytes())
    found = _SPLIT.get(key)
    if found is None:
        if len(_SPLIT) >= 256:
            _SPLIT.clear()
        found = _SPLIT[key] = tuple(float(x) for x in padded(dist))
    return found


def distort(ab: NDArray[np.float64], dist: NDArray[np.float64]) -> NDArray[np.float64]:
    """OpenCV's distortion of normalised image coordinates ``(N, 2)``."""
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = _split(dist)
    a, b = ab[:, 0], ab[:, 1]
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        r2 = a * a + b * b
        # Without k4-k6 the denominator is exactly 1 and the division changes nothing.
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        a2 = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a) + r2 * (s1 + r2 * s2)
        b2 = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b + r2 * (s3 + r2 * s4)
    # np.stack's copy, without its dispatch (a few microseconds a call).
    out = np.empty((len(a2), 2), np.result_type(a2, b2))
    out[:, 0], out[:, 1] = a2, b2
    return out


def fold_radius(dist: NDArray[np.float64]) -> float:
    """The smallest normalised radius where the radial distortion ``r N(r^2) / D(r^2)``
    stops increasing or its denominator vanishes; inf when neither happens.

    With ``s = r^2``, ``d/dr [r N(s)/D(s)] = ((N + 2 s N') D - 2 s N D') / D^2``: the
    numerator's smallest positive root, or D's if smaller. (Tangential and thin-prism terms
    are not included: for real lenses they are small next to the radial ones.)
    """
    k1, k2, _, _, k3, k4, k5, k6 = _split(dist)[:8]
    numerator = np.array([1.0, k1, k2, k3])
    denominator = np.array([1.0, k4, k5, k6])
    s = np.array([0.0, 1.0])
    slope = P.polysub(
        P.polymul(P.polyadd(numerator, 2 * P.polymul(s, P.polyder(numerator))), denominator),
        2 * P.polymul(P.polymul(s, numerator), P.polyder(denominator)),
    )
    candidates = [_smallest_positive_root(slope), _smallest_positive_root(denominator)]
    s_min = min(candidates)
    return float(np.sqrt(s_min)) if np.isfinite(s_min) else float("inf")


def _smallest_positive_root(ascending: NDArray[np.float64]) -> float:
    coefficients = np.asarray(ascending, dtype=np.float64)
    # Leading terms below a rounding error of the largest only place roots where
    # |s| > eps^(-1/degree) (r > 400 for a cubic), far beyond any lens, and scale the
    # companion matrix until its eigenvalues are noise: leave them out (as the core does).
    kept = np.flatnonzero(np.abs(coefficients) > np.finfo(np.float64).eps * np.abs(coefficients).max(initial=0.0))
    coefficients = coefficients[: kept[-1] + 1] if kept.size else coefficients[:0]
    if coefficients.size <= 1:
        return float("inf")
    roots = P.polyroots(coefficients)
    real = roots[np.abs(roots.imag) <= REAL_ROOT_RTOL * np.maximum(1.0, np.abs(roots))].real
    positive = real[real > 0]
    return float(positive.min()) if positive.size else float("inf")


def undistort(
    target: NDArray[np.float64], dist: NDArray[np.float64], fold: float
) -> NDArray[np.float64]:
    """Solve ``distort(ab) = target`` for ``ab`` ``(N, 2)`` inside the fold radius, by
    Newton's method with steps shortened to stay inside; NaN rows where there is no such
    solution (or the iteration does not find it)."""
    if not np.any(dist != 0):
        return target.copy()
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = _split(dist)
    limit = 0.999 * fold
    ab = target.copy()
    radius = np.hypot(ab[:, 0], ab[:, 1])
    outside = radius >= limit
    ab[outside] *= (0.5 * limit / radius[outside])[:, None]
    active: NDArray[np.bool_] = np.asarray(np.isfinite(ab).all(axis=1))
    for _ in range(UNDISTORT_MAX_ITERATIONS):
        index = np.flatnonzero(active)
        if index.size == 0:
            break
        a, b = ab[index, 0], ab[index, 1]
        r2 = a * a + b * b
        numerator = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        denominator = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        radial = numerator / denominator
        # d radial / d r2, by the quotient rule.
        dradial = ((k1 + r2 * (2 * k2 + 3 * k3 * r2)) * denominator
                   - numerator * (k4 + r2 * (2 * k5 + 3 * k6 * r2))) / (denominator * denominator)
        dprism_a = s1 + 2 * s2 * r2  # d (s1 r2 + s2 r2^2) / d r2
        dprism_b = s3 + 2 * s4 * r2
        fa = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a) + r2 * (s1 + r2 * s2) - target[index, 0]
        fb = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b + r2 * (s3 + r2 * s4) - target[index, 1]
        # Jacobian of the distortion map, with d r2/da = 2a, d r2/db = 2b.
        cross = 2 * a * b * dradial + 2 * p1 * a + 2 * p2 * b
        jaa = radial + 2 * a * a * dradial + 2 * p1 * b + 6 * p2 * a + 2 * a * dprism_a
        jab = cross + 2 * b * dprism_a
        jba = cross + 2 * a * dprism_b
        jbb = radial + 2 * b * b * dradial + 6 * p1 * b + 2 * p2 * a + 2 * b * dprism_b
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            det = jaa * jbb - jab * jba
            da = (jbb * fa - jab * fb) / det
            db = (jaa * fb - jba * fa) / det
        # Halve steps that would leave the fold radius, where a second, unphysical
        # preimage may lie.
        scale = np.ones_like(da)
        for _ in range(60):
            beyond = np.hypot(a - scale * da, b - scale * db) >= limit
            if not beyond.any():
                break
            scale[beyond] *= 0.5
        ab[index, 0] = a - scale * da
        ab[index, 1] = b - scale * db
        step = scale * np.maximum(np.abs(da), np.abs(db))
        with np.errstate(invalid="ignore"):
            done = step <= UNDISTORT_STEP_TOL * np.maximum(1.0, np.abs(ab[index]).max(axis=1))
        active[index[done | ~np.isfinite(step)]] = False
    residual = np.abs(distort(ab, dist) - target).max(axis=1)
    with np.errstate(invalid="ignore"):
        failed = ~(residual <= UNDISTORT_RESIDUAL_TOL * np.maximum(1.0, np.abs(target).max(axis=1)))
    ab[failed] = np.nan
    return ab
