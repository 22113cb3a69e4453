"""The tracker's box search with per-pixel template weights (rust/track/weighted_ncc.rs),
against a numpy reference of the weighted normalised cross-correlation."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from elastocap import _core
from elastocap._core import InvalidInputError

W, H = 160, 120


def _texture(seed: int, shift: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    noise = np.random.default_rng(seed).normal(0.0, 1.0, (H + 40, W + 40)).astype(np.float32)
    image = 128.0 + 40.0 * cv2.GaussianBlur(noise, (0, 0), 1.5) / 0.2
    m = np.array([[1.0, 0.0, shift[0] - 20], [0.0, 1.0, shift[1] - 20]])
    return np.ascontiguousarray(cv2.warpAffine(image, m, (W, H), flags=cv2.INTER_CUBIC), dtype=np.float32)


def _sample(image: np.ndarray, centre: np.ndarray, side: int) -> np.ndarray:
    """Bilinear samples of the ``side x side`` window centred on ``centre`` (the Rust
    sampler's convention: the window's first sample at ``centre - side // 2``)."""
    u0, v0 = centre[0] - side // 2, centre[1] - side // 2
    iu, iv = int(np.floor(u0)), int(np.floor(v0))
    tu, tv = u0 - iu, v0 - iv
    a = image[iv : iv + side + 1, iu : iu + side + 1].astype(np.float64)
    top = a[:-1, :-1] + tu * (a[:-1, 1:] - a[:-1, :-1])
    bottom = a[1:, :-1] + tu * (a[1:, 1:] - a[1:, :-1])
    return top + tv * (bottom - top)


def _reference(template, weights, point, search, prediction, size, radius) -> np.ndarray:
    """(2r+1, 2r+1) weighted NCC of the template at every integer shift, by its definition."""
    t = _sample(template, point, size)
    w = np.clip(np.nan_to_num(_sample(weights, point, size), nan=0.0), 0.0, 1.0)
    window = _sample(search, prediction, size + 2 * radius)
    patches = np.lib.stride_tricks.sliding_window_view(window, (size, size))
    total = w.sum()
    dt = t - (w * t).sum() / total
    ds = patches - np.einsum("ijab,ab->ij", patches, w)[..., None, None] / total
    num = np.einsum("ijab,ab->ij", ds, w * dt)
    var = np.einsum("ijab,ab->ij", ds * ds, w)
    return num / np.sqrt((w * dt * dt).sum() * var)


def _cut_weights(angle: float, offset: float, soft: float) -> np.ndarray:
    """Weights 1 on one side of a line through the image centre (at ``angle``, moved by
    ``offset`` px), 0 on the other, over a ramp of ``soft`` px."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    d = (u - W / 2) * np.cos(angle) + (v - H / 2) * np.sin(angle) - offset
    return np.ascontiguousarray(np.clip(0.5 + d / max(soft, 1e-6), 0.0, 1.0), dtype=np.float32)


@settings(max_examples=25, deadline=None)
@given(st.floats(0, 2 * np.pi), st.floats(-5.0, 5.0), st.floats(0.0, 4.0), st.floats(0.0, 1.0), st.floats(0.0, 1.0),
       st.sampled_from([4, 6, 9]), st.sampled_from([11, 15]))
def test_scores_are_the_weighted_correlation_at_every_shift(angle, offset, soft, fu, fv, radius, size):
    previous, current = _texture(3), _texture(3, (2.6, -1.8))
    weights = _cut_weights(angle, offset, soft)
    point = np.array([W / 2 + fu, H / 2 + fv])
    prediction = point + np.array([1.9, -1.1])
    found = _core.track_box_search(previous, point, current, prediction, size=size, radius=radius, weights=weights)
    assert found is not None
    centre, score, scores = found
    assert scores.shape == (2 * radius + 1, 2 * radius + 1)
    share = np.clip(_sample(weights, point, size), 0, 1).sum() / size**2
    if share < 0.25:
        # Too little weight: searched as without weights.
        plain = _core.track_box_search(previous, point, current, prediction, size=size, radius=radius)
        np.testing.assert_array_equal(scores, plain[2])
        return
    expected = _reference(previous, weights, point, current, prediction, size, radius)
    np.testing.assert_allclose(scores, expected, atol=1e-4)
    r, c = np.unravel_index(np.argmax(expected), expected.shape)
    assert score == pytest.approx(scores.max())
    # The integer peak is the reference's (where it is not a near tie), within half a pixel.
    if np.sort(expected.ravel())[-2] < expected.max() - 1e-3:
        assert abs(centre[0] - (prediction[0] + c - radius)) <= 0.5 + 1e-9
        assert abs(centre[1] - (prediction[1] + r - radius)) <= 0.5 + 1e-9


@settings(max_examples=15, deadline=None)
@given(st.floats(0.05, 0.99), st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_uniform_weights_give_the_plain_correlation(level, fu, fv):
    previous, current = _texture(5), _texture(5, (-1.4, 2.2))
    point = np.array([70.0 + fu, 60.0 + fv])
    prediction = point + np.array([-1.0, 2.0])
    weights = np.full((H, W), level, np.float32)
    c0, s0, plain = _core.track_box_search(previous, point, current, prediction)
    c1, s1, weighted = _core.track_box_search(previous, point, current, prediction, weights=weights)
    np.testing.assert_allclose(weighted, plain, atol=1e-4)
    np.testing.assert_allclose(c1, c0, atol=1e-3)
    # The true motion (-1.4, 2.2) is found.
    np.testing.assert_allclose(np.array(c1) - point, [-1.4, 2.2], atol=0.3)


def test_weights_of_one_and_nan_free_masks_are_the_plain_search_to_the_bit():
    previous, current = _texture(7), _texture(7, (0.7, 0.4))
    point, prediction = np.array([80.0, 60.0]), np.array([80.3, 60.2])
    plain = _core.track_box_search(previous, point, current, prediction)
    ones = _core.track_box_search(previous, point, current, prediction, weights=np.ones((H, W), np.float32))
    assert plain[0] == ones[0] and plain[1] == ones[1]
    np.testing.assert_array_equal(plain[2], ones[2])


def test_the_limbs_weights_find_its_motion_where_the_plain_search_does_not():
    # A 7 px wide limb (moving (4, -3)) in front of a surface moving (-3, 2); the template
    # centred on the limb holds 8 columns of the surface: the plain search follows the
    # surface, the limb's weights find the limb.
    def frame(limb_shift, behind_shift):
        image = _texture(11, behind_shift)
        limb = _texture(12, limb_shift)
        on = np.zeros((H, W), bool)
        u0 = int(round(77 + limb_shift[0]))
        on[:, u0 : u0 + 7] = True
        image[on] = limb[on]
        return np.ascontiguousarray(image), np.ascontiguousarray(on, dtype=np.float32)

    (a, mask), (b, _) = frame((0.0, 0.0), (0.0, 0.0)), frame((4.0, -3.0), (-3.0, 2.0))
    point = np.array([80.0, 60.0])
    plain = _core.track_box_search(a, point, b, point)
    weighted = _core.track_box_search(a, point, b, point, weights=mask)
    truth = point + [4.0, -3.0]
    assert np.hypot(*(np.array(plain[0]) - truth)) > 2.0  # between the two motions, or the surface's
    assert np.hypot(*(np.array(weighted[0]) - truth)) < 0.3 and weighted[1] > 0.9


def test_bad_input():
    image = _texture(1)
    point = [80.0, 60.0]
    with pytest.raises(InvalidInputError):
        _core.track_box_search(image, point, image, point, weights=np.ones((H, W - 1), np.float32))
    with pytest.raises(InvalidInputError):
        _core.track_box_search(image, point, image, point, size=14)
    # A window leaving the image: nothing found.
    assert _core.track_box_search(image, [3.0, 60.0], image, [3.0, 60.0]) is None
    assert _core.track_box_search(image, point, image, [W - 4.0, 60.0]) is None
