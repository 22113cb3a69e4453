"""The element-free elastic model (SPEC 4): a meshless elastic body built from a closed
mesh or a mask, with rotation compensation, energies, forces, the per-iteration linear
system and a static solver with fixed nodes and loads.

The kernels live in ``rust/elastic.rs`` (rotations, energy, forces, right-hand sides,
matrix-free products) and ``rust/efg/assembly.rs`` (the block stiffness on its fixed
pattern); node placement in :mod:`elastocap.elastic.nodes`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import scipy.sparse
import scipy.sparse.linalg
import trimesh
from numpy.typing import NDArray

import elastocap._core as _core
from elastocap._core import InvalidInputError
from elastocap.elastic.nodes import NodeSet, sample_mask, sample_mesh
from elastocap._validate import as_count, as_float_array, as_points
from elastocap.geometry.neighbors import knn

__all__ = ["ElasticModel", "StaticSolution"]

ROTATIONS = ("rhs", "warped", "none")
# Strength of the consistency penalty, chosen by measurement (benches/README.md).
STABILIZATION = 0.1


@dataclass(frozen=True)
class StaticSolution:
    """Result of :meth:`ElasticModel.solve_static`.

    Attributes
    ----------
    positions : (N, D) float64
        Node positions, units of the model.
    iterations : int
        Rotation updates done (1 for ``rotation="none"``).
    converged : bool
        Whether the largest node move of the last update fell below the tolerance.
    step : float
        That largest move, units of the model.
    """

    positions: NDArray[np.float64]
    iterations: int
    converged: bool
    step: float


def _read_only(array: Any) -> Any:
    """A C-contiguous copy that cannot be written: derived data is never silently lost to
    an in-place edit of a copy the model does not see."""
    array = np.array(array, order="C")
    array.flags.writeable = False
    return array


def _rebuild_model(nodes: NDArray[np.float64], volumes: NDArray[np.float64], options: dict[str, Any]) -> ElasticModel:
    """Unpickling: :meth:`ElasticModel.__reduce__`."""
    return ElasticModel(nodes, volumes, **options)


def _density_volumes(nodes: NDArray[np.float64], k: int, total: float) -> NDArray[np.float64]:
    """SPEC 4.1: ``V_p`` proportional to ``r_k^D`` (inverse local density), summing to
    ``total``."""
    distances, _ = knn(nodes, k - 1)
    share = distances[:, -1] ** nodes.shape[1]
    return np.ascontiguousarray(total * share / share.sum())


# Poisson's ratio of models built from a mesh (issue 17, item 4): a body's volume is nearly
# constant, and the fit's coverage term pulls the surface into hull volume that
# overestimates the body. Fast-motion capture, seed 2, 2,500 nodes, 14 frames: volume
# 0.983-1.079 of rest at 0.3, 0.982-1.051 at 0.45, 0.980-1.047 at 0.48; the 3-D cantilever's
# tip error at 9 nodes across -3.8% at 0.3, -5.6% at 0.48 (mild locking).
MESH_POISSON = 0.48

class ElasticModel:
    """A meshless (element-free Galerkin) elastic body.

    Build one with :meth:`from_mesh` (3-D, any closed mesh such as a visual hull's surface),
    :meth:`from_mask` (2-D) or directly from nodes and volumes.

    Parameters
    ----------
    nodes : (N, D) array_like of float
        Rest positions, D = 2 or 3, any length unit.
    volumes : (N,) array_like of float
        Nodal volumes (areas in 2-D), positive, units of the nodes cubed (squared).
    k : int, keyword-only
        Neighbours per node, the node itself included (the paper: 20), ``D + 1 <= k <= N``.
    youngs : float, keyword-only
        Young's modulus E > 0 (stress units).
    poisson : float, keyword-only
        Poisson's ratio in ``[0, 0.5)``.
    rotation : {"rhs", "warped", "none"}, keyword-only
        SPEC 4.4: ``"rhs"`` the paper's (rotated rest shapes on the right-hand side, the
        matrix fixed), ``"warped"`` corotational (``R_p k_p R_p^T``), ``"none"`` plain linear
        elasticity.
    plane : {"strain", "stress"}, keyword-only
        2-D only: plane strain or plane stress.
    rotation_fit : {"gradient", "weighted"}, keyword-only
        ``R_p`` is the polar rotation of the MLS deformation gradient (default) or of the
        paper's Gaussian-weighted covariance ``A_p``. Measured on a bar bent by 90 degrees:
        the ``"rhs"`` iteration diverges with ``"weighted"`` and converges with
        ``"gradient"`` (benches/README.md).
    stabilization : float, keyword-only
        Strength ``epsilon`` (relative to the shear modulus) of the consistency penalty that
        stabilises nodal integration (SPEC 4.3): ``1/2 sum_p s_p sum_j |r_pj|^2 / |X_j -
        X_p|^2`` with ``r_pj`` the neighbour's deviation from the affine field node p's
        gradient predicts and ``s_p = epsilon mu V_p / (k - 1)``. Zero for every affine
        motion (rigid ones included), so it costs a smooth deformation almost nothing, but it
        stiffens the soft node-to-node oscillations nodal integration leaves, which both
        ripple a fitted surface and slow the solver (benches/README.md). 0 turns it off.
    surface_nodes : (S,) array_like of int, optional
        Indices of the nodes on the surface.
    surface_faces : (F, 3) (3-D) or (E, 2) (2-D) array_like of int, optional
        The surface's triangles (edges in 2-D) over node indices.

    Raises
    ------
    InvalidInputError
        Wrong shapes, NaN, ``k`` out of range, ``poisson`` outside ``[0, 0.5)``, volumes that
        are not positive, neighbourhoods that do not span the space (e.g. coplanar nodes).
    """

    def __init__(
        self,
        nodes: Any,
        volumes: Any,
        *,
        k: int = 20,
        youngs: float = 1.0,
        poisson: float = 0.3,
        rotation: str = "rhs",
        plane: str = "strain",
        rotation_fit: str = "gradient",
        stabilization: float = STABILIZATION,
        surface_nodes: Any = None,
        surface_faces: Any = None,
    ) -> None:
        array = as_points("nodes", nodes)
        n, dim = array.shape
        bad = ~np.isfinite(array).all(axis=1)
        if bad.any():
            raise InvalidInputError(f"nodes hold a non-finite value (NaN or infinity) in row {int(np.argmax(bad))}")
        k = as_count("k", k, minimum=dim + 1)
        if k > n:
            raise InvalidInputError(f"k = {k} exceeds the number of nodes ({n})")
        vols = as_float_array("volumes", volumes)
        if vols.shape != (n,):
            raise InvalidInputError(f"volumes must have shape (N,) = ({n},) like nodes, got {vols.shape}")
        if rotation not in ROTATIONS:
            raise InvalidInputError(f"rotation must be one of {ROTATIONS}, got {rotation!r}")
        self._core = _core.ElasticCore(
            array, k, vols, float(youngs), float(poisson), plane, rotation, rotation_fit, float(stabilization)
        )
        self.stabilization = float(stabilization)
        self.rotation, self.rotation_fit = rotation, rotation_fit
        self.k = k
        self.youngs, self.poisson, self.plane = float(youngs), float(poisson), plane
        self.surface_nodes = _read_only(
            np.zeros(0, np.int64) if surface_nodes is None else np.array(surface_nodes, dtype=np.int64)
        )
        self.surface_faces = _read_only(
            np.zeros((0, dim), np.int64) if surface_faces is None else np.array(surface_faces, dtype=np.int64)
        )
        if self.surface_nodes.size and (self.surface_nodes.min() < 0 or self.surface_nodes.max() >= n):
            raise InvalidInputError(f"surface_nodes must index the {n} nodes")

    @classmethod
    def _from_node_set(cls, found: NodeSet, total: float, **options: Any) -> ElasticModel:
        k = options.get("k", 20)
        n = len(found.nodes)
        if as_count("k", k, minimum=found.nodes.shape[1] + 1) > n:
            raise InvalidInputError(f"k = {k} exceeds the number of nodes ({n})")
        volumes = _density_volumes(found.nodes, k, total)
        return cls(
            found.nodes,
            volumes,
            surface_nodes=np.arange(found.n_surface),
            surface_faces=found.faces,
            **options,
        )

    @classmethod
    def from_mesh(
        cls,
        mesh: trimesh.Trimesh,
        *,
        n_nodes: int = 2500,
        k: int = 20,
        youngs: float = 1.0,
        poisson: float = MESH_POISSON,
        rotation: str = "rhs",
        rotation_fit: str = "gradient",
        stabilization: float = STABILIZATION,
        seed: int = 0,
    ) -> ElasticModel:
        """A 3-D model of the solid a closed mesh bounds (SPEC 4.1).

        Options as in :class:`ElasticModel`; ``poisson`` defaults to :data:`MESH_POISSON`
        (nearly incompressible: a body fitted to hulls keeps its volume).

        Surface nodes are the vertices of the remeshed surface (about one node spacing
        ``h`` apart, on the mesh's surface to a quarter of ``h``); interior nodes a jittered
        grid of spacing ``h`` at least ``h / 2`` inside; ``h`` is chosen so that there are
        about ``n_nodes`` nodes in all (within 3%). Nodal volumes: SPEC 4.1's density
        approximation, summing to the mesh's volume.

        Raises
        ------
        InvalidInputError
            A mesh that is not a watertight triangle mesh, encloses no volume or has
            non-finite vertices; ``n_nodes`` below ``k``.
        """
        count = as_count("n_nodes", n_nodes, minimum=4)
        found = sample_mesh(mesh, count, seed)
        return cls._from_node_set(
            found,
            found.volume,
            k=k,
            youngs=youngs,
            poisson=poisson,
            rotation=rotation,
            rotation_fit=rotation_fit,
            stabilization=stabilization,
        )

    @classmethod
    def from_mask(
        cls,
        mask: Any,
        *,
        n_nodes: int = 1000,
        k: int = 12,
        youngs: float = 1.0,
        poisson: float = 0.3,
        rotation: str = "rhs",
        plane: str = "strain",
        rotation_fit: str = "gradient",
        stabilization: float = STABILIZATION,
        seed: int = 0,
    ) -> ElasticModel:
        """A 2-D model of a binary mask ``(H, W)``, in pixel coordinates ``(x, y) = (column,
        row)``: boundary nodes every ``h`` along its contours (outer and holes), interior
        nodes a jittered grid, volumes (areas) summing to the mask's pixel count.
        ``surface_faces`` are the contour edges."""
        array = np.asarray(mask)
        if array.ndim != 2:
            raise InvalidInputError(f"mask must be a 2-D array (H, W), got shape {array.shape}")
        binary = array.astype(bool)
        found = sample_mask(binary, as_count("n_nodes", n_nodes, minimum=3), seed)
        return cls._from_node_set(
            found,
            float(binary.sum()),
            k=k,
            youngs=youngs,
            poisson=poisson,
            rotation=rotation,
            plane=plane,
            rotation_fit=rotation_fit,
            stabilization=stabilization,
        )

    def __reduce__(self) -> tuple[Any, ...]:
        # The core object does not pickle; the model is rebuilt from what it was built from
        # (deterministic), so it can travel to a Dask worker or a process pool.
        options = dict(
            k=self.k, youngs=self.youngs, poisson=self.poisson, rotation=self.rotation, plane=self.plane,
            rotation_fit=self.rotation_fit, stabilization=self.stabilization,
            surface_nodes=np.array(self.surface_nodes), surface_faces=np.array(self.surface_faces),
        )
        return (_rebuild_model, (np.array(self.nodes), np.array(self.volumes), options))

    # -- what the model is made of --------------------------------------------------------

    @property
    def dim(self) -> int:
        """D, 2 or 3."""
        return self._core.dim

    @property
    def n_nodes(self) -> int:
        """N."""
        return self._core.n_nodes

    @cached_property
    def nodes(self) -> NDArray[np.float64]:
        """``(N, D)`` rest positions (read-only, cached)."""
        return _read_only(self._core.nodes)

    @cached_property
    def neighbors(self) -> NDArray[np.int64]:
        """``(N, k)`` neighbour lists, fixed at rest, each row starting with its node (read-only,
        cached)."""
        return _read_only(self._core.neighbors)

    @cached_property
    def grad(self) -> NDArray[np.float64]:
        """``(N, k, D)`` MLS shape-function gradients at the nodes (order of ``neighbors``;
        read-only, cached)."""
        return _read_only(self._core.grad)

    @cached_property
    def support(self) -> NDArray[np.float64]:
        """``(N,)`` MLS support radii ``ddm_p`` (read-only, cached)."""
        return _read_only(self._core.support)

    @cached_property
    def volumes(self) -> NDArray[np.float64]:
        """``(N,)`` nodal volumes (read-only, cached)."""
        return _read_only(self._core.volumes)

    @property
    def surface(self) -> trimesh.Trimesh:
        """The rest surface (3-D): vertex ``i`` is node ``surface_nodes[i]``."""
        return self.surface_at(self.nodes)

    def surface_at(self, positions: Any) -> trimesh.Trimesh:
        """The surface mesh (rest topology) with the nodes at ``positions`` (N, 3): vertex
        ``i`` is node ``surface_nodes[i]``, the same vertices and faces for any positions."""
        if self.dim != 3 or len(self.surface_faces) == 0:
            raise InvalidInputError("this model has no surface mesh (built from nodes, or 2-D)")
        x = self._positions(positions)
        local = np.full(self.n_nodes, -1, dtype=np.int64)
        local[self.surface_nodes] = np.arange(len(self.surface_nodes))
        return trimesh.Trimesh(x[self.surface_nodes], local[self.surface_faces], process=False)

    def enclosed_measure(self, positions: Any) -> float:
        """Volume (3-D, units cubed) or area (2-D, units squared) the surface encloses with
        the nodes at ``positions`` (N, D), by the divergence theorem over the surface faces
        (triangles or contour edges; holes subtract)."""
        if len(self.surface_faces) == 0:
            raise InvalidInputError("this model has no surface (built from nodes)")
        x = self._positions(positions)
        if self.dim == 3:
            return float(abs(self.surface_at(x).volume))
        a, b = x[self.surface_faces[:, 0]], x[self.surface_faces[:, 1]]
        return float(abs(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]) / 2))

    # -- mechanics ------------------------------------------------------------------------

    def _positions(self, positions: Any, name: str = "positions") -> NDArray[np.float64]:
        x = as_points(name, positions, dims=(self.dim,))
        if x.shape[0] != self.n_nodes:
            raise InvalidInputError(
                f"{name} must have shape (N, D) = ({self.n_nodes}, {self.dim}), got {x.shape}"
            )
        return x

    def rotations(self, positions: Any) -> NDArray[np.float64]:
        """``(N, D, D)`` per-node rotations ``R_p`` at ``positions`` (SPEC 4.4); identities
        for ``rotation="none"``."""
        return self._core.rotations(self._positions(positions))

    def energy(self, positions: Any) -> float:
        """Elastic energy at ``positions`` (N, D), rotations from the positions; zero for
        any rigid motion of the rest state in the compensated modes. Units: stress times
        volume."""
        x = self._positions(positions)
        return self._core.energy(x, self._core.rotations(x))

    def forces(self, positions: Any) -> NDArray[np.float64]:
        """``(N, D)`` elastic forces ``-dE/dx`` at ``positions``, rotations held fixed."""
        x = self._positions(positions)
        return self._core.forces(x, self._core.rotations(x))

    def stiffness(self) -> scipy.sparse.csr_matrix:
        """The rest stiffness ``K`` (N D, N D), dof ``node * D + axis``; symmetric positive
        semi-definite with the rigid motions as its null space."""
        eye = np.ascontiguousarray(np.broadcast_to(np.eye(self.dim), (self.n_nodes, self.dim, self.dim)))
        return self._matrix(eye)

    def _matrix(self, rotations: NDArray[np.float64]) -> scipy.sparse.csr_matrix:
        indptr, indices, data = self._core.system(rotations)
        size = self.n_nodes * self.dim
        return scipy.sparse.csr_matrix((data, indices, indptr), shape=(size, size))

    def linear_system(self, positions: Any) -> tuple[scipy.sparse.csr_matrix, NDArray[np.float64]]:
        """``(S, f)``: the system ``S x = f`` of one iteration at ``positions`` (SPEC 4.4):
        ``S = K`` (``"rhs"``, ``"none"``) or ``sum_p R_p k_p R_p^T`` (``"warped"``), ``f`` of
        shape (N, D). Forces are ``f - S x``."""
        x = self._positions(positions)
        rotations = self._core.rotations(x)
        return self._matrix(rotations), self._core.rhs(rotations)

    def solve_static(
        self,
        fixed: Any,
        *,
        positions: Any = None,
        loads: Any = None,
        max_iterations: int = 50,
        tolerance: float = 1e-8,
    ) -> StaticSolution:
        """Static equilibrium with fixed nodes and nodal loads (SPEC 4, item 6 of issue 4).

        Parameters
        ----------
        fixed : (M,) array_like of int or (N,) bool
            Nodes held in place.
        positions : (N, D) array_like of float, optional
            Where the fixed nodes are held (other rows are the starting guess). Default:
            the rest positions.
        loads : (N, D) array_like of float, optional
            External nodal forces (force units). Default: none.
        max_iterations : int
            Cap on rotation updates; each solves the linear system for the free nodes.
        tolerance : float
            Stop when no free node moved more than ``tolerance`` times the model's size.

        Returns
        -------
        StaticSolution
            Not converging within ``max_iterations`` is reported, not raised.
        """
        n, dim = self.n_nodes, self.dim
        held = np.zeros(n, dtype=bool)
        index = np.asarray(fixed)
        if index.size == 0:
            raise InvalidInputError("fixed is empty: a free elastic body has no static equilibrium")
        if index.dtype == bool:
            if index.shape != (n,):
                raise InvalidInputError(f"fixed as a mask must have shape ({n},), got {index.shape}")
            held = index.copy()
        else:
            if index.size and (index.dtype.kind not in "iu" or index.min() < 0 or index.max() >= n):
                raise InvalidInputError(f"fixed must hold node indices in 0..{n}")
            held[index] = True
        if not held.any():
            raise InvalidInputError("fixed is empty: a free elastic body has no static equilibrium")
        x = self.nodes.copy() if positions is None else self._positions(positions).copy()
        f_ext = np.zeros((n, dim)) if loads is None else self._positions(loads, "loads")
        free = np.repeat(~held, dim)
        size = float(np.ptp(self.nodes, axis=0).max())
        step, iterations = np.inf, as_count("max_iterations", max_iterations)
        for iteration in range(1, iterations + 1):
            matrix, rhs = self.linear_system(x)
            flat = x.ravel().copy()
            b = (rhs + f_ext).ravel()[free] - matrix[free][:, ~free] @ flat[~free]
            solved = scipy.sparse.linalg.spsolve(matrix[free][:, free].tocsc(), b)
            step = float(np.abs(solved - flat[free]).max(initial=0.0))
            flat[free] = solved
            x = flat.reshape(n, dim)
            if self.rotation == "none" or step < tolerance * size:
                return StaticSolution(x, iteration, True, step)
        return StaticSolution(x, iterations, False, step)
