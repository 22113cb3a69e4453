"""mls_shape_functions: the SPEC 4.2 identities, exact reproduction of affine fields, and
agreement with an independent numpy evaluation of the same MLS formula (values, and
gradients by central differences)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import elastocap
from elastocap import InvalidInputError, _core
from tolerances import MLS_FD_GRADIENT_ATOL, MLS_IDENTITY_ATOL, MLS_REFERENCE_ATOL

# ------------------------------------------------------------------------------------------
# Clouds and the numpy reference
# ------------------------------------------------------------------------------------------


def cloud(kind: str, dim: int, seed: int) -> np.ndarray:
    """~300-400 points: uniform random, a jittered grid, or random with one axis 10x."""
    rng = np.random.default_rng(seed)
    if kind == "random":
        return rng.random((350, dim))
    if kind == "jittered":
        side = 18 if dim == 2 else 7
        axes = np.meshgrid(*[np.arange(side, dtype=float)] * dim, indexing="ij")
        grid = np.stack([a.ravel() for a in axes], axis=1)
        return (grid + rng.uniform(-0.3, 0.3, grid.shape)) / side
    if kind == "anisotropic":
        points = rng.random((350, dim))
        points[:, rng.integers(dim)] *= 10.0
        return points
    raise AssertionError(kind)


def spline(r: np.ndarray) -> np.ndarray:
    """SPEC 4.2's cubic spline."""
    return np.where(r <= 0.5, 2 / 3 - 4 * r**2 + 4 * r**3, np.where(r <= 1, 4 / 3 * (1 - r) ** 3, 0.0))


def reference_phi(x: np.ndarray, centre: np.ndarray, neighbours: np.ndarray, ddm: float) -> np.ndarray:
    """Phi_i(x) of SPEC 4.2 written out: basis centred at ``centre`` scaled by ``ddm``."""
    w = spline(np.abs(x - neighbours) / ddm).prod(axis=1)
    basis = np.hstack([np.ones((len(neighbours), 1)), (neighbours - centre) / ddm])
    moments = (basis.T * w) @ basis
    at_x = np.concatenate([[1.0], (x - centre) / ddm])
    return np.linalg.solve(moments, at_x) @ (basis.T * w)


def identity_errors(points: np.ndarray, mls: elastocap.elastic.mls.MLSShapeFunctions) -> dict[str, float]:
    dim = points.shape[1]
    x = points[mls.neighbors]  # (N, k, D)
    scaled_grad = mls.grad * mls.support[:, None, None]
    return {
        "sum phi = 1": float(np.abs(mls.phi.sum(axis=1) - 1).max()),
        "sum phi x = x_p": float(np.abs(np.einsum("nk,nkd->nd", mls.phi, x) - points).max()),
        "sum grad = 0": float(np.abs(scaled_grad.sum(axis=1)).max()),
        "sum grad x^T = I": float(np.abs(np.einsum("nkd,nke->nde", mls.grad, x) - np.eye(dim)).max()),
    }


# ------------------------------------------------------------------------------------------
# Identities and reproduction
# ------------------------------------------------------------------------------------------


@settings(max_examples=40)
@given(
    kind=st.sampled_from(["random", "jittered", "anisotropic"]),
    dim=st.sampled_from([2, 3]),
    seed=st.integers(0, 2**32 - 1),
    extra=st.integers(0, 20),
)
def test_identities(kind: str, dim: int, seed: int, extra: int) -> None:
    points = cloud(kind, dim, seed)
    k = 2 * dim + 2 + extra  # below ~2D + 2, random clouds hold ill-conditioned nodes
    mls = elastocap.mls_shape_functions(points, k=k)
    assert mls.phi.shape == (len(points), k) and mls.grad.shape == (len(points), k, dim)
    assert np.array_equal(mls.neighbors[:, 0], np.arange(len(points)))
    assert mls.repaired == 0
    for name, error in identity_errors(points, mls).items():
        assert error < MLS_IDENTITY_ATOL, f"{name}: {error:.1e}"


@pytest.mark.parametrize("dim", [2, 3])
def test_affine_fields_are_reproduced(dim: int) -> None:
    """u(x) = a + M x: sum_i Phi_i u_i = u(x_p), and sum_i grad Phi_i u_i^T = M^T (entry
    [d, e] is du_e/dx_d), so the Jacobian du/dx = M is its transpose."""
    rng = np.random.default_rng(dim)
    points = cloud("jittered", dim, 7)
    a, m = rng.normal(size=dim), rng.normal(size=(dim, dim))
    u = a + points @ m.T
    mls = elastocap.mls_shape_functions(points)
    values = np.einsum("nk,nke->ne", mls.phi, u[mls.neighbors])
    jacobians_t = np.einsum("nkd,nke->nde", mls.grad, u[mls.neighbors])
    scale = np.abs(u).max()
    assert np.abs(values - u).max() < MLS_IDENTITY_ATOL * scale
    assert np.abs(jacobians_t - m.T).max() < MLS_IDENTITY_ATOL * np.abs(m).max() * 10


@pytest.mark.parametrize("kind", ["random", "jittered", "anisotropic"])
@pytest.mark.parametrize("dim", [2, 3])
def test_matches_numpy_reference(kind: str, dim: int) -> None:
    points = cloud(kind, dim, 3)
    mls = elastocap.mls_shape_functions(points, k=16)
    for p in [0, 1, len(points) // 2, len(points) - 1]:
        centre, neighbours, ddm = points[p], points[mls.neighbors[p]], mls.support[p]
        phi = reference_phi(centre, centre, neighbours, ddm)
        np.testing.assert_allclose(mls.phi[p], phi, rtol=0, atol=MLS_REFERENCE_ATOL)
        h = 1e-5 * ddm
        for axis in range(dim):
            step = np.zeros(dim)
            step[axis] = h
            fd = (reference_phi(centre + step, centre, neighbours, ddm) - reference_phi(centre - step, centre, neighbours, ddm)) / (2 * h)
            np.testing.assert_allclose(mls.grad[p, :, axis] * ddm, fd * ddm, rtol=0, atol=MLS_FD_GRADIENT_ATOL)


def test_given_neighbors_and_support_factor() -> None:
    points = cloud("random", 3, 11)
    distances, indices = elastocap.knn(points, 11)
    lists = np.hstack([np.arange(len(points))[:, None], indices])
    mls = elastocap.mls_shape_functions(points, neighbors=lists, c=1.3)
    np.testing.assert_allclose(mls.support, 1.3 * distances[:, -1], rtol=1e-12)
    default = elastocap.mls_shape_functions(points, k=12, c=1.3)
    np.testing.assert_allclose(mls.phi, default.phi, rtol=0, atol=1e-14)
    for name, error in identity_errors(points, mls).items():
        assert error < MLS_IDENTITY_ATOL, f"{name}: {error:.1e}"


# ------------------------------------------------------------------------------------------
# Degenerate neighbourhoods
# ------------------------------------------------------------------------------------------


def test_coplanar_cloud_is_an_error_naming_a_node() -> None:
    rng = np.random.default_rng(0)
    points = np.hstack([rng.random((200, 2)), np.full((200, 1), 0.5)])
    with pytest.raises(InvalidInputError, match=r"neighbours of node \d+ do not span"):
        elastocap.mls_shape_functions(points)


def test_support_is_enlarged_to_reach_off_plane_neighbours() -> None:
    """A 3x3 patch in z = 0 plus poles at z = +-2, all listed by every node; with c = 1.1
    times the in-plane reach given directly, the poles start outside the centre's support."""
    patch = np.array([[x, y, 0.0] for x in (-1, 0, 1) for y in (-1, 0, 1)])
    points = np.vstack([patch[[4]], np.delete(patch, 4, axis=0), [[0, 0, 2.0], [0, 0, -2.0]]])
    n = len(points)
    lists = np.tile(np.arange(n), (n, 1))
    support = np.full(n, 1.1 * np.sqrt(2))
    phi, grad, used, repaired = _core.mls_shape_functions(points, lists, support)
    assert repaired >= 1
    assert used[0] == pytest.approx(support[0] * 1.25**2)
    assert phi[0, 9] > 0 and phi[0, 10] > 0
    assert abs(phi.sum(axis=1) - 1).max() < MLS_IDENTITY_ATOL


# ------------------------------------------------------------------------------------------
# Bad input
# ------------------------------------------------------------------------------------------

POINTS = np.random.default_rng(5).random((50, 2))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"points": np.zeros((10, 4))}, "points must have shape"),
        ({"points": np.zeros(10)}, "points must have shape"),
        ({"points": np.zeros((0, 3))}, "points is empty"),
        ({"k": 2}, "k must be at least 3"),
        ({"k": 51}, "k = 51 exceeds"),
        ({"k": 2.5}, "k must be an integer"),
        ({"c": 0.0}, "c must be a positive"),
        ({"neighbors": np.zeros((50, 5))}, "neighbors must hold integers"),
        ({"neighbors": np.zeros((49, 5), int)}, r"neighbors must have shape \(N, k\) with N = 50"),
        ({"neighbors": np.tile(np.arange(2), (50, 1))}, "neighbors must have at least D . 1 = 3 columns"),
        ({"neighbors": np.tile(np.arange(5), (50, 1)) * 20}, r"neighbors\[0, 3\] = 60 is not a point index"),
        ({"neighbors": np.tile(np.arange(-1, 4), (50, 1))}, r"neighbors\[0, 0\] = -1 is not a point index"),
        ({"neighbors": np.tile(np.arange(5), (50, 1))}, "neighbors row 5 does not contain the node itself"),
    ],
)
def test_bad_input_names_the_argument(kwargs: dict, match: str) -> None:
    points = kwargs.pop("points", POINTS)
    with pytest.raises(InvalidInputError, match=match):
        elastocap.mls_shape_functions(points, **kwargs)


def test_non_finite_points_are_named() -> None:
    points = POINTS.copy()
    points[7, 1] = np.nan
    with pytest.raises(InvalidInputError, match="points holds a non-finite value .* row 7"):
        elastocap.mls_shape_functions(points)
    lists = np.tile(np.arange(5), (50, 1))
    lists[:, 0] = np.arange(50)
    with pytest.raises(InvalidInputError, match="points holds a non-finite value .* row 7"):
        elastocap.mls_shape_functions(points, neighbors=lists)


def test_core_binding_validates_its_arguments() -> None:
    lists = np.hstack([np.arange(50)[:, None], elastocap.knn(POINTS, 5).indices])
    support = np.ones(50)
    cases = [
        (POINTS, lists, support[:-1], "support has 49 rows but points has 50"),
        (POINTS, lists, -support, r"support\[0\] = -1 must be a positive finite number"),
        (POINTS, lists, support * np.inf, r"support\[0\] = inf must be"),
        (POINTS, lists[:-1], support, r"neighbors must have shape \(N, k\) with N = 50"),
        (POINTS, np.ascontiguousarray(lists[:, :2]), support, "2 neighbours per node .* at least 3 are needed"),
        (POINTS, lists + 50, support, r"neighbors\[0, 0\] = 50 is not a point index"),
        (POINTS, np.asfortranarray(lists), support, "neighbors must be C-contiguous"),
        (np.asfortranarray(POINTS), lists, support, "points must be C-contiguous"),
        (np.zeros((50, 4)), lists, support, r"points must have shape \(N, 2\) or \(N, 3\)"),
    ]
    for points, neighbors, radii, match in cases:
        with pytest.raises(InvalidInputError, match=match):
            _core.mls_shape_functions(points, neighbors, radii)
