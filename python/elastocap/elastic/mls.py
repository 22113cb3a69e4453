"""Moving Least Squares shape functions (linear basis) and their gradients at the nodes of a
2-D or 3-D point cloud: the approximation behind the element-free elastic model (SPEC 4.2).

The kernel (``rust/mls.rs``) factors one small moment matrix per node, in parallel without
the GIL, and repairs ill-conditioned neighbourhoods by enlarging their support.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

import elastocap._core as _core
from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_points, as_positive
from elastocap.geometry.neighbors import knn

__all__ = ["MLSShapeFunctions", "mls_shape_functions"]


@dataclass(frozen=True, eq=False)
class MLSShapeFunctions:
    """MLS shape functions and gradients of N nodes with k neighbours each (D = 2 or 3).

    Attributes
    ----------
    neighbors : (N, k) int64
        Row ``p`` lists the neighbours ``N_p`` of node ``p``, the node itself included.
    phi : (N, k) float64
        ``phi[p, j]`` is the shape function of node ``neighbors[p, j]`` evaluated at node
        ``p``, ``Phi_i(x_p)``; dimensionless. Each row sums to 1.
    grad : (N, k, D) float64
        ``grad[p, j]`` is its gradient ``d Phi_i / dx (x_p)``, in inverse units of the
        points, axes in the frame of the points.
    support : (N,) float64
        The support radius ``ddm_p`` used at each node, in units of the points: ``c`` times
        the distance to the farthest neighbour, enlarged by 1.25x steps where repaired.
    repaired : int
        Number of nodes whose support had to be enlarged.
    """

    neighbors: NDArray[np.int64]
    phi: NDArray[np.float64]
    grad: NDArray[np.float64]
    support: NDArray[np.float64]
    repaired: int


def _as_neighbors(value: Any, n: int, dim: int) -> NDArray[np.int64]:
    array = np.asarray(value)
    if array.dtype.kind not in "iu":
        raise InvalidInputError(f"neighbors must hold integers, got dtype {array.dtype}")
    if array.ndim != 2 or array.shape[0] != n:
        raise InvalidInputError(f"neighbors must have shape (N, k) with N = {n} like points, got {array.shape}")
    if array.shape[1] < dim + 1:
        raise InvalidInputError(
            f"neighbors must have at least D + 1 = {dim + 1} columns (the node and {dim} others) "
            f"for a linear basis in {dim}-D, got {array.shape[1]}"
        )
    bad = (array < 0) | (array >= n)
    if bad.any():
        row, column = np.argwhere(bad)[0]
        raise InvalidInputError(
            f"neighbors[{row}, {column}] = {array[row, column]} is not a point index: it must be in 0..{n}"
        )
    return np.ascontiguousarray(array, dtype=np.int64)


def mls_shape_functions(
    points: Any, *, k: int = 20, c: float = 1.1, neighbors: Any = None
) -> MLSShapeFunctions:
    """Moving Least Squares shape functions and their gradients at every node.

    Parameters
    ----------
    points : (N, 3) or (N, 2) array_like of float
        Node positions (the rest state), any units.
    k : int, keyword-only
        Neighbours per node, the node itself included (the paper: 20). At least D + 1 and
        at most N. Ignored when ``neighbors`` is given (its column count is k then).
    c : float, keyword-only
        Support radius factor: ``ddm_p = c * r_k``, with ``r_k`` the distance from node p to
        its farthest listed neighbour. Any ``c > 1`` gives every neighbour a non-zero weight.
    neighbors : (N, k) array_like of int, optional
        Neighbour lists, each row holding its own node. Default: the node followed by its
        ``k - 1`` nearest other nodes (:func:`elastocap.knn`).

    Returns
    -------
    MLSShapeFunctions
        ``neighbors (N, k)``, ``phi (N, k)``, ``grad (N, k, D)`` in inverse units of the
        points, ``support (N,)`` in units of the points, and ``repaired``.

    Raises
    ------
    InvalidInputError
        For wrong shapes or dtypes, NaN / infinity, ``k < D + 1``, neighbour indices out of
        range or rows without their node, ``c`` not positive, and neighbourhoods that do not
        span the space (collinear in 2-D, coplanar in 3-D) even after enlarging the support;
        the message names the argument or the node.

    Notes
    -----
    SPEC 4.2 (after the paper's section 3; Belytschko, Lu & Gu 1994, element-free Galerkin):
    linear basis ``p(x) = [1, (x - x_p) / ddm_p]``; weights the tensor product over the axes
    of the cubic spline ``w(r)``, ``r = |x_a - x_i,a| / ddm_p``; ``A = sum_i w_i p_i p_i^T``,
    ``B = [w_i p_i]``, ``Phi^T = p^T A^-1 B`` and
    ``dPhi^T = dp^T A^-1 B + p^T A^-1 (dB - dA A^-1 B)``, solved by Cholesky.

    A node whose moment matrix ``A`` (scaled to unit diagonal) has a reciprocal condition
    number below 1e-3 (where the gradient identities below would start to lose the 1e-10
    accuracy SPEC 4.2 asks for) has its support enlarged by 1.25, up to four times; with
    fixed neighbour lists this helps only when the listed neighbours span the space but lie
    outside, or at the edge of, the support. Such nodes do not occur with the default k = 20
    on reasonable clouds; with k close to D + 1 they do.

    The results reproduce linear fields exactly: ``sum_i Phi_i = 1``,
    ``sum_i Phi_i x_i = x_p``, ``sum_i grad Phi_i = 0``, ``sum_i grad Phi_i x_i^T = I``.

    Examples
    --------
    >>> import numpy as np, elastocap
    >>> mls = elastocap.mls_shape_functions(np.random.default_rng(0).random((500, 3)))
    >>> mls.phi.shape, mls.grad.shape
    ((500, 20), (500, 20, 3))
    >>> bool(np.allclose(mls.phi.sum(axis=1), 1.0))
    True
    """
    array = as_points("points", points)
    n = array.shape[0]
    if neighbors is None:
        k = as_count("k", k, minimum=array.shape[1] + 1)
        if k > n:
            raise InvalidInputError(f"k = {k} exceeds the number of points ({n})")
        _, indices = knn(array, k - 1)
        lists = np.hstack([np.arange(n, dtype=np.int64)[:, None], indices])
    else:
        lists = _as_neighbors(neighbors, n, array.shape[1])
    factor = as_positive("c", c)
    # The farthest listed neighbour; computed here rather than taken from knn so that
    # user-given lists are treated alike. NaN points propagate and are reported by the core.
    with np.errstate(invalid="ignore"):
        reach = np.sqrt(((array[lists] - array[:, None, :]) ** 2).sum(axis=2)).max(axis=1, initial=0.0)
    support = factor * reach
    phi, grad, used, repaired = _core.mls_shape_functions(array, lists, np.ascontiguousarray(support))
    return MLSShapeFunctions(neighbors=lists, phi=phi, grad=grad, support=used, repaired=repaired)
