"""Linear-elastic stiffness of an element-free Galerkin model by direct nodal integration
(SPEC 4.3), on the MLS shape functions of :mod:`elastocap.elastic.mls`.

The kernel (``rust/efg.rs``) builds each node's ``k_p = V_p B_p^T C B_p`` in parallel
without the GIL and assembles the global stiffness as CSR.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, QhullError

import elastocap._core as _core
from elastocap._core import InvalidInputError
from elastocap._validate import as_float_array, as_points, as_positive
from elastocap.elastic.mls import MLSShapeFunctions, mls_shape_functions

__all__ = ["stiffness_matrix"]


def _as_number(name: str, value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a number, got {value!r}") from None


def _nodal_volumes(points: NDArray[np.float64], mls: MLSShapeFunctions, total_volume: Any) -> NDArray[np.float64]:
    """SPEC 4.1 approximation of the Voronoi volumes: ``V_p`` proportional to ``r_k^D``
    (``r_k`` the distance to the farthest neighbour, i.e. inverse local density), scaled so
    that the volumes sum to ``total_volume`` (default: the convex hull's volume)."""
    dim = points.shape[1]
    if total_volume is None:
        try:
            total = float(ConvexHull(points).volume)
        except (QhullError, ValueError) as error:
            raise InvalidInputError(
                f"points: cannot compute their convex hull for the default total_volume ({error}); "
                "pass total_volume or volumes"
            ) from None
    else:
        total = as_positive("total_volume", total_volume)
    reach = np.sqrt(((points[mls.neighbors] - points[:, None, :]) ** 2).sum(axis=2)).max(axis=1)
    share = reach**dim
    return np.ascontiguousarray(total * share / share.sum())


def stiffness_matrix(
    points: Any,
    *,
    k: int = 20,
    youngs: float = 1.0,
    poisson: float = 0.3,
    volumes: Any = None,
    plane: str = "strain",
    total_volume: float | None = None,
) -> scipy.sparse.csr_matrix:
    """Linear-elastic stiffness matrix of a point cloud by nodal integration.

    Parameters
    ----------
    points : (N, 3) or (N, 2) array_like of float
        Node positions at rest, any length unit.
    k : int, keyword-only
        Neighbours per node, the node itself included (the paper: 20).
    youngs : float, keyword-only
        Young's modulus E > 0 (stress units; K is in stress times length).
    poisson : float, keyword-only
        Poisson's ratio, ``0 <= poisson < 0.5``.
    volumes : (N,) array_like of float, optional
        Nodal volumes ``V_p`` (areas in 2-D), positive. Give them when known (e.g. the cell
        volume of a jittered grid). Default: the SPEC 4.1 approximation, ``V_p``
        proportional to ``r_k^D`` with ``r_k`` the distance to node p's farthest neighbour,
        normalised to sum to ``total_volume``.
    plane : {"strain", "stress"}, keyword-only
        2-D only: plane strain or plane stress. Ignored in 3-D.
    total_volume : float, optional
        Total volume (area in 2-D) the default volumes sum to. Default: the volume of the
        convex hull of the points (``scipy.spatial.ConvexHull``). Ignored with ``volumes``.

    Returns
    -------
    scipy.sparse.csr_matrix
        ``(N D, N D)`` float64, degree of freedom ``node * D + axis``; symmetric positive
        semi-definite.

    Raises
    ------
    InvalidInputError
        For wrong shapes or dtypes, NaN / infinity, ``youngs <= 0``, ``poisson`` outside
        ``[0, 0.5)``, non-positive volumes, an unknown ``plane``, and everything
        :func:`elastocap.mls_shape_functions` rejects; the message names the argument.

    Notes
    -----
    SPEC 4.3 (the paper's section 3): strains in Voigt notation with engineering shear,
    3-D ``[xx, yy, zz, xy, yz, zx]``, 2-D ``[xx, yy, xy]``, ``eps_p = B_p u_Np`` with
    ``B_p`` built from the MLS gradients at node p; ``C`` isotropic (plane strain / stress in
    2-D); ``K = sum_p V_p B_p^T C B_p`` scattered over the neighbourhoods.

    Direct nodal integration samples the strain only at the nodes, so ``K`` can have
    zero-energy modes beyond the rigid motions; ``tests/test_efg.py`` measures them. A
    stabilisation is a later step.

    Examples
    --------
    >>> import numpy as np, elastocap
    >>> K = elastocap.stiffness_matrix(np.random.default_rng(0).random((200, 3)), k=20)
    >>> K.shape
    (600, 600)
    """
    array = as_points("points", points)
    n, dim = array.shape
    mls = mls_shape_functions(array, k=k)
    if volumes is None:
        nodal = _nodal_volumes(array, mls, total_volume)
    else:
        nodal = as_float_array("volumes", volumes)
        if nodal.shape != (n,):
            raise InvalidInputError(f"volumes must have shape (N,) = ({n},) like points, got {nodal.shape}")
    indptr, indices, data = _core.efg_stiffness(
        array,
        mls.neighbors,
        mls.grad,
        nodal,
        _as_number("youngs", youngs),
        _as_number("poisson", poisson),
        plane,
    )
    return scipy.sparse.csr_matrix((data, indices, indptr), shape=(n * dim, n * dim))
