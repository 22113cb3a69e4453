"""Nearest proper rotations of batches of 2x2 and 3x3 matrices (polar decomposition)."""

from __future__ import annotations

from typing import Any, Literal, overload

import numpy as np
from numpy.typing import NDArray

import elastocap._core as _core
from elastocap._core import InvalidInputError
from elastocap._validate import as_float_array

__all__ = ["polar_rotation"]


@overload
def polar_rotation(matrices: Any, *, return_stretch: Literal[False] = ...) -> NDArray[np.float64]: ...
@overload
def polar_rotation(
    matrices: Any, *, return_stretch: Literal[True]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...


def polar_rotation(
    matrices: Any, *, return_stretch: bool = False
) -> NDArray[np.float64] | tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The proper rotation nearest to each matrix (Frobenius norm).

    Parameters
    ----------
    matrices : (N, 3, 3) or (N, 2, 2) array_like of float
        The matrices, e.g. the weighted covariances ``A_p`` of SPEC 4.4. A single
        ``(3, 3)`` or ``(2, 2)`` matrix is accepted too.
    return_stretch : bool, keyword-only
        Also return the symmetric stretch ``S = sym(R^T A)``, so that ``A = R S`` when
        ``det A > 0`` (S is then positive semi-definite).

    Returns
    -------
    rotations : (N, D, D) float64
        Orthonormal with determinant +1. For ``det A < 0`` the smallest singular direction
        is flipped; for rank-deficient matrices one of the (then several) nearest rotations;
        for the zero matrix the identity.
    stretches : (N, D, D) float64
        Only with ``return_stretch=True``.

    Notes
    -----
    3x3: the largest eigenpair of Horn's quaternion matrix, by Newton's method on its
    characteristic quartic and inverse iteration: no SVD per matrix. 2x2: closed form.
    """
    array = as_float_array("matrices", matrices)
    single = array.ndim == 2
    if single:
        array = array[None]
    if array.ndim != 3 or array.shape[1:] not in ((3, 3), (2, 2)):
        raise InvalidInputError(
            f"matrices must have shape (N, 3, 3) or (N, 2, 2), got {np.shape(matrices)}"
        )
    if array.shape[0] == 0:
        raise InvalidInputError(f"matrices is empty: shape {array.shape}, at least one matrix is needed")
    rotations, stretches = _core.polar_rotation(array, bool(return_stretch))
    if single:
        rotations = rotations[0]
        stretches = None if stretches is None else stretches[0]
    if return_stretch:
        assert stretches is not None
        return rotations, stretches
    return rotations
