"""Node placement for element-free models (SPEC 4.1): surface nodes on a remeshed surface,
interior nodes on a jittered grid, spacing chosen from a requested node count.

3-D: the exact signed distance to the closed mesh (:class:`elastocap.geometry.mesh_distance.TriangleMesh`,
parry's BVH) is sampled on a grid of spacing ``h``; the surface is re-extracted by marching
cubes (vertices about ``h`` apart) and its vertices are moved to their closest points on the
mesh; interior nodes are the points of a jittered grid of spacing ``h`` whose signed distance
is below ``-h / 2``. Only points are queried, about 3 / h^3 per unit volume, never a voxel
grid finer than ``h``. 2-D: a mask's contours resampled every ``h`` and a jittered grid.
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
from elastocap.geometry.mesh_distance import TriangleMesh

# Offset of the grid behind marching cubes below the mesh's bounding box, in units of h:
# more than a cell and no simple fraction of one.
GRID_SHIFT = 1.2345
# Smallest |signed distance| a marching-cubes corner is given, in units of h.
CORNER_CLEARANCE = 0.125
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
    # Volume (3-D) or area (2-D) of the solid the nodes fill, world units.
    volume: float


def check_mesh(mesh: object) -> tuple[trimesh.Trimesh, TriangleMesh]:
    """The mesh, and its index for exact queries with outward triangles, if it is a closed,
    consistently oriented, finite triangle mesh enclosing a volume; else a clear error."""
    if not isinstance(mesh, trimesh.Trimesh):
        raise InvalidInputError(f"mesh must be a trimesh.Trimesh, got {type(mesh).__name__}")
    if len(mesh.faces) == 0:
        raise InvalidInputError("mesh has no faces")
    if not np.all(np.isfinite(mesh.vertices)):
        raise InvalidInputError("mesh has non-finite vertices (NaN or infinity)")
    faces = np.asarray(mesh.faces)
    index = TriangleMesh(mesh.vertices, faces)
    if not index.is_closed:
        raise InvalidInputError(
            "mesh is not watertight and consistently oriented (it has open or non-manifold "
            "edges, or neighbouring faces wound against each other); close it first, e.g. with "
            "trimesh.repair.fill_holes and trimesh.repair.fix_winding"
        )
    volume = index.volume
    extent = float(np.max(np.ptp(mesh.vertices, axis=0)))
    if not abs(volume) > 1e-9 * extent**3:
        raise InvalidInputError(f"mesh encloses no volume (volume {abs(volume):g} for extent {extent:g})")
    if volume < 0:  # signs need outward triangles: an inside-out mesh is read the other way round
        index = TriangleMesh(mesh.vertices, faces[:, ::-1])
    return mesh, index


def _lattice(lower: NDArray[np.float64], upper: NDArray[np.float64], h: float) -> NDArray[np.float64]:
    """``(N, 3)``: the points ``lower + h (i, j, k)`` up to ``upper``, C order."""
    axes = [np.arange(lower[a], upper[a], h) for a in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _sample_mesh_at(index: TriangleMesh, mesh: trimesh.Trimesh, h: float, rng: np.random.Generator) -> NodeSet:
    lo, hi = mesh.bounds
    # One cell beyond the mesh each way, so that marching cubes closes the surface; shifted
    # off the bounding box, so that the flat faces of boxes and marching-cubes meshes do not
    # lie on grid planes (corners at distance 0 give marching cubes coinciding vertices).
    origin = lo - h * GRID_SHIFT
    shape = tuple(int(v) for v in np.floor((hi - lo) / h + GRID_SHIFT).astype(int) + 3)
    corners = _lattice(origin, origin + (np.array(shape) - 0.5) * h, h)
    # Every corner of a cell the surface crosses is within sqrt(3) h of it: farther values
    # only need their sign, which spares searching deep inside the solid.
    values = index.distances(corners, signed=True, max_distance=2 * h).reshape(shape)
    # A corner almost on the surface puts the vertices of all its edges next to it: nodes
    # a thousandth of h apart, which leave the stiffness near-zero-energy modes. Held at
    # least CORNER_CLEARANCE h off the zero level (the voxelised field this replaced never
    # came nearer than h / 8), the vertices stay apart; they are projected onto the mesh next.
    values = np.where(values < 0, np.minimum(values, -CORNER_CLEARANCE * h), np.maximum(values, CORNER_CLEARANCE * h))
    vertices, faces, _, _ = measure.marching_cubes(values, level=0.0, spacing=(h,) * 3)
    surface = trimesh.Trimesh(index.closest_points(vertices + origin).points, faces, process=True)
    surface.remove_unreferenced_vertices()
    if surface.volume < 0:  # outward normals whatever marching cubes' convention
        surface.invert()
    lattice = _lattice(lo + h / 2, hi, h)
    lattice = lattice + rng.uniform(-JITTER, JITTER, lattice.shape) * h
    interior = lattice[index.distances(lattice, signed=True, max_distance=h) < -h / 2]
    nodes = np.ascontiguousarray(np.vstack([surface.vertices, interior]))
    return NodeSet(nodes, len(surface.vertices), np.asarray(surface.faces, dtype=np.int64), h, index.volume)


def sample_mesh(mesh: trimesh.Trimesh, n_nodes: int, seed: int) -> NodeSet:
    """About ``n_nodes`` nodes for the closed ``mesh`` (within a few percent)."""
    mesh, index = check_mesh(mesh)
    h, exponent = _first_spacing(index.volume, index.area, n_nodes)
    return _search_spacing(lambda h: _sample_mesh_at(index, mesh, h, np.random.default_rng(seed)), h, n_nodes, exponent)


def _first_spacing(volume: float, area: float, n_nodes: int) -> tuple[float, float]:
    """The spacing ``h`` that the count model ``V / h^3 + A / h^2 = n`` predicts, and the
    model's ``-d log n / d log h`` there.

    Interior nodes fill the volume deeper than ``h / 2``, about ``(V - A h / 2) / h^3``;
    marching cubes puts about ``1.5 A / h^2`` vertices on the surface (one per crossed grid
    edge: ``|n_x| + |n_y| + |n_z|`` per ``h^2``, 1.5 on average over directions). Thin
    shapes, whose nodes are mostly on the surface, then start within a few percent of the
    count instead of a factor of two, which saves a round of sampling."""
    roots = np.roots([volume, area, 0.0, -float(n_nodes)])
    x = float(max(r.real for r in roots if abs(r.imag) < 1e-9 * abs(r) and r.real > 0))
    return 1.0 / x, (3 * volume * x**3 + 2 * area * x**2) / n_nodes


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
    return NodeSet(nodes, len(boundary), np.vstack(edges).astype(np.int64), h, float(mask.sum()))


def sample_mask(mask: NDArray[np.bool_], n_nodes: int, seed: int) -> NodeSet:
    """About ``n_nodes`` nodes for a 2-D mask, in pixel coordinates ``(x = column, y = row)``."""
    if not mask.any():
        raise InvalidInputError("mask is empty: nothing to model")
    h = max(float(np.sqrt(mask.sum() / n_nodes)), 1.0)
    return _search_spacing(lambda h: _sample_mask_at(mask, max(h, 1.0), np.random.default_rng(seed)), h, n_nodes, 2.0)
