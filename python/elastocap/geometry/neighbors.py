"""Neighbour search over 2-D and 3-D point clouds by spatial hashing.

The index (``rust/spatial_hash.rs``) is a uniform grid hash in the style of Teschner et al.
(2003), whose cell size is picked from the data, with a hierarchical (octree) fallback so
that clustered clouds with outliers stay fast. Queries run in parallel without the GIL.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

import elastocap._core as _core
from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_points, as_positive

__all__ = ["Neighbors", "RadiusNeighbors", "SpatialIndex", "knn", "radius_neighbors"]


class Neighbors(NamedTuple):
    """The ``k`` nearest neighbours of ``M`` queries, in scipy's ``cKDTree.query`` order."""

    #: (M, k) float64: Euclidean distances, ascending, in the units of the points.
    distances: NDArray[np.float64]
    #: (M, k) int64: indices into the indexed points, nearest first (ties in index order).
    indices: NDArray[np.int64]


class RadiusNeighbors(NamedTuple):
    """The neighbours within a radius of ``M`` queries, in CSR form: row ``i`` is
    ``indices[indptr[i]:indptr[i + 1]]``, nearest first."""

    #: (nnz,) float64: Euclidean distances matching ``indices``.
    distances: NDArray[np.float64]
    #: (nnz,) int64: indices into the indexed points.
    indices: NDArray[np.int64]
    #: (M + 1,) int64: row offsets.
    indptr: NDArray[np.int64]


class SpatialIndex:
    """A spatial hash over fixed points, for repeated neighbour queries.

    Parameters
    ----------
    points : (N, 3) or (N, 2) array_like of float
        The points to index, any units. Copied; later changes to the array are not seen.

    Raises
    ------
    InvalidInputError
        For an empty array, a wrong shape or dtype, or NaN / infinity.

    Examples
    --------
    >>> import numpy as np, elastocap
    >>> index = elastocap.SpatialIndex(np.random.default_rng(0).random((1000, 3)))
    >>> distances, indices = index.knn(8)
    >>> indices.shape
    (1000, 8)
    """

    __slots__ = ("_index",)

    def __init__(self, points: Any) -> None:
        self._index = _core.SpatialIndex(as_points("points", points))

    @property
    def n_points(self) -> int:
        """Number of indexed points."""
        return self._index.n_points

    @property
    def dim(self) -> int:
        """Dimension of the indexed points, 2 or 3."""
        return self._index.dim

    def _queries(self, queries: Any) -> NDArray[np.float64] | None:
        if queries is None:
            return None
        q = as_points("queries", queries)
        if q.shape[1] != self.dim:
            raise InvalidInputError(
                f"queries must have shape (M, {self.dim}) like the indexed points, got {q.shape}"
            )
        return q

    def knn(self, k: int, *, queries: Any = None) -> Neighbors:
        """The ``k`` nearest indexed points of each query.

        Parameters
        ----------
        k : int
            Neighbours per query: ``1 <= k <= N``, or ``k <= N - 1`` without queries.
        queries : (M, D) array_like of float, optional, keyword-only
            Query points. When omitted, the queries are the indexed points themselves and
            each point is left out of its own neighbours.

        Returns
        -------
        Neighbors
            ``(distances (M, k) float64, indices (M, k) int64)``, nearest first, as
            scipy's ``cKDTree.query``; the fields are named so they cannot be swapped.
        """
        indices, distances = self._index.knn(as_count("k", k), self._queries(queries))
        return Neighbors(distances, indices)

    def radius_neighbors(self, radius: float, *, queries: Any = None) -> RadiusNeighbors:
        """Indexed points within ``radius`` (inclusive) of each query, in CSR form.

        Parameters
        ----------
        radius : float
            Search radius, positive, in the units of the points.
        queries : (M, D) array_like of float, optional, keyword-only
            Query points. When omitted, the queries are the indexed points themselves and
            each point is left out of its own neighbours.

        Returns
        -------
        RadiusNeighbors
            ``(distances (nnz,) float64, indices (nnz,) int64, indptr (M + 1,) int64)``:
            row ``i`` is ``indices[indptr[i]:indptr[i + 1]]``, nearest first.
        """
        indptr, indices, distances = self._index.radius_neighbors(
            as_positive("radius", radius), self._queries(queries)
        )
        return RadiusNeighbors(distances, indices, indptr)


def knn(points: Any, k: int, *, queries: Any = None) -> Neighbors:
    """The ``k`` nearest neighbours among ``points`` of each query.

    Builds a :class:`SpatialIndex` and queries it once; keep the index to query again.

    Parameters
    ----------
    points : (N, 3) or (N, 2) array_like of float
        Points to search.
    k : int
        Neighbours per query: ``1 <= k <= N``, or ``k <= N - 1`` without queries.
    queries : (M, D) array_like of float, optional, keyword-only
        Query points; when omitted, every point is queried, excluding itself.

    Returns
    -------
    Neighbors
        ``(distances (M, k) float64, indices (M, k) int64)``, nearest first: unpack as
        ``distances, indices = knn(...)`` (scipy's and scikit-learn's order) or use the
        named fields.

    Notes
    -----
    Exact: equals ``scipy.spatial.cKDTree(points).query(queries, k)`` up to the order of
    equidistant points.
    """
    return SpatialIndex(points).knn(k, queries=queries)


def radius_neighbors(points: Any, radius: float, *, queries: Any = None) -> RadiusNeighbors:
    """Neighbours among ``points`` within ``radius`` of each query, in CSR form.

    Parameters
    ----------
    points : (N, 3) or (N, 2) array_like of float
        Points to search.
    radius : float
        Search radius, positive, in the units of the points.
    queries : (M, D) array_like of float, optional, keyword-only
        Query points; when omitted, every point is queried, excluding itself.

    Returns
    -------
    RadiusNeighbors
        ``(distances (nnz,) float64, indices (nnz,) int64, indptr (M + 1,) int64)``:
        row ``i`` is ``indices[indptr[i]:indptr[i + 1]]``, nearest first.

    Notes
    -----
    Exact: row ``i`` holds the same points as
    ``scipy.spatial.cKDTree(points).query_ball_point(queries[i], radius)``.
    """
    return SpatialIndex(points).radius_neighbors(radius, queries=queries)
