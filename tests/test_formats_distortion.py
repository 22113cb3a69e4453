"""OpenCV's full distortion model (k1-k6, p1 p2, s1-s4): the Python camera and the Rust
projection the carving uses both equal cv2.projectPoints, for every coefficient count
OpenCV takes; the inverse and the fold radius hold for the rational model too."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import elastocap
import elastocap._core as _core
from elastocap import Camera
from elastocap.cameras.distortion import as_coefficients, distort, fold_radius
from tolerances import PROJECTION_ATOL_PX, RAY_RTOL

# Coefficients of a real wide-angle lens calibrated with CALIB_RATIONAL_MODEL |
# CALIB_THIN_PRISM_MODEL (magnitudes as OpenCV reports them), truncated per length.
FULL = np.array([0.21, -0.12, 1.1e-3, -7e-4, 0.05, 0.17, -0.09, 0.04, 1.2e-3, -3e-4, -8e-4, 2e-4, 0.0, 0.0])
K = np.array([[812.5, 0.0, 331.25], [0.0, 809.75, 238.5], [0.0, 0.0, 1.0]])


def camera_with(length: int, seed: int = 0) -> Camera:
    rng = np.random.default_rng(seed)
    R = cv2.Rodrigues(rng.normal(scale=0.3, size=3))[0]
    return Camera(f"n{length}", K, FULL[:length], R, rng.normal(scale=0.1, size=3) + [0, 0, 4.0], 640, 480)


def points_in_view(camera: Camera, n: int, seed: int) -> np.ndarray:
    """World points whose rays pass inside the image (with a margin), at depths 1 to 8."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform([-40, -40], [camera.width + 40, camera.height + 40], size=(n, 2))
    origins, directions = camera.rays(uv)
    keep = np.isfinite(directions).all(axis=1)
    return origins[keep] + directions[keep] * rng.uniform(1, 8, size=(keep.sum(), 1))


@pytest.mark.parametrize("length", [4, 5, 8, 12, 14])
def test_python_and_rust_projections_equal_opencv(length):
    camera = camera_with(length, seed=length)
    X = points_in_view(camera, 400, seed=length)
    expected, _ = cv2.projectPoints(X, cv2.Rodrigues(np.array(camera.R))[0], np.array(camera.t), np.array(camera.K),
                                    FULL[:length])
    expected = expected[:, 0]
    ours, depth = camera.project(X)
    assert (depth > 0).all()
    np.testing.assert_allclose(ours, expected, rtol=0, atol=PROJECTION_ATOL_PX)
    rust = _core.camera_project(X, np.array(camera.K), FULL[:length].copy(), np.array(camera.R), np.array(camera.t),
                                camera.width, camera.height)
    np.testing.assert_allclose(rust, expected, rtol=0, atol=PROJECTION_ATOL_PX)


@settings(max_examples=40, deadline=None)
@given(
    coefficients=st.lists(st.floats(-0.2, 0.2), min_size=12, max_size=12),
    seed=st.integers(0, 2**31),
)
# Found by hypothesis: k5, k6 of 1e-100 and 1e-38 made the core's companion matrix noise and
# its fold radius a spurious tiny root, so every point was refused.
@example(coefficients=[0.0] * 6 + [-3.92791981116489e-100 / 0.5, 1.1754943508222875e-38 / 0.2] + [0.0] * 4, seed=0)
def test_random_full_models_match_opencv(coefficients, seed):
    dist = np.array(coefficients) * np.array([1, 0.5, 0.01, 0.01, 0.2, 1, 0.5, 0.2, 0.01, 0.01, 0.01, 0.01])
    camera = Camera("c", K, dist, np.eye(3), [0.0, 0.0, 3.0], 640, 480)
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(-1, 1, (60, 2)), rng.uniform(-0.5, 2, 60)])  # |a|, |b| <= 0.6
    expected = cv2.projectPoints(X, np.zeros(3), np.array(camera.t), K, dist)[0][:, 0]
    np.testing.assert_allclose(camera.project(X)[0], expected, rtol=0, atol=PROJECTION_ATOL_PX)
    rust = _core.camera_project(X, K, dist, np.eye(3), np.array(camera.t), 640, 480)
    inside = np.hypot(*(X[:, :2] / (X[:, 2:] + 3)).T) < camera.fold_radius
    np.testing.assert_allclose(rust[inside], expected[inside], rtol=0, atol=PROJECTION_ATOL_PX)
    assert np.isnan(rust[~inside]).all()


@pytest.mark.parametrize("length", [8, 12])
def test_rays_invert_the_full_model(length):
    camera = camera_with(length, seed=3)
    X = points_in_view(camera, 300, seed=4)
    uv, _ = camera.project(X)
    origins, directions = camera.rays(uv)
    to_point = X - origins
    off_ray = np.linalg.norm(np.cross(to_point, directions), axis=1) / np.linalg.norm(to_point, axis=1)
    assert off_ray.max() < RAY_RTOL


def test_fold_radius_of_the_rational_model_is_where_the_radial_map_turns():
    dist = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.4, 0.0, 0.0])  # r / (1 + 0.4 r^2) peaks at r^2 = 2.5
    assert fold_radius(dist) == pytest.approx(np.sqrt(2.5), rel=1e-12)
    r = np.linspace(0, 3, 30001)
    radial = distort(np.column_stack([r, np.zeros_like(r)]), dist)[:, 0]
    assert r[np.argmax(radial)] == pytest.approx(np.sqrt(2.5), abs=1e-3)
    # A vanishing denominator bounds the range: 1 - 0.25 r^2 = 0 at r = 2.
    assert fold_radius(np.array([0, 0, 0, 0, 0, -0.25, 0, 0.0])) == pytest.approx(2.0, rel=1e-12)
    camera = Camera("c", K, [0, 0, 0, 0, 0, 0.4, 0, 0], np.eye(3), [0, 0, 0], 640, 480)
    beyond = np.array([[2.0, 0.0, 1.0], [1.0, 0.0, 1.0]])  # r = 2 beyond the fold, r = 1 inside
    assert not camera.visible(beyond)[0]
    rust = _core.camera_project(beyond, K, np.array(camera.dist), np.eye(3), np.zeros(3), 640, 480)
    assert np.isnan(rust[0]).all() and np.isfinite(rust[1]).all()


def test_coefficients_are_kept_at_the_shortest_opencv_length():
    assert as_coefficients([0.1, 0.2, 0, 0]).tolist() == [0.1, 0.2, 0, 0, 0]
    assert as_coefficients(FULL[:8]).size == 8
    assert as_coefficients(np.r_[FULL[:5], np.zeros(3)]).size == 5
    assert as_coefficients(FULL[:12]).size == 12
    assert as_coefficients(np.r_[FULL[:8], np.zeros(6)]).size == 8
    camera = Camera("c", K, FULL[:12].reshape(1, 12), np.eye(3), [0, 0, 1], 640, 480)
    assert camera.full_dist.tolist() == FULL[:12].tolist()


@pytest.mark.parametrize(
    ("dist", "message"),
    [
        (np.r_[np.zeros(12), 0.01, 0.0], "tilted-sensor terms tauX, tauY"),
        (np.zeros(6), "4, 5, 8, 12 or 14 coefficients"),
        (np.zeros(13), "4, 5, 8, 12 or 14 coefficients"),
        (np.r_[np.zeros(7), np.nan], "finite"),
    ],
)
def test_unsupported_distortion_is_refused_by_name(dist, message):
    with pytest.raises(elastocap.InvalidInputError, match=message):
        Camera("c", K, dist, np.eye(3), [0, 0, 1], 640, 480)


def test_carving_honours_the_rational_and_thin_prism_terms():
    """An ellipsoid seen through strongly distorting lenses (rational k4-k6, thin prism):
    the conservative hull keeps every voxel inside it; carving with the same cameras but
    only their first five coefficients cuts into it, so the extra terms reach the carving."""
    from test_hull import GRID, ellipsoid, ring, render

    lens = np.array([0.3, 0.1, 1e-3, -1e-3, 0.05, 3.0, 0.1, 0.02, 4e-3, 0.0, -4e-3, 0.0])
    rig = elastocap.Rig(c.replace(dist=lens) for c in ring(8).cameras)
    mesh = ellipsoid()
    masks = [render(mesh, camera) for camera in rig.cameras]
    inside = ((GRID.centers() / np.array([0.5, 0.35, 0.25])) ** 2).sum(axis=-1) <= 1
    assert elastocap.visual_hull(masks, rig, GRID).occupancy[inside].all()
    truncated = elastocap.Rig(c.replace(dist=c.dist[:5]) for c in rig.cameras)
    assert not elastocap.visual_hull(masks, truncated, GRID).occupancy[inside].all()
