"""Type stubs of the Rust extension (checked by ``python -m mypy.stubtest elastocap._core``)."""

from collections.abc import Sequence
import numpy as np
from numpy.typing import NDArray
from typing import Any

from typing_extensions import final

__all__ = [
    "BodySkeleton",
    "carve",
    "conjugate_gradient",
    "ConvergenceError",
    "efg_energy",
    "ElasticCore",
    "FitCore",
    "efg_stiffness",
    "ElastocapError",
    "InvalidInputError",
    "SpatialIndex",
    "__version__",
    "mls_shape_functions",
    "polar_rotation",
    "raster_fragments",
    "sample_grid",
    "signed_distance",
    "SparseCholesky",
    "camera_project",
    "intersect_per_view",
    "rigid_fits",
    "active_contour",
    "lsm_match_patches",
    "lsm_match_pairs",
    "TriangleMesh",
    "track_step",
    "track_box_search",
    "track_ncc_at",
    "seed_hull_inside",
    "seed_hull_depths",
    "seed_pixels",
    "seed_line_pixels",
    "seed_line_peaks",
    "track_ncc_at_cameras",
    "track_occluded",
    "track_rigid_held_out",
]

__version__: str

class ElastocapError(Exception):
    """Root of every error elastocap raises."""

class ConvergenceError(ElastocapError):
    """A numerical method did not converge or met a singular system."""

class InvalidInputError(ElastocapError, ValueError):
    """Bad input: wrong shape, dtype or value. Also a ValueError."""

@final
class SpatialIndex:
    def __new__(cls, points: NDArray[np.float64]) -> SpatialIndex: ...
    @property
    def n_points(self) -> int: ...
    @property
    def dim(self) -> int: ...
    def cell_size(self, k: int) -> float: ...
    def knn(
        self, k: int, queries: NDArray[np.float64] | None = None
    ) -> tuple[NDArray[np.int64], NDArray[np.float64]]: ...
    def radius_neighbors(
        self, radius: float, queries: NDArray[np.float64] | None = None
    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]: ...

def polar_rotation(
    matrices: NDArray[np.float64], return_stretch: bool = False
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]: ...

def signed_distance(
    occupancy: NDArray[np.bool_], spacing: tuple[float, float, float]
) -> NDArray[np.float64]: ...
def sample_grid(
    values: NDArray[np.float64],
    origin: tuple[float, float, float],
    spacing: float,
    points: NDArray[np.float64],
    gradient: bool = False,
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]: ...

def carve(
    masks: list[NDArray[np.uint8]],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
    r: NDArray[np.float64],
    t: NDArray[np.float64],
    origin: tuple[float, float, float],
    spacing: float,
    shape: tuple[int, int, int],
    tolerance: int = 0,
    footprint: str = "conservative",
) -> NDArray[np.bool_]: ...

def raster_fragments(
    uv: NDArray[np.float64], faces: NDArray[np.int64], width: int, height: int
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]: ...

def mls_shape_functions(
    points: NDArray[np.float64],
    neighbors: NDArray[np.int64],
    support: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], int]: ...

def efg_stiffness(
    points: NDArray[np.float64],
    neighbors: NDArray[np.int64],
    grad: NDArray[np.float64],
    volumes: NDArray[np.float64],
    youngs: float,
    poisson: float,
    plane: str = "strain",
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]: ...

def efg_energy(
    points: NDArray[np.float64],
    neighbors: NDArray[np.int64],
    grad: NDArray[np.float64],
    volumes: NDArray[np.float64],
    displacements: NDArray[np.float64],
    youngs: float,
    poisson: float,
    plane: str = "strain",
) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]: ...

@final
class ElasticCore:
    def __new__(
        cls,
        nodes: NDArray[np.float64],
        k: int,
        volumes: NDArray[np.float64],
        youngs: float,
        poisson: float,
        plane: str = "strain",
        rotation: str = "rhs",
        rotation_fit: str = "gradient",
        stabilization: float = 0.0,
    ) -> ElasticCore: ...
    @property
    def stabilization(self) -> float: ...
    @property
    def dim(self) -> int: ...
    @property
    def n_nodes(self) -> int: ...
    @property
    def nodes(self) -> NDArray[np.float64]: ...
    @property
    def neighbors(self) -> NDArray[np.int64]: ...
    @property
    def grad(self) -> NDArray[np.float64]: ...
    @property
    def support(self) -> NDArray[np.float64]: ...
    @property
    def volumes(self) -> NDArray[np.float64]: ...
    def rotations(self, positions: NDArray[np.float64]) -> NDArray[np.float64]: ...
    def energy(self, positions: NDArray[np.float64], rotations: NDArray[np.float64]) -> float: ...
    def forces(self, positions: NDArray[np.float64], rotations: NDArray[np.float64]) -> NDArray[np.float64]: ...
    def rhs(self, rotations: NDArray[np.float64]) -> NDArray[np.float64]: ...
    def apply(self, rotations: NDArray[np.float64], u: NDArray[np.float64]) -> NDArray[np.float64]: ...
    def system(
        self, rotations: NDArray[np.float64]
    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]: ...
@final
class SparseCholesky:
    def __new__(
        cls,
        size: int,
        indptr: NDArray[np.int32] | NDArray[np.int64],
        indices: NDArray[np.int32] | NDArray[np.int64],
        data: NDArray[np.float64],
        block: int,
    ) -> SparseCholesky: ...
    def factorize(
        self,
        indptr: NDArray[np.int32] | NDArray[np.int64],
        indices: NDArray[np.int32] | NDArray[np.int64],
        data: NDArray[np.float64],
    ) -> None: ...
    def solve(self, rhs: NDArray[np.float64]) -> NDArray[np.float64]: ...
    @property
    def size(self) -> int: ...
    @property
    def block(self) -> int: ...
    @property
    def factor_entries(self) -> int: ...

def conjugate_gradient(
    size: int,
    indptr: NDArray[np.int32] | NDArray[np.int64],
    indices: NDArray[np.int32] | NDArray[np.int64],
    data: NDArray[np.float64],
    rhs: NDArray[np.float64],
    x0: NDArray[np.float64],
    block: int,
    tolerance: float,
    max_iterations: int,
    preconditioner: SparseCholesky | None = None,
    nodes: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], bool, int, float]: ...

@final
class FitCore:
    def __new__(
        cls, model: ElasticCore, surface_nodes: NDArray[np.int64], faces: NDArray[np.int64]
    ) -> FitCore: ...
    def fit_frame(
        self,
        values: NDArray[np.float64],
        origin: tuple[float, float, float] | list[float] | NDArray[np.float64],
        spacing: float,
        start: NDArray[np.float64],
        *,
        stiffness: float = 1.0,
        contact: float = 1.0,
        max_iterations: int = 10,
        stop_fraction: float = 0.01,
        invalidate: bool = True,
        self_intersection: bool = True,
        solver_tolerance: float = 1e-6,
        solver_max_iterations: int = 500,
        matrix_free: bool = False,
        coarse: bool = True,
        hold_contacts: bool = False,
        coverage: float = 2.0,
        volume: float = 4.0,
        silhouette: float = 0.0,
        views: list[
            tuple[
                list[float],
                list[float],
                list[float],
                list[float],
                NDArray[np.float64],
                tuple[tuple[int, int], tuple[int, int], tuple[int, int, int, int]] | None,
            ]
        ]
        | None = None,
        tracks: tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None = None,
        track_weight: float = 1.0,
        track_sigma: float = 1.0,
        track_scale: float = 10.0,
    # The metrics mix numbers, flags and per-term dicts ("terms"): read by key.
    ) -> tuple[NDArray[np.float64], dict[str, Any]]: ...

@final
class BodySkeleton:
    def __new__(
        cls,
        parent: NDArray[np.int64],
        offset: NDArray[np.float64],
        rest: NDArray[np.float64],
        axes: NDArray[np.float64],
        axis_count: NDArray[np.int64],
        ball_part: NDArray[np.int64],
        ball_centre: NDArray[np.float64],
        ball_radii: NDArray[np.float64],
    ) -> BodySkeleton: ...
    @property
    def n_motion(self) -> int: ...
    @property
    def n_shape(self) -> int: ...
    @property
    def taper_weight(self) -> NDArray[np.float64]: ...
    def pose(
        self, shape: NDArray[np.float64], motion: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
    def field(
        self, shape: NDArray[np.float64], motion: NDArray[np.float64], points: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]: ...
    def values(
        self, shape: NDArray[np.float64], motion: NDArray[np.float64], points: NDArray[np.float64]
    ) -> NDArray[np.float64]: ...
    def jacobian(
        self,
        shape: NDArray[np.float64],
        motion: NDArray[np.float64],
        points: NDArray[np.float64],
        exact: bool = True,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
    def rays(
        self,
        shape: NDArray[np.float64],
        motion: NDArray[np.float64],
        origins: NDArray[np.float64],
        directions: NDArray[np.float64],
    ) -> tuple[
        NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64]
    ]: ...
    def rays_inside(
        self,
        shape: NDArray[np.float64],
        motion: NDArray[np.float64],
        origins: NDArray[np.float64],
        directions: NDArray[np.float64],
        threshold: float,
    ) -> NDArray[np.bool_]: ...
    def fit(
        self,
        observations: dict[str, Any],
        shape: NDArray[np.float64],
        motion: NDArray[np.float64],
        lower: NDArray[np.float64],
        upper: NDArray[np.float64],
        *,
        fit_shape: bool,
        max_iterations: int,
        refresh_every: int,
        outlier_distance: float | None,
    ) -> dict[str, Any]: ...

def camera_project(
    points: NDArray[np.float64],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
    r: NDArray[np.float64],
    t: NDArray[np.float64],
    width: int,
    height: int,
) -> NDArray[np.float64]: ...
def intersect_per_view(
    obs: NDArray[np.float64],
    cov: NDArray[np.float64],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
    r: NDArray[np.float64],
    t: NDArray[np.float64],
    reject: bool,
    critical: float,
    iterations: int,
    step_tolerance: float,
) -> tuple[
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.bool_],
    NDArray[np.float64],
    NDArray[np.bool_],
]: ...
def rigid_fits(
    a: NDArray[np.float64], b: NDArray[np.float64], weights: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
def active_contour(
    image: NDArray[np.float64],
    init: NDArray[np.float64],
    *,
    alpha: float,
    beta: float,
    gamma: float,
    kappa: float,
    max_move: float,
    spacing: float,
    min_spacing: float,
    max_spacing: float,
    max_iterations: int,
    tolerance: float,
    window: int,
    min_area: float,
) -> tuple[NDArray[np.float64], str, int, int]: ...
def lsm_match_patches(
    template: NDArray[np.float32],
    points: NDArray[np.float64],
    search_images: list[NDArray[np.float32]],
    initial: NDArray[np.float64],
    epipolar: NDArray[np.float64] | None = None,
    *,
    size: int = 11,
    max_iterations: int = 30,
    tolerance: float = 0.01,
    max_shift: float = 5.0,
    max_scale: float = 3.0,
    min_texture: float = 0.0,
    line_sigma: float = 0.0,
    shift_only_iterations: int = 1,
    interpolation: str = "bicubic",
    threads: int | None = None,
    weights: NDArray[np.float32] | None = None,
    extra_iterations: int = 0,
    extra_warp: str = "affine",
    extra_gain_gradient: bool = False,
    extra_warp_sigma: float = 0.0,
    extra_gain_sigma: float = 0.0,
    extra_fallback: bool = False,
    extra_jacobian: str = "search",
    extra_skip_correlation: float = ...,
) -> tuple[
    NDArray[np.uint8],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.uint32],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.uint8],
]: ...
def lsm_match_pairs(
    images: list[NDArray[np.float32] | None],
    cameras: NDArray[np.int64],
    points: NDArray[np.float64],
    initial: NDArray[np.float64],
    *,
    size: int = 11,
    max_iterations: int = 30,
    tolerance: float = 0.01,
    max_shift: float = 5.0,
    max_scale: float = 3.0,
    min_texture: float = 0.0,
    shift_only_iterations: int = 1,
    interpolation: str = "bicubic",
    weights: list[NDArray[np.float32] | None] | None = None,
) -> tuple[
    NDArray[np.uint8],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.uint32],
    NDArray[np.float64],
]: ...

@final
class TriangleMesh:
    def __new__(cls, vertices: NDArray[np.float64], triangles: NDArray[np.int64]) -> TriangleMesh: ...
    @property
    def n_vertices(self) -> int: ...
    @property
    def n_triangles(self) -> int: ...
    def volume(self) -> float: ...
    def area(self) -> float: ...
    def is_closed(self) -> bool: ...
    def diagonal(self) -> float: ...
    def closest_points(
        self, queries: NDArray[np.float64], signed: bool
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]: ...
    def distances(self, queries: NDArray[np.float64], signed: bool, max_distance: float) -> NDArray[np.float64]: ...
    def contains(self, queries: NDArray[np.float64]) -> NDArray[np.bool_]: ...
    def cast_rays(
        self, origins: NDArray[np.float64], directions: NDArray[np.float64], max_distance: float
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]: ...

def track_step(
    previous: list[NDArray[np.float32]],
    current: list[NDArray[np.float32]],
    last: NDArray[np.float64],
    before: NDArray[np.float64],
    *,
    size: int = 11,
    radius: int = 4,
    min_correlation: float = 0.8,
    forward_backward: float = 0.3,
    max_iterations: int = 15,
    min_texture: float = 0.0,
    shift_only_iterations: int = 1,
    weights: tuple[list[NDArray[np.float32]], list[NDArray[np.float32]]] | None = None,
    weighted_box: bool = False,
) -> tuple[NDArray[np.float64], NDArray[np.uint8], NDArray[np.float64], NDArray[np.float64]]: ...
def track_box_search(
    template: NDArray[np.float32],
    point: Sequence[float],
    search: NDArray[np.float32],
    prediction: Sequence[float],
    *,
    size: int = 15,
    radius: int = 6,
    weights: NDArray[np.float32] | None = None,
) -> tuple[tuple[float, float], float, NDArray[np.float64]] | None: ...
def track_ncc_at(
    template: NDArray[np.float32],
    points: NDArray[np.float64],
    search: NDArray[np.float32],
    candidates: NDArray[np.float64],
    *,
    size: int = 11,
    decide: tuple[float, float] | None = None,
) -> NDArray[np.float64]: ...
def seed_hull_inside(
    points: NDArray[np.float64],
    r: NDArray[np.float64],
    t: NDArray[np.float64],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
    masks: list[NDArray[np.bool_]],
    *,
    min_seen: int,
) -> NDArray[np.bool_]: ...
def seed_hull_depths(
    origins: NDArray[np.float64],
    dirs: NDArray[np.float64],
    coarse: NDArray[np.float64],
    fractions: NDArray[np.float64],
    step: float,
    r: NDArray[np.float64],
    t: NDArray[np.float64],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
    masks: list[NDArray[np.bool_]],
    *,
    min_seen: int,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]: ...
def seed_pixels(
    points: NDArray[np.float64],
    r: NDArray[np.float64],
    t: NDArray[np.float64],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
    *,
    width: int,
    height: int,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]: ...
def seed_line_pixels(
    points: NDArray[np.float64],
    inside: NDArray[np.bool_],
    rows: NDArray[np.int64],
    r: NDArray[np.float64],
    t: NDArray[np.float64],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
    *,
    width: int,
    height: int,
) -> NDArray[np.float64]: ...
def seed_line_peaks(
    scores: NDArray[np.float64],
    *,
    width: int,
    uv: NDArray[np.float64] | None = None,
    pixels: float | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]: ...
def track_ncc_at_cameras(
    templates: list[NDArray[np.float32]],
    points: NDArray[np.float64],
    searches: list[NDArray[np.float32]],
    candidates: NDArray[np.float64],
    cameras: NDArray[np.int64],
    *,
    size: int = 11,
) -> NDArray[np.float64]: ...
def track_occluded(
    occluders: NDArray[np.float64],
    depths: NDArray[np.float64],
    points: NDArray[np.float64],
    thresholds: NDArray[np.float64],
    *,
    radius: float,
    nearest: int,
) -> NDArray[np.bool_]: ...
def track_rigid_held_out(
    a: NDArray[np.float64], b: NDArray[np.float64], weights: NDArray[np.float64], *, min_others: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
