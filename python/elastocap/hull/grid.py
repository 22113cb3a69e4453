"""Voxel grids: where voxel ``[i, j, k]`` sits in the world."""

from __future__ import annotations

import warnings

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_float_array, as_positive

__all__ = ["Grid", "check_baseline", "space_seen_by"]


@dataclass(frozen=True)
class Grid:
    """A regular voxel grid in world units.

    Voxel ``[i, j, k]`` is the cube of edge ``spacing`` centred at
    ``origin + spacing * (i, j, k)`` (DESIGN conventions).

    Parameters
    ----------
    origin : (3,) array_like of float
        World position of the centre of voxel ``[0, 0, 0]``.
    spacing : float
        Voxel edge, world units, positive.
    shape : (3,) tuple of int
        Voxels per axis ``(nx, ny, nz)``, each at least 1.
    """

    origin: NDArray[np.float64]
    spacing: float
    shape: tuple[int, int, int]

    def __init__(self, origin: Any, spacing: float, shape: Any) -> None:
        o = as_float_array("origin", origin).reshape(-1).copy()
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise InvalidInputError(f"origin must be 3 finite numbers, got {origin!r}")
        values = np.asarray(shape).reshape(-1)
        if values.dtype.kind not in "iuf" or not np.all(np.isfinite(values)) or not np.all(values == np.round(values)):
            raise InvalidInputError(f"shape must be 3 positive integers, got {shape!r}")
        s = tuple(int(v) for v in values)
        if len(s) != 3 or min(s) < 1:
            raise InvalidInputError(f"shape must be 3 positive integers, got {shape!r}")
        o.flags.writeable = False
        object.__setattr__(self, "origin", o)
        object.__setattr__(self, "spacing", as_positive("spacing", spacing))
        object.__setattr__(self, "shape", s)

    @classmethod
    def around(cls, lower: Any, upper: Any, resolution: int) -> Grid:
        """The grid covering the box ``[lower, upper]`` with ``resolution`` voxels along its
        longest side (voxel centres inside the box, edges on its faces)."""
        lo = np.asarray(lower, dtype=np.float64)
        hi = np.asarray(upper, dtype=np.float64)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(hi > lo):
            raise InvalidInputError(f"need lower < upper on every axis, got {lower!r} and {upper!r}")
        if int(resolution) < 1:
            raise InvalidInputError(f"resolution must be at least 1, got {resolution!r}")
        spacing = float((hi - lo).max()) / int(resolution)
        shape = np.maximum(1, np.ceil((hi - lo) / spacing - 1e-9)).astype(int)
        return cls(lo + spacing / 2, spacing, tuple(shape))

    @classmethod
    def seen_by(cls, rig: Any, resolution: int, *, samples: int = 48) -> Grid:
        """The grid over the box of the space every camera of ``rig`` sees, with
        ``resolution`` voxels along its longest side.

        Samples a box around the camera centres (``samples`` per side) and keeps the points
        in front of every camera and inside every image.

        Raises
        ------
        InvalidInputError
            When no sampled point is seen by all cameras.
        """
        lower, upper = space_seen_by(rig, samples=samples)
        return cls.around(lower, upper, resolution)

    @property
    def bounds(self) -> NDArray[np.float64]:
        """``(2, 3)``: lower and upper corners of the box the voxels cover, world units."""
        lo = self.origin - self.spacing / 2
        return np.stack([lo, lo + self.spacing * np.array(self.shape)])

    def centers(self) -> NDArray[np.float64]:
        """``(nx, ny, nz, 3)`` world positions of all voxel centers."""
        axes = [self.origin[a] + self.spacing * np.arange(self.shape[a]) for a in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)

    def centres(self) -> NDArray[np.float64]:
        """Deprecated spelling of :meth:`centers` (the API spells it as numpy and OpenCV do)."""
        warnings.warn("Grid.centres() is now Grid.centers()", DeprecationWarning, stacklevel=2)
        return self.centers()

    def to_index(self, points: Any) -> NDArray[np.float64]:
        """``(N, 3)`` continuous voxel indices of world points (centre of voxel = integer)."""
        return (np.asarray(points, dtype=np.float64) - self.origin) / self.spacing


def check_baseline(rig: Any) -> None:
    """Refuse a rig of several cameras that all sit at one centre: views from one point
    carry no depth, so neither carving nor the body fit can place anything."""
    centres = np.array([c.center for c in rig.cameras])
    middle = centres.mean(axis=0)
    if len(centres) > 1 and np.linalg.norm(centres - middle, axis=1).max() <= 1e-9 * (1 + np.abs(middle).max()):
        raise InvalidInputError(
            f"all {len(centres)} cameras are at one centre {middle.tolist()}: views from one point carry no "
            "depth; check the calibration's translations"
        )


def space_seen_by(rig: Any, *, samples: int = 48) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(lower (3,), upper (3,))``: the box around the space every camera of ``rig`` sees
    (see :meth:`Grid.seen_by`)."""
    cameras = list(rig.cameras)
    check_baseline(rig)
    centres = np.array([c.center for c in cameras])
    middle = centres.mean(axis=0)
    reach = max(float(np.linalg.norm(centres - middle, axis=1).max()), 1e-9) * 1.5
    axis = np.linspace(-reach, reach, samples)
    points = middle + np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    seen = np.ones(len(points), bool)
    for camera in cameras:
        seen &= camera.visible(points)
    if not seen.any():
        raise InvalidInputError("no point is seen by all cameras: check the calibration")
    step = 2 * reach / (samples - 1)
    return points[seen].min(axis=0) - step, points[seen].max(axis=0) + step
