"""OpenCV's lens distortion of normalised image coordinates (k1 k2 p1 p2 k3): the forward
map, the radius where it folds over, and its inverse by Newton's method."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["distort", "fold_radius", "undistort"]

# Newton's method on the distortion map stops when the step is below this (normalised image
# coordinates, i.e. about 1e-15 focal lengths: rounding level) ...
UNDISTORT_STEP_TOL = 1e-15
# ... or after this many iterations; a point whose distortion residual is then still above
# UNDISTORT_RESIDUAL_TOL lies where the distortion map folds over and has no unique ray.
UNDISTORT_MAX_ITERATIONS = 50
UNDISTORT_RESIDUAL_TOL = 1e-10


def distort(ab: NDArray[np.float64], dist: NDArray[np.float64]) -> NDArray[np.float64]:
    """OpenCV's distortion of normalised image coordinates ``(N, 2)``."""
    k1, k2, p1, p2, k3 = dist
    a, b = ab[:, 0], ab[:, 1]
    with np.errstate(invalid="ignore", over="ignore"):
        r2 = a * a + b * b
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        a2 = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
        b2 = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
    return np.stack([a2, b2], axis=1)


def fold_radius(dist: NDArray[np.float64]) -> float:
    """The smallest normalised radius where the radial distortion ``r (1 + k1 r^2 + k2 r^4 +
    k3 r^6)`` stops increasing, or inf when it never does."""
    k1, k2, _, _, k3 = dist
    # d/dr [r (1 + k1 s + k2 s^2 + k3 s^3)] = 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3, s = r^2.
    coefficients = np.trim_zeros(np.array([7 * k3, 5 * k2, 3 * k1, 1.0]), "f")
    roots = np.roots(coefficients) if len(coefficients) > 1 else np.array([])
    real = roots[np.abs(roots.imag) <= 1e-12 * np.maximum(1.0, np.abs(roots))].real
    positive = real[real > 0]
    return float(np.sqrt(positive.min())) if positive.size else float("inf")


def undistort(
    target: NDArray[np.float64], dist: NDArray[np.float64], fold: float
) -> NDArray[np.float64]:
    """Solve ``distort(ab) = target`` for ``ab`` ``(N, 2)`` inside the fold radius, by
    Newton's method with steps shortened to stay inside; NaN rows where there is no such
    solution (or the iteration does not find it)."""
    if not np.any(dist != 0):
        return target.copy()
    k1, k2, p1, p2, k3 = dist
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
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d radial / d r2
        fa = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a) - target[index, 0]
        fb = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b - target[index, 1]
        # Jacobian of the distortion map (symmetric), with d r2/da = 2a, d r2/db = 2b.
        jaa = radial + 2 * a * a * dradial + 2 * p1 * b + 6 * p2 * a
        jab = 2 * a * b * dradial + 2 * p1 * a + 2 * p2 * b
        jbb = radial + 2 * b * b * dradial + 6 * p1 * b + 2 * p2 * a
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            det = jaa * jbb - jab * jab
            da = (jbb * fa - jab * fb) / det
            db = (jaa * fb - jab * fa) / det
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
