"""Disparity: the Tsukuba figure, depth against the truth of a rendered textured scene seen
by a skewed, distorted pair, the geometry against OpenCV, the post-processing steps against
references, and bad input."""

import functools
import warnings

import cv2
import numpy as np
import pytest
from data_paths import SHARED_DATA
from scipy import ndimage

from elastocap import Camera, InvalidInputError
from elastocap.stereo.board import subpixel_rays
from elastocap.stereo.disparity import DisparityWarning, compute_disparity, disparity_range
from elastocap.stereo.disparity_filter import (
    fill_from_background,
    guided_filter,
    left_right_consistent,
    weighted_median,
    window_correlation,
)
from elastocap.stereo.disparity_scene import random_scene
from elastocap.stereo.disparity_stage import disparity_to_points, pair_disparity, write_disparity
from elastocap.stereo.disparity_subpixel import refine_subpixel
from elastocap.stereo.rectify import rectify_pair

TSUKUBA = SHARED_DATA / "tsukuba"
# The figure: at most 4% of the pixels with known disparity off by more than 1 px,
# unmatched pixels counted as wrong.
TSUKUBA_BAD = 0.04
# Rendered scene seen by a skewed, distorted pair: seed 7 (the guard band below the volume's
# range was chosen on seeds 0-2 of this scene, the disparity settings on other scenes). On
# seeds 5-8 the stage gives: mask recall 0.94-0.99, precision 0.965-0.98, checked matches on
# 92-98% of the volume's pixels, median disparity error 0.30-0.44 px, 1.6-12% of them over
# 1 px; seed 7: 0.949, 0.972, 92.3%, 0.327 px, 2.0%. The bounds below leave room for other
# OpenCV builds.
SCENE_SEED = 7
MASK_RECALL, MASK_PRECISION, CHECKED_SHARE = 0.92, 0.9, 0.88
MEDIAN_ERROR_PX, OVER_ONE_PX_SHARE = 0.45, 0.08


def _tsukuba():
    left = cv2.imread(str(TSUKUBA / "tsukuba1.png"))[..., ::-1].copy()
    right = cv2.imread(str(TSUKUBA / "tsukuba2.png"))[..., ::-1].copy()
    truth = cv2.imread(str(TSUKUBA / "tsukuba_gt.png"), cv2.IMREAD_GRAYSCALE) / 16.0
    return left, right, np.where(truth > 0, truth, np.nan)


@pytest.mark.skipif(not TSUKUBA.is_dir(), reason="Tsukuba not found")
def test_tsukuba_figure():
    left, right, truth = _tsukuba()
    result = compute_disparity(left, right, min_disparity=0, num_disparities=16)
    known = np.isfinite(truth)
    matched = np.isfinite(result.disparity)
    assert matched[known].all()  # every pixel gets a disparity: holes would count as wrong
    with np.errstate(invalid="ignore"):
        wrong = ~matched | (np.abs(result.disparity - truth) > 1.0)
    assert wrong[known].mean() <= TSUKUBA_BAD


# --------------------------------------------------------------------------- rendered rig


def _look_at(centre, target, roll):
    z = target - centre
    z = z / np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R = cv2.Rodrigues(np.array([0.0, 0.0, roll]))[0] @ np.stack([x, np.cross(z, x), z])
    return R, -R @ centre


TARGET = np.array([0.0, 0.0, 1.2])
VOLUME = np.array([TARGET - 0.3, TARGET + 0.3])


@functools.lru_cache(maxsize=None)
def _rig_scene(seed):
    """A short-baseline pair (11 cm at 1.2 m) with skew and distortion, looking at a textured
    scene inside VOLUME before a background plane 0.9 m behind its centre."""
    Ra, ta = _look_at(np.array([-0.05, 0.0, 0.0]), TARGET, 0.01)
    Rb, tb = _look_at(np.array([0.06, 0.005, 0.01]), TARGET, -0.015)
    a = Camera("a", [[300.0, 2.5, 158], [0, 298, 122], [0, 0, 1]], [-0.18, 0.05, 0.001, -0.0005, 0], Ra, ta, 320, 240)
    b = Camera("b", [[305.0, -2.0, 163], [0, 303, 118], [0, 0, 1]], [-0.12, 0.03, -0.0008, 0.0006, 0], Rb, tb, 320, 240)
    scene = random_scene(seed, TARGET, 0.3, np.zeros(3), focal=300.0, background=3.0)
    rng = np.random.default_rng(seed)
    return a, b, scene, scene.render(a, rng=rng), scene.render(b, rng=rng)


def test_depth_of_a_rendered_scene():
    a, b, scene, image_a, image_b = _rig_scene(SCENE_SEED)
    pair = rectify_pair(a, b, volume=VOLUME)
    result = pair_disparity(pair, image_a, image_b, VOLUME)
    # The truth in the left rectified image: depth of every pixel centre, the disparity it
    # makes, and which pixels see a surface inside the volume.
    depth = scene.depth(pair.left_rectified)
    truth = pair.focal * pair.baseline / depth + pair.disparity_offset
    directions = subpixel_rays(pair.left_rectified, 1).reshape(depth.shape + (3,))
    directions /= (directions @ pair.rotation[2])[..., None]
    points = pair.left.center + directions * depth[..., None]
    inside = ((points >= VOLUME[0]) & (points <= VOLUME[1])).all(axis=-1)
    mask = result.mask
    recall = (mask & inside).sum() / inside.sum()
    precision = (mask & inside).sum() / mask.sum()
    assert recall >= MASK_RECALL and precision >= MASK_PRECISION
    checked = inside & result.disparity.valid
    assert checked.sum() >= CHECKED_SHARE * inside.sum()
    error = np.abs(result.disparity.disparity - truth)[checked]
    assert np.median(error) <= MEDIAN_ERROR_PX
    assert (error > 1.0).mean() <= OVER_ONE_PX_SHARE
    # The world points of the mask, against the surface point seen at the same pixel.
    got, pixels = disparity_to_points(result.disparity.disparity, pair, mask=mask & inside & result.disparity.valid)
    distance = np.linalg.norm(got - points[pixels[:, 1], pixels[:, 0]], axis=1)
    depth_per_pixel = depth[pixels[:, 1], pixels[:, 0]] ** 2 / (pair.focal * pair.baseline)  # dZ/dd
    assert np.median(distance / depth_per_pixel) <= MEDIAN_ERROR_PX  # in pixels of disparity
    assert len(result.points) == (mask & result.disparity.valid).sum()
    assert result.mask_original.shape == (a.height, a.width)


def test_points_equal_opencv_reprojection():
    a, b, *_ = _rig_scene(SCENE_SEED)
    pair = rectify_pair(a, b, volume=VOLUME)
    width, height = pair.size
    rng = np.random.default_rng(0)
    disparity = (pair.disparity_offset + rng.uniform(5, 40, (height, width))).astype(np.float32)
    K = pair.left_rectified.K
    B = pair.baseline
    # OpenCV's Q for a rectified pair whose right camera sits at -Tx = B along x.
    Q = np.array([[1, 0, 0, -K[0, 2]], [0, 1, 0, -K[1, 2]], [0, 0, 0, K[0, 0]], [0, 0, 1 / B, -pair.disparity_offset / B]])
    expected = cv2.reprojectImageTo3D(disparity, Q)
    points, pixels = disparity_to_points(disparity, pair)
    in_rectified = (points - pair.left.center) @ pair.rotation.T
    np.testing.assert_allclose(in_rectified, expected[pixels[:, 1], pixels[:, 0]], rtol=1e-5)


def test_range_covers_the_volume():
    a, b, *_ = _rig_scene(SCENE_SEED)
    pair = rectify_pair(a, b, volume=VOLUME)
    minimum, count = disparity_range(pair, VOLUME, margin=0.0)
    X = np.random.default_rng(1).uniform(VOLUME[0], VOLUME[1], (5000, 3))
    d = pair.left_rectified.project(X)[0][:, 0] - pair.right_rectified.project(X)[0][:, 0]
    assert d.min() >= minimum and d.max() < minimum + count and count % 16 == 0
    # Tight: the range is no wider than the volume's disparities plus rounding to 16.
    assert d.max() - d.min() > count - 16 - 2


# --------------------------------------------------------------------------- steps


def test_left_right_check_and_background_fill():
    left = np.array([[np.nan, 2.0, 2.0, 5.0, 5.0, 2.0]], np.float32)
    right = np.array([[2.0, 2.0, 2.0, 2.0, 5.0, 2.0]], np.float32)
    valid = left_right_consistent(left, right, tolerance=0.5)
    # u=1: 1-2 = -1 outside; u=2: right[0] = 2 ok; u=3: right[-2] outside; u=4: right[-1]
    # outside... only matches landing in the right image and agreeing survive.
    np.testing.assert_array_equal(valid, [[False, False, True, False, False, True]])
    filled = fill_from_background(left, valid)
    np.testing.assert_array_equal(filled, [[2.0, 2.0, 2.0, 2.0, 2.0, 2.0]])
    rng = np.random.default_rng(0)
    d = rng.uniform(0, 10, (20, 30)).astype(np.float32)
    keep = rng.random((20, 30)) < 0.3
    out = fill_from_background(d, keep)
    for r in range(20):
        columns = np.flatnonzero(keep[r])
        for c in range(30):
            if keep[r, c]:
                assert out[r, c] == d[r, c]
            elif columns.size:
                neighbours = [d[r, columns[columns < c].max()]] if (columns < c).any() else []
                neighbours += [d[r, columns[columns > c].min()]] if (columns > c).any() else []
                assert out[r, c] == min(neighbours)


def test_guided_filter_matches_its_definition():
    rng = np.random.default_rng(1)
    guide = ndimage.uniform_filter(rng.random((40, 50)), 3).astype(np.float32)
    p = rng.random((40, 50)).astype(np.float32)
    r, eps = 3, 1e-3
    box = lambda x: ndimage.uniform_filter(x.astype(np.float64), 2 * r + 1, mode="reflect")  # noqa: E731
    a = (box(guide * p) - box(guide) * box(p)) / (box(guide * guide) - box(guide) ** 2 + eps)
    b = box(p) - a * box(guide)
    expected = box(a) * guide + box(b)
    np.testing.assert_allclose(guided_filter(guide, p, radius=r, eps=eps), expected, atol=1e-4)


def test_weighted_median_with_a_flat_guide():
    rng = np.random.default_rng(2)
    d = rng.integers(0, 12, (30, 40)).astype(np.float32)
    guide = np.full((30, 40), 0.5, np.float32)
    r = 2
    out = weighted_median(guide, d, np.arange(-1.0, 13.0), radius=r, eps=1e-2)
    # A flat guide makes the guided filter the mean of the window means: weights are the
    # (2r+1)-box convolved with itself, a tent over (4r+1)^2 pixels.
    tent = np.convolve(np.ones(2 * r + 1), np.ones(2 * r + 1)) / (2 * r + 1) ** 2
    weights = np.outer(tent, tent)
    reach = 2 * r
    for row in range(reach, 30 - reach):
        for column in range(reach, 40 - reach):
            window = d[row - reach : row + reach + 1, column - reach : column + reach + 1].ravel()
            order = np.argsort(window, kind="stable")
            cumulative = np.cumsum(weights.ravel()[order])
            median = window[order][np.searchsorted(cumulative, 0.5 - 1e-6)]
            # The interpolated crossing lies in (median - 1, median].
            assert median - 1 < out[row, column] <= median + 1e-4


def test_subpixel_refinement_undoes_pixel_locking():
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (120, 260)).astype(np.float32), (0, 0), 1.5)
    texture = cv2.normalize(texture, None, 10, 245, cv2.NORM_MINMAX)
    rows, columns = np.mgrid[0:120, 0:220].astype(np.float32)
    shift = 7.3
    left = cv2.remap(texture, columns + 20, rows, cv2.INTER_CUBIC).astype(np.uint8)
    right = cv2.remap(texture, columns + 20 + shift, rows, cv2.INTER_CUBIC).astype(np.uint8)
    sgbm = compute_disparity(left, right, min_disparity=0, num_disparities=16, fill=False, subpixel_radius=0)
    interior = (slice(10, -10), slice(30, -10))
    locked = np.nanmedian(sgbm.disparity[interior]) - shift
    refined, accepted = refine_subpixel(left, right, sgbm.disparity, sgbm.valid)
    assert accepted[interior].mean() > 0.9
    error = (refined - shift)[interior][accepted[interior]]
    assert abs(np.median(error)) < 0.02 < abs(locked)
    assert np.percentile(np.abs(error), 95) < 0.05


def test_window_correlation():
    rng = np.random.default_rng(3)
    image = rng.integers(0, 255, (30, 40)).astype(np.uint8)
    same = window_correlation(image, image, np.zeros((30, 40), np.float32))
    np.testing.assert_allclose(same, 1.0, atol=1e-4)
    other = window_correlation(image, rng.integers(0, 255, (30, 40)).astype(np.uint8), np.zeros((30, 40), np.float32))
    assert np.abs(other).mean() < 0.3


# --------------------------------------------------------------------------- bad input and files


def test_bad_input():
    image = np.random.default_rng(0).integers(0, 255, (60, 80, 3)).astype(np.uint8)
    with pytest.raises(InvalidInputError, match="same shape"):
        compute_disparity(image, image[:50])
    with pytest.raises(InvalidInputError, match="uint8"):
        compute_disparity(image.astype(np.float32), image)
    with pytest.raises(InvalidInputError, match="multiple of 16"):
        compute_disparity(image, image, num_disparities=20)
    black = np.zeros_like(image)
    with pytest.warns(DisparityWarning, match="blank"):
        empty = compute_disparity(black, black, num_disparities=16)
    assert np.isnan(empty.disparity).all() and not empty.valid.any()
    a, b, *_ = _rig_scene(SCENE_SEED)
    pair = rectify_pair(a, b)
    with pytest.raises(InvalidInputError, match="behind"):
        disparity_range(pair, np.array([[-1.0, -1.0, -3.0], [1.0, 1.0, -2.0]]))
    with pytest.raises(InvalidInputError, match="does not overlap|outside"):
        disparity_range(pair, np.array([[5.0, -0.1, 1.0], [5.5, 0.1, 1.5]]))
    with pytest.raises(InvalidInputError, match="same shape|left_image"):
        pair_disparity(pair, image, image, VOLUME)


def test_disparity_files(tmp_path):
    a, b, _, image_a, image_b = _rig_scene(SCENE_SEED)
    pair = rectify_pair(a, b, volume=VOLUME)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = pair_disparity(pair, image_a, image_b, VOLUME)
    png, npz = write_disparity(tmp_path, result, 12)
    assert png == tmp_path / "disparity" / "a-b" / "000012.png"
    mask = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    np.testing.assert_array_equal(mask > 0, result.mask_original)
    assert set(np.unique(mask)) <= {0, 255}
    data = np.load(npz)
    np.testing.assert_array_equal(data["disparity"], result.disparity.disparity)
    np.testing.assert_array_equal(data["mask"], result.mask)
    assert str(data["left"]) == "a" and str(data["right"]) == "b"
    assert sorted(p.name for p in png.parent.iterdir()) == ["000012.npz", "000012.png"]
