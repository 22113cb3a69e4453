"""Visual hulls by voxel carving (SPEC 2) and their surfaces.

The carving runs in Rust (``rust/carve.rs``): hierarchical, parallel, with O(1) footprint
tests on summed-area tables; cameras that do not see a voxel do not carve it, and
``tolerance`` cameras may disagree (real silhouettes have holes).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import cached_property
from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray
from skimage import measure

import elastocap._core as _core
from elastocap._core import InvalidInputError
from elastocap._validate import as_count
from elastocap.cameras.rig import Rig
from elastocap.hull.grid import Grid
from elastocap.hull.sdf import SDF

__all__ = ["Hull", "masks_in_rig_order", "visual_hull"]


class Hull:
    """A carved visual hull: occupancy on a grid, with its signed distance and surface.

    Parameters
    ----------
    occupancy : (nx, ny, nz) bool
        True for voxels inside the hull.
    grid : Grid
        Where the voxels are.
    sdf : SDF, optional, keyword-only
        The hull's signed distance when already known (e.g. read back from the hull
        stage's files); computed from the occupancy on first use otherwise.
    """

    def __init__(self, occupancy: NDArray[np.bool_], grid: Grid, *, sdf: SDF | None = None) -> None:
        occ = np.ascontiguousarray(occupancy, dtype=bool)
        if occ.shape != tuple(grid.shape):
            raise InvalidInputError(f"occupancy must have the grid's shape {grid.shape}, got {occ.shape}")
        if sdf is not None and (not isinstance(sdf, SDF) or sdf.values.shape != occ.shape):
            raise InvalidInputError("sdf must be an SDF on the hull's grid")
        occ.flags.writeable = False
        self._occupancy = occ
        self.grid = grid
        if sdf is not None:
            self.__dict__["_sdf"] = sdf  # the cached_property's slot: not computed again

    @property
    def occupancy(self) -> NDArray[np.bool_]:
        """``(nx, ny, nz)`` read-only: True inside the hull."""
        return self._occupancy

    @property
    def volume(self) -> float:
        """Volume of the kept voxels, world units cubed."""
        return float(self._occupancy.sum()) * self.grid.spacing**3

    @cached_property
    def _sdf(self) -> SDF:
        return SDF.from_occupancy(self._occupancy, self.grid)

    def sdf(self) -> SDF:
        """The signed distance field of the hull (computed once, then cached)."""
        return self._sdf

    def mesh(self) -> trimesh.Trimesh:
        """The hull surface: marching cubes of the signed distance at level 0, in world units.

        The field is padded by one outside voxel so that a hull touching the grid's border
        still gives a closed surface. Computed once; each call returns a copy, so editing
        it does not change the hull's.

        Raises
        ------
        InvalidInputError
            For an empty hull (nothing to mesh).
        """
        return self._mesh.copy()

    @cached_property
    def _mesh(self) -> trimesh.Trimesh:
        if not self._occupancy.any():
            raise InvalidInputError("the hull is empty: every voxel was carved")
        h = self.grid.spacing
        values = np.pad(self._sdf.values, 1, constant_values=h)
        values = np.where(np.isfinite(values), values, np.sign(values) * 1e3 * h)
        # Level a thousandth of a voxel inside, not 0: the distances next to the surface are
        # exactly +-h/2, so where two inside voxels touch only along an edge (a pinch) the
        # two sheets' vertices coincide at level 0 and the mesh has an edge of four faces
        # (not watertight: the fast-motion capture's frame 0, seed 1).
        vertices, faces, _, _ = measure.marching_cubes(values, level=-1e-3 * h, spacing=(h, h, h))
        vertices += self.grid.origin - h
        mesh = trimesh.Trimesh(vertices, faces, process=True)
        # Outward normals whatever marching cubes' winding convention (its faces came out
        # inward for this negative-inside field, volume < 0, which made normal-based
        # consumers such as trimesh's nricp_amberg reject every match).
        if mesh.volume < 0:
            mesh.invert()
        return mesh


def masks_in_rig_order(masks: Any, rig: Rig) -> list[NDArray[np.uint8]]:
    """Silhouettes as ``(H, W) uint8`` 0/1 in the rig's camera order, each checked against its
    camera's image size; ``masks`` a dict of camera name to mask or a sequence in rig order."""
    if isinstance(masks, Mapping):
        missing = [name for name in rig.names if name not in masks]
        if missing:
            raise InvalidInputError(f"masks has no mask for camera(s) {missing}")
        ordered = [masks[name] for name in rig.names]
    elif isinstance(masks, (Sequence, np.ndarray)):
        ordered = list(masks)
        if len(ordered) != len(rig):
            raise InvalidInputError(f"got {len(ordered)} masks for {len(rig)} cameras")
    else:
        raise InvalidInputError(f"masks must be a dict of camera name to mask or a sequence, got {type(masks)}")
    out = []
    for name, camera, mask in zip(rig.names, rig.cameras, ordered):
        m = np.asarray(mask)
        if m.shape != (camera.height, camera.width):
            raise InvalidInputError(
                f"mask of camera {name!r} has shape {m.shape}, but the camera images "
                f"({camera.height}, {camera.width}) (height, width)"
            )
        if m.dtype.kind not in "biu":
            raise InvalidInputError(f"mask of camera {name!r} must be boolean or integer, got dtype {m.dtype}")
        out.append(np.ascontiguousarray(m != 0, dtype=np.uint8))
    return out


def visual_hull(
    masks: Any,
    rig: Rig,
    grid: Grid,
    *,
    tolerance: int = 0,
    footprint: str = "conservative",
) -> Hull:
    """Carve the visual hull of silhouettes seen by calibrated cameras.

    Parameters
    ----------
    masks : dict of str to (H, W) array, or sequence of (H, W) arrays in rig order
        Silhouettes, non-zero = foreground, each the size of its camera's image.
    rig : Rig
        The calibrated cameras.
    grid : Grid
        The voxels to carve, world units.
    tolerance : int, keyword-only
        A voxel is kept when at most this many of the cameras that see it reject it.
    footprint : {"conservative", "center"}, keyword-only
        The test at the finest level: ``"conservative"`` rejects a voxel only when its
        whole projected box is background (never removes a voxel the object touches);
        ``"center"`` looks at the pixel under the voxel centre (a tighter hull).

    Returns
    -------
    Hull

    Notes
    -----
    SPEC section 2. Cameras that do not see a voxel (behind them, or outside their image)
    do not carve it.
    """
    if not isinstance(rig, Rig) or len(rig) == 0:
        raise InvalidInputError("rig must be a Rig with at least one camera")
    if not isinstance(grid, Grid):
        raise InvalidInputError(f"grid must be a Grid, got {type(grid)}")
    ordered = masks_in_rig_order(masks, rig)
    cameras = rig.cameras
    if as_count("tolerance", tolerance, minimum=0) >= len(cameras):
        raise InvalidInputError(
            f"tolerance must be below the number of cameras ({len(cameras)}): with {tolerance} cameras allowed "
            "to disagree, nothing is carved"
        )
    corners = grid.bounds[np.indices((2, 2, 2)).reshape(3, -1).T, [0, 1, 2]]
    for name, camera in zip(rig.names, cameras):
        if np.all(camera.to_camera(corners)[:, 2] <= 0):
            raise InvalidInputError(f"camera {name!r} has the whole grid behind it: check its pose or the grid")
    occupancy = _core.carve(
        ordered,
        np.ascontiguousarray([c.K for c in cameras], dtype=np.float64),
        np.ascontiguousarray([c.full_dist for c in cameras], dtype=np.float64),
        np.ascontiguousarray([c.R for c in cameras], dtype=np.float64),
        np.ascontiguousarray([c.t for c in cameras], dtype=np.float64),
        (float(grid.origin[0]), float(grid.origin[1]), float(grid.origin[2])),
        grid.spacing,
        grid.shape,
        as_count("tolerance", tolerance, minimum=0),
        footprint,
    )
    return Hull(occupancy, grid)
