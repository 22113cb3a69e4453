"""The targets of an elastic fit (SPEC 5): a 3-D target's signed distance field (an
:class:`SDF`, a :class:`Hull` or a closed trimesh), a 2-D target's (a binary mask), and the
frame numbers of a sequence of targets."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.geometry.mesh_distance import TriangleMesh
from elastocap.hull.carve import Hull
from elastocap.hull.grid import Grid
from elastocap.hull.sdf import SDF

__all__ = ["field_arrays", "frame_numbers", "mask_field", "target_field"]


def target_field(target: Any) -> SDF:
    """The signed distance field of a target: an :class:`SDF`, a :class:`Hull`, or a closed
    trimesh (its exact signed distance sampled every 1/100 of its largest extent). Non-finite values (an empty or full
    grid) are an error."""
    if isinstance(target, SDF):
        sdf = target
    elif isinstance(target, Hull):
        if not target.occupancy.any():
            raise InvalidInputError("the hull is empty: every voxel was carved")
        sdf = target.sdf()
    elif isinstance(target, trimesh.Trimesh):
        if not target.is_watertight:
            raise InvalidInputError("a target mesh must be watertight")
        lo, hi = target.bounds
        h = float(np.max(hi - lo)) / 100
        grid = Grid(lo - 5 * h, h, tuple(int(v) for v in np.ceil((hi - lo) / h).astype(int) + 11))
        faces = np.asarray(target.faces)
        # Exact signed distances at the voxel centres (no voxelisation error); signs need
        # outward triangles, so an inside-out mesh is read the other way round.
        index = TriangleMesh(target.vertices, faces if target.volume > 0 else faces[:, ::-1])
        sdf = SDF(index.distances(grid.centers().reshape(-1, 3), signed=True).reshape(grid.shape), grid)
    else:
        raise InvalidInputError(f"a target must be an SDF, a Hull or a trimesh.Trimesh, got {type(target).__name__}")
    if not np.all(np.isfinite(sdf.values)):
        raise InvalidInputError("the target's signed distance is not finite (an empty or completely full grid)")
    return sdf


def mask_field(target: Any) -> tuple[NDArray[np.float64], tuple[float, float, float], float]:
    """A 2-D target: the signed distance (pixels) of a binary mask ``(H, W)`` as a grid one
    voxel thick over the model's pixel coordinates, pixel ``(row, column)`` at ``(column,
    row)``."""
    from elastocap.hull.sdf import signed_distance

    if isinstance(target, (SDF, Hull, trimesh.Trimesh)):
        raise InvalidInputError(f"a 2-D model fits to masks (H, W), not to a 3-D {type(target).__name__}")
    mask = np.asarray(target)
    if mask.ndim != 2:
        raise InvalidInputError(f"a 2-D target must be a mask of shape (H, W), got shape {mask.shape}")
    inside = mask.astype(bool)
    if not inside.any() or inside.all():
        raise InvalidInputError("a target mask is empty or full: it has no contour to fit to")
    values = signed_distance(np.ascontiguousarray(inside.T)[:, :, None])
    return values, (0.0, 0.0, 0.0), 1.0


def field_arrays(target: Any) -> tuple[NDArray[np.float64], tuple[float, float, float], float]:
    """``(values, origin, spacing)`` of a 3-D :class:`SDF` or of :func:`mask_field`'s tuple."""
    if isinstance(target, SDF):
        o = target.grid.origin
        return np.ascontiguousarray(target.values, dtype=np.float64), (float(o[0]), float(o[1]), float(o[2])), float(target.grid.spacing)
    values, origin, spacing = target
    return np.ascontiguousarray(values, dtype=np.float64), origin, spacing


def frame_numbers(targets: Sequence[Any] | Mapping[int, Any]) -> list[int]:
    """The frame numbers of ``targets``: a mapping's keys (ascending), or a sequence's
    positions."""
    if isinstance(targets, Mapping):
        keys = list(targets.keys())
        if not all(isinstance(key, (int, np.integer)) and not isinstance(key, bool) for key in keys):
            raise InvalidInputError("targets given as a mapping must be keyed by int frame numbers")
        return sorted(int(key) for key in keys)
    if isinstance(targets, (str, bytes)) or not isinstance(targets, Sequence):
        raise InvalidInputError(f"targets must be a sequence or a mapping of frame -> target, got {type(targets).__name__}")
    return list(range(len(targets)))
