"""Weighted least-squares matching (issue 15): template pixels weighted by a silhouette mask.

A patch on the edge of a moving body holds background that does not move with it: without
weights the match settles between the two motions (or fails), with the mask as weights it
follows the body. Scenes are exact: the body's texture and the background's are smooth
random fields sampled at each image's own pixels, so the body's true shift is known to
rounding."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from elastocap import InvalidInputError, _core
from elastocap.stereo import MatchStatus, match_patches

H, W = 80, 120
EDGE = 60.0  # the body's edge in the template: columns u < EDGE are body
SHIFT = np.array([1.3, -0.6])  # the body's motion, pixels


def _field(seed: int) -> ndimage.map_coordinates:
    """A smooth random texture (blobs of ~4 px, contrast ~30 grey levels) as a spline that
    can be sampled anywhere."""
    rng = np.random.default_rng(seed)
    raw = ndimage.gaussian_filter(rng.normal(0, 1, (H + 40, W + 40)), 2.0)
    raw *= 30.0 / raw.std()
    coefficients = ndimage.spline_filter(raw, order=3)

    def at(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return ndimage.map_coordinates(coefficients, [v + 20, u + 20], order=3, prefilter=False)

    return at


def _frames(seed: int, noise: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Template and next frame: the body (left of its edge) moves by SHIFT, the background
    (a different texture) stays. Returns both images and both masks (float32)."""
    body, background = _field(seed), _field(seed + 100)
    v, u = np.mgrid[0:H, 0:W].astype(float)
    rng = np.random.default_rng(seed + 200)
    images, masks = [], []
    for shift in (np.zeros(2), SHIFT):
        inside = u < EDGE + shift[0]
        grey = np.where(inside, 128 + body(u - shift[0], v - shift[1]), 100 + background(u, v))
        images.append((grey + rng.normal(0, noise, grey.shape)).astype(np.float32))
        masks.append(inside.astype(np.float32))
    return images[0], images[1], masks[0], masks[1]


def _edge_points() -> np.ndarray:
    """Points 3 to 5 px inside the body's edge: a third of their 15x15 patch is background."""
    rows = np.arange(20.0, 61.0, 5.0)
    return np.array([[EDGE - d, r] for r in rows for d in (3.0, 4.0, 5.0)])


@pytest.mark.parametrize("seed", [1000, 1001, 1002])
def test_mask_weights_make_an_edge_patch_follow_the_body(seed):
    template, search, mask, _ = _frames(seed)
    points = _edge_points()
    errors = {}
    for weighted in (False, True):
        m = match_patches(template, points, search, initial=points + np.round(SHIFT), size=15, min_texture=0.0,
                          weights=mask if weighted else None)
        ok = m.status[:, 0] == MatchStatus.CONVERGED
        error = np.linalg.norm(m.positions[:, 0] - (points + SHIFT), axis=1)
        errors[weighted] = np.where(ok, error, np.inf)
    # With weights every edge patch lands on the body's motion; without, the static third
    # of the patch pulls it off (or it does not converge).
    assert np.isfinite(errors[True]).all()
    assert np.max(errors[True]) < 0.06
    assert np.median(errors[False]) > 0.15


def test_unit_weights_match_exactly_as_without():
    template, search, _, _ = _frames(1003)
    points = np.array([[30.0, 30.0], [40.5, 50.25], [20.0, 60.0]])
    plain = match_patches(template, points, search, initial=points + 1.0, size=11, min_texture=0.0)
    ones = match_patches(template, points, search, initial=points + 1.0, size=11, min_texture=0.0,
                         weights=np.ones_like(template))
    np.testing.assert_array_equal(plain.status, ones.status)
    np.testing.assert_array_equal(plain.affine, ones.affine)
    np.testing.assert_array_equal(plain.covariance, ones.covariance)
    np.testing.assert_array_equal(plain.correlation, ones.correlation)


def test_weighted_correlation_and_sigma0_ignore_the_background():
    # A patch whose outside is noise unrelated to the search image: unweighted, the
    # correlation of the whole patch is poor; weighted, the body part alone correlates
    # as an interior patch does.
    template, search, mask, _ = _frames(1004, noise=0.5)
    rng = np.random.default_rng(7)
    scrambled = np.where(mask > 0, template, rng.uniform(0, 255, template.shape)).astype(np.float32)
    points = _edge_points()
    start = points + SHIFT
    weighted = match_patches(scrambled, points, search, initial=start, size=15, min_texture=0.0, weights=mask,
                             max_iterations=1)
    plain = match_patches(scrambled, points, search, initial=start, size=15, min_texture=0.0, max_iterations=1)
    assert np.min(weighted.correlation) > 0.98
    assert np.max(plain.correlation) < 0.9
    assert np.max(weighted.sigma0) < 3.0


def test_too_little_weight_is_low_texture():
    template, search, mask, _ = _frames(1005)
    # One column of weight 1: its pixels' neighbours weigh 0, so (a pixel weighs no more
    # than its neighbours) nothing is left to fit.
    thin = np.zeros_like(mask)
    thin[:, 30] = 1.0
    m = match_patches(template, [[30.0, 40.0]], search, initial=[[31.3, 39.4]], size=11, min_texture=0.0,
                      weights=thin)
    assert m.status[0, 0] == MatchStatus.LOW_TEXTURE


def test_track_step_with_mask_weights_follows_the_edge():
    previous, current, mask0, mask1 = _frames(1006)
    points = _edge_points()[None]
    nan = np.full_like(points, np.nan)
    found = {}
    for weighted in (False, True):
        pos, flags, _, _ = _core.track_step([previous], [current], points, nan, size=15, radius=3,
                                            min_correlation=0.5, forward_backward=0.3,
                                            weights=([mask0], [mask1]) if weighted else None)
        error = np.linalg.norm(pos[0] - (points[0] + SHIFT), axis=1)
        found[weighted] = (flags[0] == 0) & (error < 0.1)
    assert found[True].mean() >= 0.9
    assert found[False].mean() <= 0.3


def test_bad_weights():
    template, search, mask, _ = _frames(1007)
    with pytest.raises(InvalidInputError, match="weights"):
        match_patches(template, [[30.0, 30.0]], search, weights=mask[:, :-1])
    bad = mask.copy()
    bad[0, 0] = np.nan
    with pytest.raises(InvalidInputError, match="weights"):
        match_patches(template, [[30.0, 30.0]], search, weights=bad)
    z = np.zeros((1, 1, 2))
    with pytest.raises(InvalidInputError, match="weights"):
        _core.track_step([template], [search], z, z, weights=([mask], []))
    with pytest.raises(InvalidInputError, match="weights"):
        _core.track_step([template], [search], z, z, weights=([mask[:, :-1]], [mask]))
