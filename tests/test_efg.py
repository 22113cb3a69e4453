"""Stiffness by nodal integration (SPEC 4.3): symmetry, positive semi-definiteness and the
zero-mode count of K, the constant-strain patch test, rigid modes, the energy of a uniform
stretch against 1/2 eps^T C eps V, matrix-free forces against -K u, and bad input."""

from __future__ import annotations

import numpy as np
import pytest

import elastocap
from elastocap import InvalidInputError, _core
from tolerances import (
    EFG_ENERGY_RTOL,
    EFG_PATCH_ATOL,
    EFG_PSD_RTOL,
    EFG_RIGID_RTOL,
    EFG_SYMMETRY_RTOL,
    EFG_ZERO_EIGENVALUE_RTOL,
)

K_NEIGHBOURS = 20
YOUNGS, POISSON = 2.5, 0.3
# (dimension, grid side): 8x8 in 2-D, 5x5x5 in 3-D.
MODELS = [(2, 8), (3, 5)]
# Voigt rows as (displacement axis, derivative axis) pairs, SPEC 4.3 order.
VOIGT = {
    2: [[(0, 0)], [(1, 1)], [(0, 1), (1, 0)]],
    3: [[(0, 0)], [(1, 1)], [(2, 2)], [(0, 1), (1, 0)], [(1, 2), (2, 1)], [(0, 2), (2, 0)]],
}


def jittered_grid(side: int, dim: int, seed: int = 0) -> np.ndarray:
    """A grid of unit spacing jittered by up to 0.3 per axis: each node owns volume 1."""
    rng = np.random.default_rng(seed)
    axes = np.meshgrid(*[np.arange(side, dtype=float)] * dim, indexing="ij")
    grid = np.stack([a.ravel() for a in axes], axis=1)
    return grid + rng.uniform(-0.3, 0.3, grid.shape)


def elasticity(dim: int, plane: str = "strain") -> np.ndarray:
    """C written out independently from SPEC 4.3 (engineering shear)."""
    e, nu = YOUNGS, POISSON
    if dim == 2 and plane == "stress":
        return e / (1 - nu**2) * np.array([[1, nu, 0], [nu, 1, 0], [0, 0, (1 - nu) / 2]])
    s = 3 if dim == 2 else 6
    c = np.zeros((s, s))
    c[:dim, :dim] = nu
    c[range(dim), range(dim)] = 1 - nu
    c[range(dim, s), range(dim, s)] = 0.5 - nu
    return e / ((1 + nu) * (1 - 2 * nu)) * c


def voigt(a: np.ndarray) -> np.ndarray:
    """Voigt strain (engineering shear) of the displacement gradient a."""
    return np.array([sum(a[i, j] for i, j in row) for row in VOIGT[a.shape[0]]])


class Model:
    def __init__(self, dim: int, side: int, plane: str = "strain") -> None:
        self.dim, self.plane = dim, plane
        self.points = jittered_grid(side, dim)
        self.n = len(self.points)
        self.mls = elastocap.mls_shape_functions(self.points, k=K_NEIGHBOURS)
        self.volumes = np.ones(self.n)
        indptr, indices, data = _core.efg_stiffness(
            self.points, self.mls.neighbors, self.mls.grad, self.volumes, YOUNGS, POISSON, plane
        )
        size = self.n * dim
        self.stiffness = np.zeros((size, size))
        for row in range(size):
            self.stiffness[row, indices[indptr[row] : indptr[row + 1]]] = data[indptr[row] : indptr[row + 1]]

    def energy(self, u: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        return _core.efg_energy(
            self.points, self.mls.neighbors, self.mls.grad, self.volumes, np.ascontiguousarray(u),
            YOUNGS, POISSON, self.plane,
        )


@pytest.fixture(scope="module", params=MODELS, ids=["2d", "3d"])
def model(request: pytest.FixtureRequest) -> Model:
    return Model(*request.param)


def test_stiffness_is_symmetric_positive_semidefinite(model: Model) -> None:
    k = model.stiffness
    scale = np.abs(k).max()
    assert np.abs(k - k.T).max() <= EFG_SYMMETRY_RTOL * scale
    eigenvalues = np.linalg.eigvalsh(k)
    assert eigenvalues[0] >= -EFG_PSD_RTOL * eigenvalues[-1]


def test_zero_modes_are_exactly_the_rigid_motions(model: Model) -> None:
    """SPEC 4.3: 3 zero eigenvalues in 2-D, 6 in 3-D (measured: exactly these counts on the
    8x8 and 5x5x5 jittered grids with k = 20, the next eigenvalue ~4e-5 / ~7e-3 of the
    largest)."""
    eigenvalues = np.linalg.eigvalsh(model.stiffness)
    zeros = int((eigenvalues < EFG_ZERO_EIGENVALUE_RTOL * eigenvalues[-1]).sum())
    assert zeros == (3 if model.dim == 2 else 6)


def test_constant_strain_patch(model: Model) -> None:
    rng = np.random.default_rng(1)
    a = rng.normal(size=(model.dim, model.dim))
    u = model.points @ a.T + rng.normal(size=model.dim)
    _, _, strains = model.energy(u)
    np.testing.assert_allclose(strains, np.broadcast_to(voigt(a), strains.shape), rtol=0, atol=EFG_PATCH_ATOL)


def rigid_modes(points: np.ndarray) -> list[np.ndarray]:
    dim = points.shape[1]
    modes = [np.broadcast_to(np.eye(dim)[a], points.shape).copy() for a in range(dim)]
    for i, j in [(0, 1)] if dim == 2 else [(0, 1), (1, 2), (2, 0)]:
        w = np.zeros((dim, dim))
        w[i, j], w[j, i] = -1.0, 1.0
        modes.append(points @ w.T)
    return modes


def test_rigid_modes_have_no_force(model: Model) -> None:
    k = model.stiffness
    norm = np.linalg.norm(k, 2)
    for u in rigid_modes(model.points):
        assert np.linalg.norm(k @ u.ravel()) <= EFG_RIGID_RTOL * norm * np.linalg.norm(u)
        energy, forces, _ = model.energy(u)
        assert np.linalg.norm(forces) <= EFG_RIGID_RTOL * norm * np.linalg.norm(u)
        assert abs(energy) <= EFG_RIGID_RTOL * norm * np.linalg.norm(u) ** 2


@pytest.mark.parametrize("plane", ["strain", "stress"])
def test_uniform_stretch_energy(plane: str) -> None:
    dim = 2 if plane == "stress" else 3
    model = Model(dim, 8 if dim == 2 else 5, plane)
    a = np.zeros((dim, dim))
    a[0, 0], a[1, 1], a[0, 1] = 0.01, -0.003, 0.002
    u = model.points @ a.T
    energy, forces, _ = model.energy(u)
    eps = voigt(a)
    expected = 0.5 * eps @ elasticity(dim, plane) @ eps * model.volumes.sum()
    assert energy == pytest.approx(expected, rel=EFG_ENERGY_RTOL)
    ku = model.stiffness @ u.ravel()
    assert 0.5 * u.ravel() @ ku == pytest.approx(expected, rel=EFG_ENERGY_RTOL)
    np.testing.assert_allclose(forces.ravel(), -ku, rtol=0, atol=EFG_ENERGY_RTOL * np.abs(ku).max())


def test_forces_match_stiffness_on_a_general_field(model: Model) -> None:
    u = np.random.default_rng(2).normal(size=model.points.shape)
    energy, forces, _ = model.energy(u)
    ku = model.stiffness @ u.ravel()
    np.testing.assert_allclose(forces.ravel(), -ku, rtol=0, atol=EFG_ENERGY_RTOL * np.abs(ku).max())
    assert energy == pytest.approx(0.5 * u.ravel() @ ku, rel=EFG_ENERGY_RTOL)


def test_stiffness_matrix_api() -> None:
    points = jittered_grid(5, 3)
    given = elastocap.stiffness_matrix(points, youngs=YOUNGS, poisson=POISSON, volumes=np.ones(len(points)))
    assert given.shape == (375, 375)
    np.testing.assert_allclose(given.toarray(), Model(3, 5).stiffness, rtol=0, atol=1e-14 * abs(given).max())
    # Default volumes (SPEC 4.1 approximation) sum to the hull volume: a uniform stretch
    # then has the energy 1/2 eps^T C eps times that volume.
    from scipy.spatial import ConvexHull

    k = elastocap.stiffness_matrix(points, youngs=YOUNGS, poisson=POISSON)
    u = (points * [0.01, 0.0, 0.0]).ravel()
    eps = voigt(np.diag([0.01, 0.0, 0.0]))
    expected = 0.5 * eps @ elasticity(3) @ eps * ConvexHull(points).volume
    assert 0.5 * u @ (k @ u) == pytest.approx(expected, rel=EFG_ENERGY_RTOL)


def core_args(model: Model, **changes: object) -> list[object]:
    args: dict[str, object] = {
        "points": model.points,
        "neighbors": model.mls.neighbors,
        "grad": model.mls.grad,
        "volumes": model.volumes,
        "youngs": YOUNGS,
        "poisson": POISSON,
    }
    args.update(changes)
    return list(args.values())


@pytest.mark.parametrize(
    ("change", "argument"),
    [
        ({"poisson": 0.5}, "poisson"),
        ({"poisson": -0.1}, "poisson"),
        ({"poisson": float("nan")}, "poisson"),
        ({"youngs": 0.0}, "youngs"),
        ({"youngs": -1.0}, "youngs"),
        ({"volumes": np.zeros(64)}, "volumes"),
        ({"volumes": np.ones(63)}, "volumes"),
        ({"grad": np.zeros((64, 19, 2))}, "grad"),
        ({"neighbors": np.zeros((63, 20), dtype=np.int64)}, "neighbors"),
    ],
)
def test_bad_input_names_the_argument(change: dict[str, object], argument: str) -> None:
    model = Model(2, 8)
    with pytest.raises(InvalidInputError, match=argument):
        _core.efg_stiffness(*core_args(model, **change))


def test_bad_values_name_the_argument() -> None:
    model = Model(2, 8)
    neighbors = model.mls.neighbors.copy()
    neighbors[3, 5] = 64
    with pytest.raises(InvalidInputError, match=r"neighbors\[3, 5\]"):
        _core.efg_stiffness(*core_args(model, neighbors=neighbors))
    grad = model.mls.grad.copy()
    grad[7, 2, 1] = np.nan
    with pytest.raises(InvalidInputError, match="grad"):
        _core.efg_stiffness(*core_args(model, grad=grad))
    with pytest.raises(InvalidInputError, match="plane"):
        _core.efg_stiffness(*core_args(model), "membrane")
    with pytest.raises(InvalidInputError, match="displacements"):
        _core.efg_energy(*core_args(model)[:4], np.zeros((64, 3)), YOUNGS, POISSON)
    points = model.points.copy()
    points[0, 0] = np.nan
    with pytest.raises(InvalidInputError, match="points"):
        elastocap.stiffness_matrix(points)
    with pytest.raises(InvalidInputError, match="poisson"):
        elastocap.stiffness_matrix(model.points, poisson=0.5)
    with pytest.raises(InvalidInputError, match="youngs"):
        elastocap.stiffness_matrix(model.points, youngs="stiff")
    with pytest.raises(InvalidInputError, match="total_volume"):
        elastocap.stiffness_matrix(model.points, total_volume=-1.0)
