"""Dense matching by region growing: recovery of a known smooth disparity field on a
band-limited texture with noise, the precision its covariance predicts, growth around
untextured obstacles from few seeds, Voronoi-like regions, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from elastocap import InvalidInputError
from elastocap.stereo.dense import grow_matches

SIZE = (320, 240)
# Matches vs the exact correspondence on a band-limited texture (periods 5.5 to 33 px,
# noise sigma 2 in both images): measured median 0.011-0.013 px per axis, max 0.1.
MEDIAN_ERROR_MAX = 0.03
ERROR_MAX = 0.3
# Normalised errors (error / predicted sigma): measured std 1.06-1.12.
NORMALISED_STD = (0.7, 1.5)
# Grid points matched out of those whose patches fit in both images (measured ~98%).
COVERAGE_MIN = 0.9


def _texture(u: np.ndarray, v: np.ndarray, seed: int) -> np.ndarray:
    """A band-limited texture: 40 plane waves of 0.03-0.18 cycles/px, known everywhere."""
    rng = np.random.default_rng(seed)
    frequency, angle, phase = rng.uniform(0.03, 0.18, 40), rng.uniform(0, 2 * np.pi, 40), rng.uniform(0, 2 * np.pi, 40)
    out = np.full(np.shape(u), 128.0)
    for f, a, p in zip(frequency, angle, phase):
        out += 9.0 * np.sin(2 * np.pi * f * (np.cos(a) * u + np.sin(a) * v) + p)
    return out


def _disparity(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Disparity as a function of the right image's pixel: smooth, 6 to 12.4 px."""
    return 9.0 + 3.0 * np.sin(2 * np.pi * x / 260.0) + 0.01 * y


def _pair(seed: int, noise: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    width, height = SIZE
    y, x = np.mgrid[0:height, 0:width].astype(float)
    rng = np.random.default_rng(100 + seed)
    left = _texture(x, y, seed) + rng.normal(0, noise, (height, width))
    right = _texture(x + _disparity(x, y), y, seed) + rng.normal(0, noise, (height, width))
    return left.astype(np.float32), right.astype(np.float32)


def _truth(points: np.ndarray) -> np.ndarray:
    """The right-image pixel of left pixels ``points``: solves ``x + d(x, v) = u``."""
    u, v = points[:, 0], points[:, 1]
    x = u - 9.0
    for _ in range(60):  # a contraction: |d/dx d| <= 0.073
        x = u - _disparity(x, v)
    return np.stack([x, v], axis=1)


@pytest.mark.parametrize("seed", [0, 1])
def test_recovers_a_smooth_disparity_field(seed: int) -> None:
    left, right = _pair(seed)
    rng = np.random.default_rng(seed)
    seeds = np.stack([rng.uniform(30, 290, 6), rng.uniform(30, 210, 6)], axis=1)
    found = grow_matches(left, right, seeds, _truth(seeds) + rng.normal(0, 0.7, (6, 2)))
    error = found.positions - _truth(found.points)
    assert np.median(np.abs(error)) < MEDIAN_ERROR_MAX
    assert np.abs(error).max() < ERROR_MAX
    normalised = error / np.sqrt(np.diagonal(found.covariance, axis1=1, axis2=2))
    assert NORMALISED_STD[0] < normalised.std() < NORMALISED_STD[1]
    # Coverage: the grid's first ~16 px of columns match outside the right image (disparity
    # 6-12 px plus the patch); the rest should nearly all match.
    assert len(found.points) >= COVERAGE_MIN * (found.grid != 0).sum() * (1 - 16 / SIZE[0])
    # The affine maps' centres are the positions; the growth ran in waves, not per point.
    np.testing.assert_array_equal(found.affine[:, :, 2], found.positions)
    assert found.waves < len(found.points) / 20
    # Regions: every match grew from one of the seeds, each seed's region is near it.
    assert set(np.unique(found.region)) <= set(range(6))
    nearest = np.argmin(np.linalg.norm(found.points[:, None] - seeds[None], axis=2), axis=1)
    assert (nearest == found.region).mean() > 0.7


def test_grows_around_an_untextured_wall_and_respects_the_mask() -> None:
    left, right = _pair(2)
    # A flat vertical bar 60 px wide from the top to 40 px above the bottom: nothing matches on it,
    # growth from seeds on its left must reach the right side around its lower end.
    left[:190, 130:190] = 128.0
    seeds = np.array([[60.0, 60.0], [80.0, 150.0]])
    mask = np.ones(left.shape, bool)
    mask[:, 300:] = False
    found = grow_matches(left, right, seeds, _truth(seeds), mask=mask)
    right_side = found.points[:, 0] > 195
    assert right_side.sum() > 2000
    # No match where even the largest patch (23 px) holds no texture.
    assert not ((found.points[:, 0] > 142) & (found.points[:, 0] < 178) & (found.points[:, 1] < 178)).any()
    assert found.points[:, 0].max() < 300
    error = found.positions - _truth(found.points)
    assert np.median(np.abs(error[right_side])) < MEDIAN_ERROR_MAX


def test_bad_seeds_are_dropped_and_bad_input_refused() -> None:
    left, right = _pair(3)
    seeds = np.array([[100.0, 100.0], [200.0, 120.0]])
    # A seed 30 px off cannot be refined near where it was put: no growth from it.
    far = _truth(seeds) + [[30.0, 0.0], [0.0, 0.0]]
    found = grow_matches(left, right, seeds, far)
    assert set(np.unique(found.region)) == {1}
    empty = grow_matches(left, right, np.zeros((0, 2)), np.zeros((0, 2)))
    assert len(empty.points) == 0 and empty.waves == 0
    with pytest.raises(InvalidInputError, match="seeds"):
        grow_matches(left, right, seeds, seeds[:1])
    with pytest.raises(InvalidInputError, match="mask"):
        grow_matches(left, right, seeds, seeds, mask=np.ones((10, 10), bool))
    with pytest.raises(InvalidInputError, match="odd"):
        grow_matches(left, right, seeds, seeds, size=10)
    with pytest.raises(InvalidInputError, match="template"):
        grow_matches(np.zeros((5, 5, 3)), right, seeds, seeds)
