"""Signed distance fields: exact against scipy's EDT, sampled like scipy's trilinear
interpolation, and geometrically right on spheres."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy import ndimage

import elastocap
from elastocap import SDF, Grid
from tolerances import EDT_RTOL, TRILINEAR_RTOL


def reference_sdf(occ: np.ndarray, spacing=(1.0, 1.0, 1.0)) -> np.ndarray:
    half = min(spacing) / 2
    inside = ndimage.distance_transform_edt(occ, sampling=spacing)
    outside = ndimage.distance_transform_edt(~occ, sampling=spacing)
    return np.where(occ, -(inside - half), outside - half)


def blob(shape, seed, sigma=2.0):
    rng = np.random.default_rng(seed)
    return ndimage.gaussian_filter(rng.random(shape), sigma) > 0.5


CASES = {
    "blobs": blob((40, 33, 27), 0),
    "thin plate": np.pad(np.ones((1, 20, 20), bool), ((10, 10), (2, 2), (3, 3))),
    "single voxel": np.pad(np.ones((1, 1, 1), bool), ((4, 5), (3, 2), (6, 1))),
    "one slab line": np.pad(np.ones((30, 1, 1), bool), ((0, 0), (1, 1), (1, 1))),
    "flat grid": blob((50, 40, 1), 1),
}


@pytest.mark.parametrize("name", sorted(CASES))
@pytest.mark.parametrize("spacing", [(1.0, 1.0, 1.0), (0.5, 1.0, 2.0)])
def test_equals_scipy_edt(name, spacing):
    occ = CASES[name]
    assert occ.any() and not occ.all()
    got = elastocap.signed_distance(occ, spacing)
    np.testing.assert_allclose(got, reference_sdf(occ, spacing), rtol=EDT_RTOL, atol=0)


@settings(max_examples=60)
@given(hnp.arrays(bool, hnp.array_shapes(min_dims=3, max_dims=3, min_side=1, max_side=9)))
def test_equals_scipy_edt_on_random_grids(occ):
    if not occ.any() or occ.all():
        return  # no boundary: covered by test_empty_and_full_grids
    np.testing.assert_allclose(elastocap.signed_distance(occ), reference_sdf(occ), rtol=EDT_RTOL, atol=0)


def test_empty_and_full_grids():
    """No boundary: +inf outside everywhere, -inf inside everywhere (scipy's EDT returns a
    distance to a phantom background voxel there, which is not a distance to anything)."""
    assert np.all(elastocap.signed_distance(np.zeros((4, 5, 6), bool)) == np.inf)
    assert np.all(elastocap.signed_distance(np.ones((4, 5, 6), bool)) == -np.inf)


def sphere_sdf(radius=0.7, n=48):
    grid = Grid.around([-1, -1, -1], [1, 1, 1], n)
    centres = grid.centers()
    occ = np.linalg.norm(centres, axis=-1) <= radius
    return SDF.from_occupancy(occ, grid), radius


def unit_vectors(n, seed):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_zero_level_lies_within_one_voxel_of_the_sphere():
    sdf, r = sphere_sdf()
    on_surface = r * unit_vectors(2000, 1)
    assert np.abs(sdf.sample(on_surface)).max() <= sdf.grid.spacing


@settings(max_examples=40)
@given(st.floats(0.2, 0.95), st.integers(0, 10_000))
def test_gradient_points_outwards_and_closest_points_reach_the_sphere(distance, seed):
    sdf, r = sphere_sdf()
    direction = unit_vectors(1, seed)[0]
    x = distance * direction
    g = sdf.gradient(x[None])[0]
    if abs(distance - r) > 3 * sdf.grid.spacing:
        # Away from the surface the distance to the voxel set is smooth, radial and of unit
        # slope; within a few voxels of it the staircase of boundary voxels shows.
        assert np.dot(g, direction) > 0.95 * np.linalg.norm(g)
        assert 0.8 < np.linalg.norm(g) < 1.25
    closest = sdf.closest_points(x[None])[0]
    assert abs(np.linalg.norm(closest) - r) <= sdf.grid.spacing
    assert np.dot(closest / np.linalg.norm(closest), direction) > 0.99


def test_samples_equal_scipy_trilinear_interpolation_inside_the_grid():
    rng = np.random.default_rng(3)
    values = rng.normal(size=(7, 8, 9))
    grid = Grid([0.5, -1.0, 2.0], 0.3, values.shape)
    index = rng.uniform(0, np.array(values.shape) - 1, size=(500, 3))
    points = grid.origin + grid.spacing * index
    want = ndimage.map_coordinates(values, index.T, order=1)
    got, gradient = SDF(values, grid).sample_with_gradient(points)
    np.testing.assert_allclose(got, want, rtol=TRILINEAR_RTOL, atol=TRILINEAR_RTOL * np.abs(values).max())
    # The gradient is that of the interpolant: check it by central differences inside cells.
    h = 1e-6
    for axis in range(3):
        step = np.zeros(3)
        step[axis] = h
        fd = (SDF(values, grid).sample(points + step) - SDF(values, grid).sample(points - step)) / (2 * h)
        np.testing.assert_allclose(gradient[:, axis], fd, rtol=1e-5, atol=1e-5)


def test_outside_the_grid_adds_the_distance_to_the_box():
    values = np.arange(8.0).reshape(2, 2, 2)
    sdf = SDF(values, Grid([0, 0, 0], 1.0, (2, 2, 2)))
    np.testing.assert_allclose(sdf.sample([[3.0, 0.0, 0.0]]), [values[1, 0, 0] + 2.0])
    np.testing.assert_allclose(sdf.gradient([[3.0, 0.0, 0.0]]), [[1.0, 2.0, 1.0]])


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: elastocap.signed_distance(np.zeros((3, 3)), 1.0), "3-D"),
        (lambda: elastocap.signed_distance(np.zeros((3, 3, 3), complex), 1.0), "boolean"),
        (lambda: elastocap.signed_distance(np.zeros((3, 3, 3), bool), 0.0), "spacing"),
        (lambda: elastocap.signed_distance(np.zeros((3, 3, 3), bool), (1.0, np.nan, 1.0)), "spacing"),
        (lambda: SDF(np.zeros((3, 3, 3)), Grid([0, 0, 0], 1.0, (3, 3, 4))), "shape"),
        (lambda: SDF(np.zeros((3, 3, 3)), Grid([0, 0, 0], 1.0, (3, 3, 3))).sample([[0, np.nan, 0]]), "points"),
        (lambda: SDF(np.zeros((3, 3, 3)), Grid([0, 0, 0], 1.0, (3, 3, 3))).sample([[0, 0]]), "points"),
        (lambda: Grid([0, 0], 1.0, (3, 3, 3)), "origin"),
        (lambda: Grid([0, 0, 0], -1.0, (3, 3, 3)), "spacing"),
        (lambda: Grid([0, 0, 0], 1.0, (3, 0, 3)), "shape"),
    ],
)
def test_bad_input_is_a_clear_error(call, message):
    with pytest.raises(elastocap.InvalidInputError, match=message):
        call()
