"""Checks at the public boundary: shapes, dtypes and values, with messages that name the
argument and say what was expected. Finiteness is checked by the Rust core, in parallel."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError


def as_float_array(name: str, value: Any) -> NDArray[np.float64]:
    """``value`` as a C-contiguous float64 array; real numbers only (no bool, complex, object)."""
    try:
        array = np.asarray(value)
    except (ValueError, TypeError):  # ragged nested lists
        raise InvalidInputError(f"{name} must be an array of numbers with one length per axis, got {value!r}"[:400]) from None
    if array.dtype.kind not in "fiu":
        raise InvalidInputError(f"{name} must hold real numbers, got dtype {array.dtype}")
    return np.ascontiguousarray(array, dtype=np.float64)


def as_points(name: str, value: Any, dims: tuple[int, ...] = (2, 3)) -> NDArray[np.float64]:
    """``value`` as ``(N, D) float64`` with D in ``dims`` and N >= 1."""
    points = as_float_array(name, value)
    expected = " or ".join(f"(N, {d})" for d in dims)
    if points.ndim != 2 or points.shape[1] not in dims:
        raise InvalidInputError(f"{name} must have shape {expected}, got {points.shape}")
    if points.shape[0] == 0:
        raise InvalidInputError(f"{name} is empty: shape {points.shape}, at least one row is needed")
    return points


def as_count(name: str, value: Any, minimum: int = 1) -> int:
    """``value`` as a Python int of at least ``minimum``, rejecting floats such as 2.5,
    booleans, and values too large for a 64-bit count."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise InvalidInputError(f"{name} must be an integer, got {value!r}")
    count = int(value)
    if count < minimum:
        raise InvalidInputError(f"{name} must be at least {minimum}, got {count}")
    if count >= 2**63:
        raise InvalidInputError(f"{name} = {count} is too large")
    return count


def as_positive(name: str, value: Any) -> float:
    """``value`` as a positive finite float (a number, not a string that reads as one)."""
    if isinstance(value, (str, bytes)):
        raise InvalidInputError(f"{name} must be a number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a number, got {value!r}") from None
    if not (np.isfinite(number) and number > 0):
        raise InvalidInputError(f"{name} must be a positive finite number, got {value!r}")
    return number
