"""The seeding's Rust kernels (benches/README.md, "seednear1", "seedfast1"): the hull test
(``seed_hull_inside``: the rotation into each camera, the pixel, the footprint and the mask
read) must give the numbers of the numpy code it replaces, bit for bit: every seed (and so
every track) follows from it. (Its rotation is OpenBLAS's fused multiply-add chain, which
numpy's product is on x86-64 with FMA: the machines this is built and tested on.) The correlation along a seed's line is
``track_ncc_at``'s (its grouped scoring is checked against one candidate at a time in
``rust/track/ncc_at_tests.rs``); here, that it finds the shift on a seed's line."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_track_seeding_hull import _camera, _numpy_seen_pixels, fused_blas

from elastocap import InvalidInputError, _core
from elastocap.cameras import Camera
from elastocap.cameras.distortion import padded

SEEDS = st.integers(min_value=0, max_value=2**32 - 1)


def _image(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A smooth texture with a flat corner (flat windows: NaN scores)."""
    grey = cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), rng.uniform(0.7, 2.5))
    grey[:25, :25] = 100.0
    return grey


def test_line_scores_find_the_shift():
    # A window matched against its own image along a line through it peaks at the point.
    rng = np.random.default_rng(3)
    a = _image(rng, 80, 80)
    point = np.array([[40.0, 41.0]])
    candidates = np.column_stack([np.linspace(35, 45, 41), np.full(41, 41.0)])[None]
    scores = _core.track_ncc_at(a, point, a, candidates, size=11)
    assert int(np.argmax(scores[0])) == 20
    assert abs(scores[0, 20] - 1.0) < 1e-5


def _inside(cameras: list[Camera], x: np.ndarray, masks: list[np.ndarray], min_seen: int) -> np.ndarray:
    return _core.seed_hull_inside(x, np.array([c.R for c in cameras]), np.array([c.t for c in cameras]),
                                  np.array([c.K for c in cameras]), np.array([padded(c.dist) for c in cameras]),
                                  masks, min_seen=min_seen)


def _held(camera: Camera, x: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One camera's (held, seen) through the hull test: held with no count needed, seen
    as the hull of a mask that holds everywhere with one view needed."""
    held = _inside([camera], x, [mask], 0)
    seen = _inside([camera], x, [np.ones_like(mask)], 1)
    return held, seen


@fused_blas
@settings(max_examples=40, deadline=None)
@given(seed=SEEDS, coefficients=st.sampled_from([4, 5, 8, 12]), zero=st.lists(st.booleans(), min_size=12, max_size=12),
       skew=st.booleans())
def test_hull_held_is_the_numpy_projection_and_read(seed, coefficients, zero, skew):
    rng = np.random.default_rng(seed)
    camera = _camera(rng, "c", coefficients, np.array(zero), skew)
    x = np.concatenate([rng.normal(scale=0.6, size=(2000, 3)), rng.normal(scale=8.0, size=(500, 3))])
    mask = rng.uniform(size=(camera.height, camera.width)) < 0.5
    held, seen = _held(camera, x, mask)
    uv, want_seen = _numpy_seen_pixels(camera, x)
    want_held = np.ones(len(x), bool)
    at = np.flatnonzero(want_seen)
    want_held[at] = mask[np.rint(uv[at, 1]).astype(np.intp), np.rint(uv[at, 0]).astype(np.intp)]
    assert held.dtype == seen.dtype == np.bool_
    assert np.array_equal(seen, want_seen)
    assert np.array_equal(held, want_held)
    assert seen.any() and (~seen).any() and (~held).any()


def test_hull_held_rounds_ties_to_even_and_tests_the_edges():
    # Pixels exactly half-way between two (a power-of-two focal length makes them exact):
    # numpy's rint rounds them to even, and the footprint ends half a pixel out.
    K = np.array([[512.0, 0.0, 256.0], [0.0, 512.0, 128.0], [0.0, 0.0, 1.0]])
    camera = Camera("c", K, np.zeros(5), np.eye(3), np.zeros(3), 8, 4)
    u = np.array([0.5, 1.5, 2.5, -0.5, 7.5, 7.49, -0.51, 3.0])
    v = np.array([0.5, 1.5, 2.5, 0.0, 0.0, 3.49, 0.0, 3.5])
    x = np.column_stack([(u - 256) / 512, (v - 128) / 512, np.ones(len(u))])
    mask = np.zeros((4, 8), bool)
    mask[0, 0] = mask[2, 2] = mask[0, 0] = mask[3, 7] = True
    held, seen = _held(camera, x, mask)
    assert list(seen) == [True, True, True, True, False, True, False, False]
    # (0.5, 0.5) -> (0, 0); (1.5, 1.5) -> (2, 2); (2.5, 2.5) -> (2, 2); (-0.5, 0) -> (0, 0); (7.49, 3.49) -> (7, 3).
    assert list(held) == [True, True, True, True, True, True, True, True]
    mask[:] = False
    held, _ = _held(camera, x, mask)
    assert list(held) == [False, False, False, False, True, False, True, True]


@fused_blas
@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, count=st.integers(min_value=1, max_value=7), min_seen=st.integers(min_value=0, max_value=4))
def test_hull_is_every_cameras_numpy_read_and_count(seed, count, min_seen):
    # Several cameras: inside only where every camera that sees the point holds it and at
    # least min_seen see it (the early exit at the first refusal changes no answer);
    # non-finite points are outside.
    rng = np.random.default_rng(seed)
    min_seen = min(min_seen, count)
    cameras = [_camera(rng, f"c{i}", 5, rng.uniform(size=12) < 0.5, bool(i % 2)) for i in range(count)]
    masks = [rng.uniform(size=(c.height, c.width)) < 0.9 for c in cameras]
    x = np.concatenate([rng.normal(scale=0.6, size=(1500, 3)), rng.normal(scale=8.0, size=(300, 3))])
    x[rng.uniform(size=len(x)) < 0.03, rng.integers(0, 3)] = rng.choice([np.nan, np.inf, -np.inf])
    got = _inside(cameras, x, masks, min_seen)
    finite = np.isfinite(x).all(axis=1)
    want = finite.copy()
    seen_by = np.zeros(len(x), int)
    for camera, mask in zip(cameras, masks):
        uv, seen = _numpy_seen_pixels(camera, np.nan_to_num(x))
        at = np.flatnonzero(seen)
        held = np.ones(len(x), bool)
        held[at] = mask[np.rint(uv[at, 1]).astype(np.intp), np.rint(uv[at, 0]).astype(np.intp)]
        want &= held
        seen_by += seen
    want &= seen_by >= min_seen
    assert got.dtype == np.bool_
    assert np.array_equal(got, want)
    assert want.any() and (~want).any()


def test_hull_refuses_mismatched_cameras():
    rng = np.random.default_rng(0)
    camera = _camera(rng, "c", 5, np.zeros(12, bool), False)
    mask = np.ones((camera.height, camera.width), bool)
    x = rng.normal(size=(10, 3))
    with pytest.raises(InvalidInputError):
        _core.seed_hull_inside(x, np.array([camera.R] * 2), np.array([camera.t] * 2), np.array([camera.K] * 2),
                               np.array([padded(camera.dist)] * 2), [mask], min_seen=0)
    with pytest.raises(InvalidInputError):
        _core.seed_hull_inside(x[:, :2].copy(), np.array([camera.R]), np.array([camera.t]), np.array([camera.K]),
                               np.array([padded(camera.dist)]), [mask], min_seen=0)


@settings(max_examples=30, deadline=None)
@given(seed=SEEDS, period=st.sampled_from([0, 13, 23]), noise=st.sampled_from([0.0, 3.0, 10.0]),
       min_correlation=st.sampled_from([0.5, 0.75, 0.9]), peak_pixels=st.sampled_from([None, 2.0]))
def test_decisive_line_scores_decide_seeding_as_the_exact_ones(seed, period, noise, min_correlation, peak_pixels):
    # track_ncc_at(decide=...) leaves at -inf only scores that cannot change seeding's test
    # (benches/README.md, "seedfloor1"): every other score is the exact one to the bit, and the
    # test (seeding._unique_peaks, the code seed_points runs) keeps the same rows and samples.
    # Lines through a shifted, noisy copy; a repeated texture makes rivals along them.
    from elastocap.tracking import seeding

    rng = np.random.default_rng(seed)
    a = _image(rng, 120, 160)
    if period:
        a = np.ascontiguousarray(a[:, np.arange(160) % period])
    shift = rng.integers(-6, 7, 2)
    b = (np.roll(a, (shift[1], shift[0]), axis=(0, 1)) + noise * rng.uniform(-1, 1, a.shape)).astype(np.float32)
    points = rng.uniform([15, 15], [145, 105], (40, 2))
    angle = rng.uniform(0, np.pi, 40)
    step = rng.uniform(0.1, 1.2, 40)
    t = (np.arange(96)[None, :] - 48 + rng.uniform(-40, 40, 40)[:, None]) * step[:, None]
    centre = points + shift + rng.uniform(-1, 1, (40, 2))
    uv = centre[:, None, :] + t[..., None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)[:, None, :]
    exact = _core.track_ncc_at(a, points, b, uv, size=15)
    got = _core.track_ncc_at(a, points, b, uv, size=15, decide=(min_correlation, seeding._UNIQUENESS))
    same = (exact.view(np.int64) == got.view(np.int64)) | (np.isnan(exact) & np.isnan(got))
    assert np.all(same | (got == -np.inf))
    assert (got == -np.inf).any()
    saved = seeding.settings.SEED_PEAK_PIXELS
    try:
        seeding.settings.SEED_PEAK_PIXELS = peak_pixels
        good, best = seeding._unique_peaks(exact, uv, min_correlation)
        good_got, best_got = seeding._unique_peaks(got, uv, min_correlation)
    finally:
        seeding.settings.SEED_PEAK_PIXELS = saved
    assert np.array_equal(good, good_got)
    assert np.array_equal(best[good], best_got[good])


def test_decisive_line_scores_reject_no_real_candidate():
    # On a capture's seeding-like lines most scores are left at -inf, and rows are still kept.
    from elastocap.tracking import seeding

    rng = np.random.default_rng(5)
    a = _image(rng, 120, 160)
    b = np.roll(a, (2, 3), axis=(0, 1))
    points = rng.uniform([20, 20], [140, 100], (60, 2))
    uv = points[:, None, :] + [3.0, 2.0] + np.linspace(-20, 20, 96)[None, :, None] * [1.0, 0.0]
    got = _core.track_ncc_at(a, points, b, uv, size=15, decide=(0.75, seeding._UNIQUENESS))
    good, best = seeding._unique_peaks(got, uv, 0.75)
    assert good.mean() > 0.8
    assert np.all(np.abs(np.take_along_axis(uv, best[:, None, None], 1)[:, 0] - points - [3.0, 2.0]).max(axis=1)[good] < 0.3)
    assert (got == -np.inf).mean() > 0.5
