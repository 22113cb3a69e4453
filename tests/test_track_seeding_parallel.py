"""The seeding frame's work moved off the seed loop's thread (benches/README.md, "seedpar1"):
each piece must give the numbers of the numpy code it replaced, bit for bit, since every
seed (and so every track) follows from them.

- ``seed_line_pixels``: the line a partner scores, numpy's gather of the rows' ray samples,
  ``nan_to_num``, ``seed_pixels`` and the -1e6 of the samples outside the hull.
- ``seed_line_peaks``: the best score along the line and the best local maximum away from
  it, numpy's ``where`` / ``argmax`` / padded comparison / masked ``max`` chain.
- ``candidate_maps``: the cover-independent part of a camera's candidates, made in a
  thread beside the loop; candidates from given maps are those made in place, and the
  texture's box (from the rows and columns that hold the eroded mask) is ``np.nonzero``'s.
- ``match_checked(epipolar=)``: the line's least-squares match on images checked once per
  seeding call is ``match_patches``' on the same line."""

from __future__ import annotations

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from test_track_seeding_hull import _camera

from elastocap import InvalidInputError, _core
from elastocap.cameras import Camera
from elastocap.cameras.distortion import padded
from elastocap.stereo import match_patches
from elastocap.stereo.matching import MatchStatus, checked_image, match_checked
from elastocap.tracking import seeding
from elastocap.tracking.seeding import candidate_maps, seed_candidates

SEEDS = st.integers(min_value=0, max_value=2**32 - 1)


def _numpy_line_pixels(camera: Camera, points: np.ndarray, inside: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``seed_points``' lines before "seedpar1"."""
    uv, _ = _core.seed_pixels(np.nan_to_num(points[rows].reshape(-1, 3)), camera.R, camera.t, camera.K,
                              padded(camera.dist), width=camera.width, height=camera.height)
    uv = uv.reshape(len(rows), points.shape[1], 2)
    uv[~inside[rows]] = -1e6
    return uv


@settings(max_examples=40, deadline=None)
@given(seed=SEEDS, m=st.integers(1, 40), d=st.integers(1, 100), t=st.integers(0, 60),
       coefficients=st.sampled_from([4, 5, 8, 12]))
def test_line_pixels_are_the_gathered_cleaned_projection_masked(seed, m, d, t, coefficients):
    rng = np.random.default_rng(seed)
    camera = _camera(rng, "c", coefficients, rng.uniform(size=12) < 0.3, bool(rng.integers(2)))
    points = rng.normal(scale=rng.choice([0.6, 8.0]), size=(m, d, 3))
    # Samples numpy's nan_to_num changes (NaN to 0, infinities to the largest floats).
    odd = rng.uniform(size=points.shape) < 0.05
    points[odd] = rng.choice([np.nan, np.inf, -np.inf], size=int(odd.sum()))
    inside = rng.uniform(size=(m, d)) < 0.7
    rows = rng.integers(0, m, size=t)  # repeated and unordered, as any index array
    got = _core.seed_line_pixels(points, inside, rows, camera.R, camera.t, camera.K, padded(camera.dist),
                                 width=camera.width, height=camera.height)
    want = _numpy_line_pixels(camera, points, inside, rows)
    assert got.shape == (t, d, 2)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(seeding._line_pixels(camera, points, inside, rows), want)


def test_line_pixels_refuse_bad_rows_and_shapes():
    rng = np.random.default_rng(0)
    camera = _camera(rng, "c", 5, np.zeros(12, bool), False)
    points, inside = np.zeros((3, 4, 3)), np.ones((3, 4), bool)
    args = camera.R, camera.t, camera.K, padded(camera.dist)
    for rows in (np.array([3]), np.array([-1])):
        try:
            _core.seed_line_pixels(points, inside, rows, *args, width=camera.width, height=camera.height)
        except InvalidInputError:
            continue
        raise AssertionError(f"rows {rows} accepted")
    try:
        _core.seed_line_pixels(points, inside[:, :3], np.array([0]), *args, width=camera.width, height=camera.height)
    except InvalidInputError:
        pass
    else:
        raise AssertionError("inside of the wrong shape accepted")


def _numpy_peaks(scores: np.ndarray, uv: np.ndarray, width: int,
                 pixels: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``seed_points``' choice along the line before "seedpar1"."""
    scores = np.where(np.isfinite(scores), scores, -np.inf)
    best = np.argmax(scores, axis=1)
    peak = scores[np.arange(len(scores)), best]
    pad = np.pad(scores, ((0, 0), (1, 1)), constant_values=-np.inf)
    local = (scores >= pad[:, :-2]) & (scores >= pad[:, 2:]) & np.isfinite(scores)
    if pixels is None:
        away = np.abs(np.arange(scores.shape[1])[None, :] - best[:, None]) > width
    else:
        offset = uv - uv[np.arange(len(scores)), best][:, None, :]
        away = np.hypot(offset[..., 0], offset[..., 1]) > pixels
    second = np.where(local & away, scores, -np.inf).max(axis=1)
    return best, peak, second


@settings(max_examples=60, deadline=None)
@given(seed=SEEDS, t=st.integers(0, 200), d=st.integers(1, 100), width=st.integers(0, 8),
       levels=st.sampled_from([3, 10, 1000, 0]), pixels=st.sampled_from([None, 0.5, 2.0, 7.0]))
def test_line_peaks_are_numpys_chain(seed, t, d, width, levels, pixels):
    rng = np.random.default_rng(seed)
    scores = rng.uniform(-1, 1, size=(t, d))
    if levels:
        scores = np.round(scores * levels) / levels  # ties and plateaus
    odd = rng.uniform(size=scores.shape) < rng.choice([0.0, 0.1, 0.6])
    scores[odd] = rng.choice([np.nan, np.inf, -np.inf], size=int(odd.sum()))
    scores[rng.uniform(size=t) < 0.05] = np.nan  # lines scored nowhere
    # Pixels along each line, some samples far outside (-1e6, as the lines have them), and
    # offsets on a 0.5 px grid so that some lie exactly at the threshold.
    uv = np.cumsum(np.round(rng.normal(scale=1.0, size=(t, d, 2)) * 2) / 2, axis=1)
    uv[rng.uniform(size=(t, d)) < 0.1] = -1e6
    best, peak, second = _core.seed_line_peaks(scores, width=width, uv=uv if pixels is not None else None,
                                               pixels=pixels)
    want = _numpy_peaks(scores, uv, width, pixels)
    assert best.dtype == np.int64
    np.testing.assert_array_equal(best, want[0])
    np.testing.assert_array_equal(peak, want[1])
    np.testing.assert_array_equal(second, want[2])


def test_line_peaks_need_uv_for_pixels():
    try:
        _core.seed_line_peaks(np.zeros((2, 5)), width=3, pixels=1.0)
    except InvalidInputError:
        return
    raise AssertionError("pixels without uv accepted")


def _blobs(rng: np.random.Generator, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """A mask of a few ellipses and thin bars (regions the cells miss) and a texture with
    flat parts (under the texture floor)."""
    mask = np.zeros((h, w), np.uint8)
    for _ in range(rng.integers(0, 6)):
        centre = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        axes = (int(rng.integers(2, w // 3)), int(rng.integers(2, h // 3)))
        cv2.ellipse(mask, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    for _ in range(rng.integers(0, 3)):
        v, u = int(rng.integers(0, h - 12)), int(rng.integers(0, w - 40))
        mask[v:v + int(rng.integers(5, 12)), u:u + 40] = 1
    grey = cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), 1.2)
    grey[: h // 3] = 90.0
    return mask > 0, grey


def _texture_box_reference(grey: np.ndarray, inner: np.ndarray, size: int) -> np.ndarray:
    """``_texture`` before "seedpar1": its box from ``np.nonzero``."""
    texture = np.zeros(grey.shape, np.float32)
    vs, us = np.nonzero(inner)
    if vs.size == 0:
        return texture
    pad = size + 4
    v0, v1 = max(0, int(vs.min()) - pad), min(grey.shape[0], int(vs.max()) + pad + 1)
    u0, u1 = max(0, int(us.min()) - pad), min(grey.shape[1], int(us.max()) + pad + 1)
    box = np.ascontiguousarray(grey[v0:v1, u0:u1])
    texture[v0:v1, u0:u1] = np.sqrt(np.maximum(cv2.cornerMinEigenVal(box, size, ksize=3), 0)) * 8
    return texture


@settings(max_examples=40, deadline=None)
@given(seed=SEEDS, spacing=st.integers(3, 8), size=st.sampled_from([7, 11, 15]), bare=st.integers(0, 2),
       margin=st.sampled_from([None, 3]), covered=st.integers(0, 300))
def test_candidates_from_given_maps_are_those_made_in_place(seed, spacing, size, bare, margin, covered):
    rng = np.random.default_rng(seed)
    h, w = 90, 130
    mask, grey = _blobs(rng, h, w)
    cover = np.column_stack([rng.uniform(-5, w + 5, covered), rng.uniform(-5, h + 5, covered)])
    cover[rng.uniform(size=covered) < 0.1] = np.nan
    options = dict(spacing=spacing, size=size, min_texture=2.0, margin=margin)
    alone = seed_candidates(mask, grey, cover, bare=bare, **options)
    for distance in (False, True):
        maps = candidate_maps(mask, grey, distance=distance, **options)
        assert (maps.distance is not None) == distance
        np.testing.assert_array_equal(seed_candidates(mask, grey, cover, bare=bare, maps=maps, **options), alone)
        np.testing.assert_array_equal(seeding._texture(grey, maps.inner, size),
                                      _texture_box_reference(grey, maps.inner, size))


@settings(max_examples=15, deadline=None)
@given(seed=SEEDS, n=st.integers(1, 30), shaped=st.booleans())
def test_checked_match_on_a_line_is_match_patches(seed, n, shaped):
    # The seeding's least-squares match on the epipolar line from images checked once
    # (match_checked(epipolar=)) gives match_patches' every field, bit for bit.
    rng = np.random.default_rng(seed)
    template = cv2.GaussianBlur(rng.uniform(0, 255, (120, 160)).astype(np.float32), (0, 0), 1.5)
    shift = rng.uniform(-2, 2, 2)
    search = cv2.warpAffine(template, np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]]), (160, 120),
                            flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    points = np.column_stack([rng.uniform(15, 145, n), rng.uniform(15, 105, n)])
    initial = points + shift + rng.normal(scale=0.7, size=(n, 2))
    # Lines through the true match, some tilted, (a, b, c) with a u + b v + c = 0.
    angle = rng.uniform(0, np.pi, n)
    a, b = np.sin(angle), -np.cos(angle)
    true = points + shift
    line = np.column_stack([a, b, -(a * true[:, 0] + b * true[:, 1])])
    options = dict(size=11, min_texture=1.0, max_iterations=20)
    want = match_patches(template, points, [search], initial=initial[:, None, :], epipolar=line[:, None, :], **options)
    got = match_checked(checked_image(template), points, [checked_image(search)], initial=initial[:, None, :],
                        epipolar=line[:, None, :] if shaped else line, **options)
    for field in ("status", "positions", "affine", "gain", "offset", "sigma0", "covariance", "correlation",
                  "iterations"):
        np.testing.assert_array_equal(getattr(got, field), getattr(want, field), err_msg=field)
    assert (want.status[:, 0] == MatchStatus.CONVERGED).any()
