"""Active contours (rust/snake.rs, elastocap.silhouettes.snake) on constructed images: a
known outline under noise and clutter is found; resampling keeps the spacing within its
bounds; a collapsing contour is reported, not returned; bad input is refused."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from elastocap import InvalidInputError
from elastocap.silhouettes.gradient import filtered_gradient
from elastocap.silhouettes.snake import active_contour, mask_contours, polygon_mask, snake_silhouette


def blob(shape=(240, 320)) -> np.ndarray:
    """A body-like outline: an ellipse with an arm-like bar, filled."""
    mask = np.zeros(shape, np.uint8)
    cv2.ellipse(mask, (160, 130), (45, 75), 0, 0, 360, 1, -1)
    cv2.rectangle(mask, (160, 90), (250, 110), 1, -1)
    return mask != 0


def picture(mask: np.ndarray, rng: np.random.Generator, *, clutter: bool, noise: float) -> np.ndarray:
    h, w = mask.shape
    image = np.full((h, w, 3), 120.0)
    if clutter:
        for _ in range(40):
            x, y = rng.integers(0, w), rng.integers(0, h)
            a, b = rng.integers(5, 40, 2)
            cv2.rectangle(image, (int(x - a), int(y - b)), (int(x + a), int(y + b)), tuple(float(c) for c in rng.uniform(0, 255, 3)), -1)
    stripes = (np.sin(np.arange(h) / 3.0) > 0)[:, None, None] * 30.0
    image = np.where(mask[..., None], np.array([200.0, 60.0, 50.0]) + stripes, image)
    image += rng.normal(0, noise, image.shape)
    return np.clip(image, 0, 255).astype(np.uint8)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def outline_distance(points: np.ndarray, mask: np.ndarray) -> np.ndarray:
    outline = np.concatenate(mask_contours(mask))
    return np.linalg.norm(points[:, None, :] - outline[None, :, :], axis=2).min(axis=1)


@pytest.mark.parametrize(("clutter", "noise", "scale"), [(False, 2.0, 1.08), (False, 12.0, 0.93), (True, 6.0, 1.08), (True, 6.0, 0.93)])
def test_snake_finds_a_known_outline(clutter: bool, noise: float, scale: float) -> None:
    rng = np.random.default_rng(7)
    truth = blob()
    image = picture(truth, rng, clutter=clutter, noise=noise)
    # stereo's mask: the subject grown by 4 pixels, with a hole
    near = cv2.dilate(truth.astype(np.uint8), np.ones((9, 9), np.uint8)) != 0
    cv2.circle(near.view(np.uint8), (150, 150), 6, 0, -1)
    attraction, _ = filtered_gradient(image, near)
    start = mask_contours(truth)[0]
    centre = start.mean(axis=0)
    init = centre + scale * (start - centre)
    result = active_contour(attraction, init, max_iterations=400)
    assert result.status in ("converged", "maximum iterations")
    assert result.points is not None
    assert np.median(outline_distance(result.points, truth)) < 1.0
    assert iou(polygon_mask([result.points], truth.shape), truth) > 0.95
    # started away from it, the contour was that far: the test can fail
    assert np.median(outline_distance(init, truth)) > 3.0


def test_clutter_without_the_disparity_filter_misleads_the_snake() -> None:
    rng = np.random.default_rng(7)
    truth = blob()
    image = picture(truth, rng, clutter=True, noise=6.0)
    near = cv2.dilate(truth.astype(np.uint8), np.ones((9, 9), np.uint8)) != 0
    start = mask_contours(truth)[0]
    init = start.mean(axis=0) + 1.15 * (start - start.mean(axis=0))
    filtered = active_contour(filtered_gradient(image, near)[0], init, max_iterations=400)
    raw = active_contour(filtered_gradient(image, None)[0], init, max_iterations=400)
    assert filtered.points is not None and raw.points is not None
    assert iou(polygon_mask([filtered.points], truth.shape), truth) > iou(polygon_mask([raw.points], truth.shape), truth)


@pytest.mark.parametrize("radius", [6.0, 15.0])
def test_resampling_keeps_spacing_within_bounds(radius: float) -> None:
    """A small contour pulled out to a ring 8x its size stretches: it is resampled, and
    every segment ends within the bounds."""
    h = w = 200
    y, x = np.mgrid[0:h, 0:w]
    ring = np.exp(-((np.hypot(x - 100, y - 100) - 70) ** 2) / 800.0)
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    init = np.stack([100 + radius * np.cos(t), 100 + radius * np.sin(t)], axis=1)
    result = active_contour(ring, init, alpha=0.01, beta=0.1, kappa=200.0, spacing=3.0, spacing_bounds=(1.5, 6.0), max_iterations=600)
    assert result.points is not None
    assert result.resamplings > 0
    segments = np.linalg.norm(np.roll(result.points, -1, axis=0) - result.points, axis=1)
    assert segments.min() >= 1.5 and segments.max() <= 6.0
    assert np.abs(np.hypot(*(result.points - 100).T) - 70).max() < 3.0


def test_a_collapsing_contour_is_reported_not_returned() -> None:
    flat = np.zeros((120, 120))
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    init = np.stack([60 + 30 * np.cos(t), 60 + 30 * np.sin(t)], axis=1)
    result = active_contour(flat, init, alpha=2.0, max_iterations=3000, min_area=300.0)
    assert result.status == "collapsed" and result.points is None
    square = np.zeros((120, 120), bool)
    square[40:80, 40:80] = True
    mask, results = snake_silhouette(flat, square, alpha=2.0, max_iterations=3000, min_area=300.0)
    assert mask is None and results[0].status == "collapsed"


def test_bad_input_is_refused() -> None:
    image = np.zeros((50, 50))
    square = np.array([[10.0, 10.0], [40.0, 10.0], [40.0, 40.0], [10.0, 40.0]])
    with pytest.raises(InvalidInputError, match="init"):
        active_contour(image, square[:2])
    with pytest.raises(InvalidInputError):
        active_contour(np.full((50, 50), np.nan), square)
    with pytest.raises(InvalidInputError, match="spacing"):
        active_contour(image, square, spacing=10.0, spacing_bounds=(1.0, 5.0))
    with pytest.raises(InvalidInputError, match="disparity_mask"):
        filtered_gradient(np.zeros((50, 50, 3), np.uint8), np.ones((40, 40), bool))
    # an empty disparity leaves nothing to climb: no edges at all
    attraction, edges = filtered_gradient(picture(blob(), np.random.default_rng(0), clutter=True, noise=3.0), np.zeros((240, 320), bool))
    assert not edges.any() and not attraction.any()
