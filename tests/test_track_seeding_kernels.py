"""The seeding's Rust kernels (benches/README.md, "seednear1"): the hull test's pixel and mask
read (``seed_hull_held``) must give the numbers of the code it replaces, bit for bit: every
seed (and so every track) follows from it. The correlation along a seed's line is
``track_ncc_at``'s (its grouped scoring is checked against one candidate at a time in
``rust/track/ncc_at_tests.rs``); here, that it finds the shift on a seed's line."""

from __future__ import annotations

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from test_track_seeding_hull import _camera

from elastocap import _core
from elastocap.cameras import Camera
from elastocap.cameras.distortion import padded
from elastocap.tracking.seeding import _camera_frame, _seen_pixels

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


def _held(camera: Camera, x: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return _core.seed_hull_held(_camera_frame(camera, x), np.ascontiguousarray(camera.K, dtype=float),
                                np.ascontiguousarray(padded(camera.dist), dtype=float), mask)


@settings(max_examples=40, deadline=None)
@given(seed=SEEDS, coefficients=st.sampled_from([4, 5, 8, 12]), zero=st.lists(st.booleans(), min_size=12, max_size=12),
       skew=st.booleans())
def test_hull_held_is_the_numpy_projection_and_read(seed, coefficients, zero, skew):
    rng = np.random.default_rng(seed)
    camera = _camera(rng, "c", coefficients, np.array(zero), skew)
    x = np.concatenate([rng.normal(scale=0.6, size=(2000, 3)), rng.normal(scale=8.0, size=(500, 3))])
    mask = rng.uniform(size=(camera.height, camera.width)) < 0.5
    held, seen = _held(camera, x, mask)
    uv, want_seen = _seen_pixels(camera, x)
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
