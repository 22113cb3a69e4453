"""Exact queries against a triangle mesh: closest points, (signed) distances, containment
and ray casts, through parry's bounding-volume hierarchy (``rust/mesh.rs``), in parallel
without the GIL.

The distance of a point to a mesh is the exact minimum of its point-to-triangle distances:
no voxel grid, no candidate heuristic. Signs come from the pseudo-normal of the closest
face, edge or vertex (Bærentzen & Aanæs, "Signed distance computation using the angle
weighted pseudonormal", IEEE TVCG 2005), exact for a closed, consistently oriented mesh.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import trimesh
from numpy.typing import NDArray

import elastocap._core as _core
from elastocap._core import InvalidInputError
from elastocap._validate import as_float_array

__all__ = ["ClosestPoints", "RayHits", "TriangleMesh"]


class ClosestPoints(NamedTuple):
    """The closest points on a mesh of ``M`` queries.

    Attributes
    ----------
    points : (M, 3) float64
        The closest point on the mesh, world units.
    distances : (M,) float64
        Distance to it, signed (negative inside) if asked for.
    triangles : (M,) int64
        Index of the triangle it lies on (one of them where several are equally close).
    """

    points: NDArray[np.float64]
    distances: NDArray[np.float64]
    triangles: NDArray[np.int64]


class RayHits(NamedTuple):
    """The first hits of ``M`` rays on a mesh.

    Attributes
    ----------
    distances : (M,) float64
        Ray parameter ``t`` of the hit ``origin + t direction`` (world units for unit
        directions); ``inf`` where the ray misses.
    triangles : (M,) int64
        Index of the triangle hit; -1 where the ray misses.
    """

    distances: NDArray[np.float64]
    triangles: NDArray[np.int64]


def _rows(name: str, value: Any) -> NDArray[np.float64]:
    """``value`` as ``(M, 3) float64``; M may be 0. Finiteness is checked by the core."""
    array = as_float_array(name, value)
    if array.ndim != 2 or array.shape[1] != 3:
        raise InvalidInputError(f"{name} must have shape (M, 3), got {array.shape}")
    return array


class TriangleMesh:
    """A triangle mesh indexed once (a BVH over its triangles) for exact queries.

    Parameters
    ----------
    vertices : (N, 3) array_like of float, or trimesh.Trimesh
        Vertex positions, world units; or a trimesh whose vertices and faces are taken
        (then ``faces`` is omitted).
    faces : (M, 3) array_like of int
        Vertex indices of each triangle, counter-clockwise seen from outside (trimesh's
        convention) for the signs of :meth:`distances` and :meth:`contains` to hold.

    Raises
    ------
    InvalidInputError
        No vertices or no faces (an empty mesh has no distance), NaN or infinity in a
        vertex, a face index that names no vertex, wrong shapes or dtypes.

    Notes
    -----
    Degenerate (zero-area) triangles are allowed: for distances and ray casts they are the
    segment or point they collapse to; having no normal, they never decide a sign.
    Unsigned distances, closest points and ray casts hold for any triangle soup; signed
    distances and containment need a closed (watertight) mesh with consistent outward
    orientation: :attr:`is_closed` and a positive :attr:`volume`.

    Examples
    --------
    >>> import numpy as np, trimesh
    >>> from elastocap.geometry.mesh_distance import TriangleMesh
    >>> box = TriangleMesh(trimesh.creation.box())
    >>> box.distances(np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]), signed=True)
    array([-0.5,  1.5])
    """

    __slots__ = ("_mesh",)

    def __init__(self, vertices: Any, faces: Any = None) -> None:
        if isinstance(vertices, trimesh.Trimesh):
            if faces is not None:
                raise InvalidInputError("faces must be omitted when vertices is a trimesh.Trimesh")
            vertices, faces = vertices.vertices, vertices.faces
        elif faces is None:
            raise InvalidInputError("faces is missing: pass (vertices, faces) or a trimesh.Trimesh")
        points = as_float_array("vertices", vertices)
        if points.ndim != 2 or points.shape[1] != 3:
            raise InvalidInputError(f"vertices must have shape (N, 3), got {points.shape}")
        triangles = np.asarray(faces)
        if triangles.ndim != 2 or triangles.shape[1] != 3:
            raise InvalidInputError(f"faces must have shape (M, 3), got {triangles.shape}")
        if triangles.dtype.kind not in "iu" and triangles.size:
            raise InvalidInputError(f"faces must hold integer vertex indices, got dtype {triangles.dtype}")
        if triangles.dtype == np.uint64 and triangles.size and triangles.max() >= 2**63:
            raise InvalidInputError("faces holds an index too large for any mesh")
        triangles = np.ascontiguousarray(triangles, dtype=np.int64)
        self._mesh = _core.TriangleMesh(points, triangles)

    @property
    def n_vertices(self) -> int:
        """Number of vertices."""
        return self._mesh.n_vertices

    @property
    def n_faces(self) -> int:
        """Number of triangles."""
        return self._mesh.n_triangles

    @property
    def volume(self) -> float:
        """Signed enclosed volume, world units cubed: positive for a closed mesh with
        outward triangles (meaningless for an open one)."""
        return self._mesh.volume()

    @property
    def area(self) -> float:
        """Surface area, world units squared."""
        return self._mesh.area()

    @property
    def is_closed(self) -> bool:
        """Whether every edge is shared by exactly two triangles running along it in
        opposite directions: a closed (watertight), consistently oriented surface, on which
        signed distances and containment hold."""
        return self._mesh.is_closed()

    @property
    def size(self) -> float:
        """Diagonal of the axis-aligned bounding box, world units."""
        return self._mesh.diagonal()

    def closest_points(self, points: Any, *, signed: bool = False) -> ClosestPoints:
        """The closest point on the mesh of each query, its distance and triangle.

        Parameters
        ----------
        points : (M, 3) array_like of float
            Query points, world units.
        signed : bool, default False
            Sign the distances: negative inside the closed mesh.

        Returns
        -------
        ClosestPoints
            ``(points (M, 3), distances (M,), triangles (M,))``.
        """
        closest, distances, triangles = self._mesh.closest_points(_rows("points", points), bool(signed))
        return ClosestPoints(closest, distances, triangles)

    def distances(self, points: Any, *, signed: bool = False, max_distance: float = np.inf) -> NDArray[np.float64]:
        """Distance of each query to the mesh.

        Parameters
        ----------
        points : (M, 3) array_like of float
            Query points, world units.
        signed : bool, default False
            Sign the distances: negative inside the closed mesh.
        max_distance : float, default inf
            Distances beyond this are reported as ``max_distance`` (``-max_distance``
            inside): the far points' closest triangles are not searched for, their side
            is found by a ray cast. For when only a band around the surface matters.

        Returns
        -------
        (M,) float64
            World units.
        """
        limit = float(max_distance)
        if not limit >= 0:
            raise InvalidInputError(f"max_distance must be non-negative (inf for every distance exact), got {max_distance!r}")
        return self._mesh.distances(_rows("points", points), bool(signed), limit)

    def contains(self, points: Any) -> NDArray[np.bool_]:
        """``(M,) bool``: whether each query ``(M, 3)`` lies inside the closed mesh (a
        point on the surface is outside)."""
        return self._mesh.contains(_rows("points", points))

    def cast_rays(self, origins: Any, directions: Any, *, max_distance: float = np.inf) -> RayHits:
        """The first hit of each ray ``origins[i] + t directions[i]``, ``0 <= t <=
        max_distance``, front or back face alike.

        Parameters
        ----------
        origins, directions : (M, 3) array_like of float
            Ray starts (world units) and directions (any non-zero length; ``t`` is in units
            of that length).
        max_distance : float, default inf
            Largest ``t`` searched.

        Returns
        -------
        RayHits
            ``(distances (M,), triangles (M,))``, ``inf`` and -1 for rays that miss.
        """
        return RayHits(
            *self._mesh.cast_rays(_rows("origins", origins), _rows("directions", directions), float(max_distance))
        )
