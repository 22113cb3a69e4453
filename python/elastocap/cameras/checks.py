"""Validation of camera parameters as they come from users and files: rotations and
intrinsics at printed precision (corrected with a :class:`CalibrationWarning`), distortion
vectors, image sizes, point arrays."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_float_array
from elastocap.cameras.distortion import as_coefficients
from elastocap.geometry.polar import polar_rotation

__all__ = [
    "CalibrationWarning",
    "as_distortion",
    "as_image_size",
    "as_intrinsics",
    "as_matrix",
    "as_points2",
    "as_points3",
    "as_rotation",
    "read_only",
]

# A rotation is kept exactly as given when R^T R = I holds to this, entry-wise (a Rodrigues
# vector or a matrix printed with 15 or more digits), so that files round-trip bit for bit.
ROTATION_EXACT_ATOL = 1e-12
# Calibration files print rotations with 6 to 17 significant digits, so a printed rotation is
# orthonormal only to about 1e-6. Up to this error R is projected onto the nearest rotation
# (polar decomposition) with a CalibrationWarning naming the camera and the size of the
# change; beyond it (a scaled or sheared matrix, a typo) R is refused.
ROTATION_TOLERANCE = 1e-3
# K's last row must be [0, 0, 1] and K[1, 0] zero to this (relative to fy); within it they
# are set exactly (a printed 1.0000001 or -1e-17), beyond it K is refused.
INTRINSICS_TOLERANCE = 1e-6




class CalibrationWarning(UserWarning):
    """A calibration was accepted after a correction (a printed rotation projected onto the
    nearest rotation, printed intrinsics rounded to their exact form) or looks implausible.
    The message names the camera and the size of the correction."""


def as_rotation(camera: str, value: Any) -> NDArray[np.float64]:
    """``value`` as a rotation matrix: kept when orthonormal to rounding, projected onto the
    nearest rotation (with a warning) when within ROTATION_TOLERANCE, refused otherwise."""
    R = as_matrix("R", value, (3, 3))
    orthonormality = float(np.abs(R.T @ R - np.eye(3)).max())
    determinant = float(np.linalg.det(R))
    if determinant <= 0.0:
        raise InvalidInputError(
            f"camera {camera!r}: R must be a rotation, got a reflection or a singular matrix "
            f"(det R = {determinant:.9g})"
        )
    if orthonormality > ROTATION_TOLERANCE:
        raise InvalidInputError(
            f"camera {camera!r}: R must be a rotation: max |R^T R - I| = {orthonormality:.3g} "
            f"exceeds the {ROTATION_TOLERANCE:g} that printed precision explains "
            f"(det R = {determinant:.9g}); is it scaled or a different matrix?"
        )
    if orthonormality <= ROTATION_EXACT_ATOL:
        return R
    nearest = polar_rotation(R[None])[0]
    warnings.warn(
        f"camera {camera!r}: R is orthonormal only to {orthonormality:.3g} (printed "
        f"precision); replaced by the nearest rotation, entries changed by at most "
        f"{np.abs(nearest - R).max():.3g}",
        CalibrationWarning,
        stacklevel=3,
    )
    return np.ascontiguousarray(nearest)


def as_intrinsics(camera: str, value: Any) -> NDArray[np.float64]:
    """``value`` as an intrinsic matrix: last row [0, 0, 1] and K[1, 0] = 0 to printed
    precision (set exactly), positive focal lengths."""
    K = as_matrix("K", value, (3, 3))
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InvalidInputError(
            f"camera {camera!r}: K must have positive focal lengths, got fx = {K[0, 0]}, "
            f"fy = {K[1, 1]}"
        )
    if np.abs(K[2] - [0.0, 0.0, 1.0]).max() > INTRINSICS_TOLERANCE:
        raise InvalidInputError(f"camera {camera!r}: K must have last row [0, 0, 1], got {K[2].tolist()}")
    if abs(K[1, 0]) > INTRINSICS_TOLERANCE * K[1, 1]:
        raise InvalidInputError(f"camera {camera!r}: K[1, 0] must be 0, got {K[1, 0]}")
    K = K.copy()
    K[2] = [0.0, 0.0, 1.0]
    K[1, 0] = 0.0
    return K


def read_only(array: NDArray[np.float64]) -> NDArray[np.float64]:
    array = np.array(array, dtype=np.float64, order="C")
    array.flags.writeable = False
    return array


def as_matrix(name: str, value: Any, shape: tuple[int, int]) -> NDArray[np.float64]:
    matrix = as_float_array(name, value)
    if matrix.shape != shape:
        raise InvalidInputError(f"{name} must have shape {shape}, got {matrix.shape}")
    if not np.isfinite(matrix).all():
        raise InvalidInputError(f"{name} must be finite, got {matrix.tolist()}")
    return matrix


def as_distortion(value: Any) -> NDArray[np.float64]:
    """``value`` as OpenCV distortion coefficients (see
    :func:`elastocap.cameras.distortion.as_coefficients`)."""
    return as_coefficients(value)


def as_image_size(name: str, value: Any) -> int:
    if isinstance(value, (float, np.floating)) and float(value).is_integer():
        value = int(value)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value <= 0:
        raise InvalidInputError(f"{name} must be a positive integer (pixels), got {value!r}")
    return int(value)


def as_points3(name: str, value: Any) -> NDArray[np.float64]:
    points = as_float_array(name, value)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InvalidInputError(f"{name} must have shape (N, 3), got {points.shape}")
    return points


def as_points2(name: str, value: Any) -> NDArray[np.float64]:
    points = as_float_array(name, value)
    if points.ndim != 2 or points.shape[1] != 2:
        raise InvalidInputError(f"{name} must have shape (N, 2), got {points.shape}")
    return points
