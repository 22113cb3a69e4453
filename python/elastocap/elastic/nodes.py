"""Node placement for element-free models (SPEC 4.1): surface nodes on a remeshed surface,
interior nodes on a jittered grid, spacing chosen from a requested node count.

3-D: the closed mesh is voxelised (:mod:`elastocap.hull.voxelize`) at a quarter of the node
spacing ``h`` and turned into an exact signed distance field; the surface is re-extracted by
marching cubes with steps of ``h`` (vertices about ``h`` apart) and its vertices are pulled
onto the zero level; interior nodes are the points of a jittered grid of spacing ``h`` at
least ``h / 2`` inside. 2-D: a mask's contours resampled every ``h`` and a jittered grid.
A jittered grid rather than uniform random points: SPEC 4.1 measured that random clouds
give soft near-zero-energy modes and grids do not.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import trimesh
from numpy.typing import NDArray
from scipy import ndimage
from skimage import measure

from elastocap._core import InvalidInputError
from elastocap.hull.voxelize import solid_voxels
from elastocap.hull.grid import Grid
from elastocap.hull.sdf import SDF

# Voxels per node spacing for the distance field behind the sampling.
SUBDIVISION = 4
# Jitter of the interior grid, a fraction of h each way.
JITTER = 0.2
# Rounds of re-estimating h from the measured node count (a secant step on log count vs
# log h: the exponent is between -2 (surface-dominated, thin shapes) and -3 (bulky ones)).
ROUNDS = 6


@dataclass(frozen=True)
class NodeSet:
    """Nodes (surface ones first), the surface faces/edges over them, and the spacing."""

    nodes: NDArray[np.float64]
    n_surface: int
    faces: NDArray[np.int64]
    spacing: float


def check_mesh(mesh: object) -> trimesh.Trimesh:
    """The mesh if it is a closed, finite, non-degenerate triangle mesh; else a clear error."""
    if not isinstance(mesh, trimesh.Trimesh):
        raise InvalidInputError(f"mesh must be a trimesh.Trimesh, got {type(mesh).__name__}")
    if len(mesh.faces) == 0:
        raise InvalidInputError("mesh has no faces")
    if not np.all(np.isfinite(mesh.vertices)):
        raise InvalidInputError("mesh has non-finite vertices (NaN or infinity)")
    if not mesh.is_watertight:
        raise InvalidInputError(
            "mesh is not watertight (it has open edges or non-manifold edges); "
            "close it first, e.g. with trimesh.repair.fill_holes"
        )
    volume = abs(float(mesh.volume))
    extent = float(np.max(mesh.extents))
    if not volume > 1e-9 * extent**3:
        raise InvalidInputError(f"mesh encloses no volume (volume {volume:g} for extent {extent:g})")
    return mesh


def _sample_mesh_at(mesh: trimesh.Trimesh, h: float, rng: np.random.Generator) -> NodeSet:
    pitch = h / SUBDIVISION
    lo, hi = mesh.bounds
    pad = 2 * SUBDIVISION * pitch
    shape = tuple(int(v) for v in np.ceil((hi - lo + 2 * pad) / pitch).astype(int) + 1)
    grid = Grid(lo - pad, pitch, shape)
    sdf = SDF.from_occupancy(solid_voxels(mesh, grid), grid)
    values = np.where(np.isfinite(sdf.values), sdf.values, pad)
    vertices, faces, _, _ = measure.marching_cubes(values, level=0.0, spacing=(pitch,) * 3, step_size=SUBDIVISION)
    surface = trimesh.Trimesh(sdf.closest_points(vertices + grid.origin), faces, process=True)
    surface.remove_unreferenced_vertices()
    if surface.volume < 0:  # outward normals whatever marching cubes' convention
        surface.invert()
    axes = [np.arange(lo[a] + h / 2, hi[a], h) for a in range(3)]
    lattice = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    lattice = lattice + rng.uniform(-JITTER, JITTER, lattice.shape) * h
    interior = lattice[sdf.sample(lattice) < -h / 2]
    nodes = np.ascontiguousarray(np.vstack([surface.vertices, interior]))
    return NodeSet(nodes, len(surface.vertices), np.asarray(surface.faces, dtype=np.int64), h)


def sample_mesh(mesh: trimesh.Trimesh, n_nodes: int, seed: int) -> NodeSet:
    """About ``n_nodes`` nodes for the closed ``mesh`` (within a few percent)."""
    mesh = check_mesh(mesh)
    h = (abs(float(mesh.volume)) / n_nodes) ** (1 / 3)
    return _search_spacing(lambda h: _sample_mesh_at(mesh, h, np.random.default_rng(seed)), h, n_nodes, 3.0)


def _search_spacing(sample: Any, h: float, n_nodes: int, exponent: float) -> NodeSet:
    """The node set whose count is nearest ``n_nodes`` over a few secant steps in h."""
    best: NodeSet | None = None
    previous: tuple[float, int] | None = None
    for _ in range(ROUNDS):
        found = sample(h)
        count = len(found.nodes)
        if best is None or abs(count - n_nodes) < abs(len(best.nodes) - n_nodes):
            best = found
        if abs(count / n_nodes - 1) < 0.03:
            break
        if previous is not None and previous[1] != count and previous[0] != h:
            slope = np.log(count / previous[1]) / np.log(h / previous[0])
            exponent = float(np.clip(-slope, 1.0, 4.0))
        previous = (h, count)
        h *= (count / n_nodes) ** (1 / exponent)
    assert best is not None
    return best


def _resample_closed(contour: NDArray[np.float64], h: float) -> NDArray[np.float64]:
    closed = np.vstack([contour, contour[:1]])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    count = max(3, int(round(arc[-1] / h)))
    at = np.linspace(0.0, arc[-1], count, endpoint=False)
    return np.stack([np.interp(at, arc, closed[:, a]) for a in range(2)], axis=1)


def _sample_mask_at(mask: NDArray[np.bool_], h: float, rng: np.random.Generator) -> NodeSet:
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    rings = [_resample_closed(c[:, 0, :].astype(np.float64), h) for c in contours if len(c) >= 3]
    edges, start = [], 0
    for ring in rings:
        index = np.arange(start, start + len(ring))
        edges.append(np.stack([index, np.roll(index, -1)], axis=1))
        start += len(ring)
    boundary = np.vstack(rings)
    # Distance inside the mask (pixels), at pixel centres (x = column, y = row).
    depth = ndimage.distance_transform_edt(mask)
    axes = [np.arange(h / 2, mask.shape[1 - a], h) for a in range(2)]
    lattice = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)
    lattice = lattice + rng.uniform(-JITTER, JITTER, lattice.shape) * h
    rows = np.clip(np.round(lattice[:, 1]).astype(int), 0, mask.shape[0] - 1)
    cols = np.clip(np.round(lattice[:, 0]).astype(int), 0, mask.shape[1] - 1)
    interior = lattice[depth[rows, cols] > h / 2 + 0.5]
    nodes = np.ascontiguousarray(np.vstack([boundary, interior]))
    return NodeSet(nodes, len(boundary), np.vstack(edges).astype(np.int64), h)


def sample_mask(mask: NDArray[np.bool_], n_nodes: int, seed: int) -> NodeSet:
    """About ``n_nodes`` nodes for a 2-D mask, in pixel coordinates ``(x = column, y = row)``."""
    if not mask.any():
        raise InvalidInputError("mask is empty: nothing to model")
    h = max(float(np.sqrt(mask.sum() / n_nodes)), 1.0)
    return _search_spacing(lambda h: _sample_mask_at(mask, max(h, 1.0), np.random.default_rng(seed)), h, n_nodes, 2.0)
