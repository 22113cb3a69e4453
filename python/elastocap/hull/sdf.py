"""Signed distance fields of voxel occupancy, and their sampling.

The transform is exact and linear-time (Felzenszwalb & Huttenlocher 2012, in
``rust/sdf.rs``); sampling is trilinear with the gradient of the interpolant
(``rust/grid_sample.rs``). SPEC section 3.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

import elastocap._core as _core
from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_points
from elastocap.hull.grid import Grid

__all__ = ["SDF", "signed_distance"]


def _occupancy(occupancy: Any) -> NDArray[np.bool_]:
    array = np.asarray(occupancy)
    if array.ndim != 3:
        raise InvalidInputError(f"occupancy must be a 3-D array (nx, ny, nz), got shape {array.shape}")
    if array.size == 0:
        raise InvalidInputError(f"occupancy is empty: shape {array.shape}")
    if array.dtype != np.bool_:
        if array.dtype.kind not in "biu":
            raise InvalidInputError(f"occupancy must be boolean (or 0/1 integers), got dtype {array.dtype}")
        array = array != 0
    return np.ascontiguousarray(array)


def signed_distance(occupancy: Any, spacing: float | Any = 1.0) -> NDArray[np.float64]:
    """Exact signed distance to the boundary of an occupancy grid, negative inside.

    Parameters
    ----------
    occupancy : (nx, ny, nz) array_like of bool
        True where a voxel is inside.
    spacing : float or (3,) floats
        Voxel edge per axis, world units.

    Returns
    -------
    sdf : (nx, ny, nz) float64
        World units. With ``edt_in`` the Euclidean distance from an inside voxel centre to
        the nearest outside one (and ``edt_out`` the reverse), the surface is placed half a
        voxel from the centres: ``-(edt_in - h/2)`` inside, ``edt_out - h/2`` outside, with
        ``h`` the smallest spacing. An empty grid gives ``+inf`` everywhere and a full grid
        ``-inf`` (there is no boundary).

    Notes
    -----
    ``edt_in`` and ``edt_out`` equal ``scipy.ndimage.distance_transform_edt`` with
    ``sampling=spacing`` (to rounding), computed in linear time in parallel.
    """
    occ = _occupancy(occupancy)
    if isinstance(spacing, (str, bytes)):
        raise InvalidInputError(f"spacing must be a number or 3 numbers, got {spacing!r}")
    s = np.broadcast_to(np.asarray(spacing, dtype=np.float64), (3,))
    if not np.all(np.isfinite(s) & (s > 0)):
        raise InvalidInputError(f"spacing must be positive and finite, got {spacing!r}")
    return _core.signed_distance(occ, (float(s[0]), float(s[1]), float(s[2])))


class SDF:
    """A signed distance field on a :class:`~elastocap.hull.grid.Grid`, sampled trilinearly.

    Parameters
    ----------
    values : (nx, ny, nz) array_like of float
        Signed distance at the voxel centres, world units, negative inside.
    grid : Grid
        Where the voxels are.

    Notes
    -----
    Outside the grid, a sample is the value at the nearest point of the grid box plus the
    distance to the box (SPEC 3), and its gradient gains the outward unit vector.
    """

    __slots__ = ("_values", "grid")

    def __init__(self, values: Any, grid: Grid) -> None:
        v = np.ascontiguousarray(values, dtype=np.float64)
        if v.shape != tuple(grid.shape):
            raise InvalidInputError(f"values must have the grid's shape {grid.shape}, got {v.shape}")
        v.flags.writeable = False
        self._values = v
        self.grid = grid

    @classmethod
    def from_occupancy(cls, occupancy: Any, grid: Grid) -> SDF:
        """The signed distance of an occupancy grid (see :func:`signed_distance`)."""
        return cls(signed_distance(occupancy, grid.spacing), grid)

    @property
    def values(self) -> NDArray[np.float64]:
        """``(nx, ny, nz)`` read-only signed distances at the voxel centres."""
        return self._values

    def sample(self, points: Any) -> NDArray[np.float64]:
        """``(N,)`` signed distance at ``(N, 3)`` world points."""
        p = as_points("points", points, dims=(3,))
        values, _ = _core.sample_grid(self._values, tuple(self.grid.origin), self.grid.spacing, p, False)
        return values

    def gradient(self, points: Any) -> NDArray[np.float64]:
        """``(N, 3)`` gradient of the trilinear interpolant at world points (about unit
        length near the surface, pointing outwards)."""
        return self.sample_with_gradient(points)[1]

    def sample_with_gradient(self, points: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(values (N,), gradients (N, 3))`` in one pass."""
        p = as_points("points", points, dims=(3,))
        values, gradients = _core.sample_grid(self._values, tuple(self.grid.origin), self.grid.spacing, p, True)
        assert gradients is not None
        return values, gradients

    def closest_points(self, points: Any, *, steps: int = 3) -> NDArray[np.float64]:
        """``(N, 3)`` points on the zero level near each point, by ``steps`` Newton steps
        ``x <- x - d(x) g / |g|^2`` (SPEC 3). Points where the gradient vanishes stay put."""
        x = as_points("points", points, dims=(3,)).copy()
        for _ in range(as_count("steps", steps)):
            d, g = self.sample_with_gradient(x)
            g2 = np.einsum("ij,ij->i", g, g)
            ok = np.isfinite(d) & (g2 > 1e-12)
            x[ok] -= (d[ok] / g2[ok])[:, None] * g[ok]
        return x
