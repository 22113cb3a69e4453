"""The seeding's visual-hull test, depth search and texture map, cut for speed
(benches/README.md, "seedframe1", "seednear1", "seedfast1"): they must give what the plain
formulation gives, bit for bit, since the seeds (and so every track) follow from them."""

from __future__ import annotations

import ctypes
import ctypes.util

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from elastocap.cameras import Camera
from elastocap.cameras.distortion import padded
from elastocap.tracking.seeding import _COARSE, _DEPTHS, _hull_depths, _inside_hull, _seen_pixels, _texture

SEEDS = st.integers(min_value=0, max_value=2**32 - 1)


def _numpy_rotation_is_fused() -> bool:
    """True when numpy's ``points @ R.T`` rounds as the fused multiply-add chain
    ``fma(x2, r2, fma(x1, r1, x0 * r0))`` that the core's hull kernels compute (OpenBLAS's
    kernels for x86-64 with FMA do: the machines this is built and tested on). Elsewhere the
    core and numpy differ at rounding level, so the bit-for-bit comparisons with numpy cannot
    hold there; the Rust tests still hold the kernels to their one-at-a-time form."""
    path = ctypes.util.find_library("m")
    if path is None:
        return False
    fma = ctypes.CDLL(path).fma
    fma.restype = ctypes.c_double
    fma.argtypes = [ctypes.c_double] * 3
    rng = np.random.default_rng(0)
    points = rng.normal(size=(257, 3))
    R, _ = cv2.Rodrigues(np.array([0.3, -0.2, 0.5]))
    fused = np.array([[fma(x[2], r[2], fma(x[1], r[1], x[0] * r[0])) for r in R] for x in points])
    return bool(np.array_equal(points @ R.T, fused))


# The comparisons of the core's hull kernels with numpy's projection, bit for bit.
fused_blas = pytest.mark.skipif(not _numpy_rotation_is_fused(),
                                reason="numpy's BLAS does not round the rotation as the core's fused chain")


def _camera(rng: np.random.Generator, name: str, coefficients: int, zero: np.ndarray, skew: bool) -> Camera:
    """A camera 3-5 units from the origin looking roughly at it, with ``coefficients``
    distortion coefficients of moderate size, those flagged in ``zero`` set to 0."""
    fx = rng.uniform(300, 1500)
    K = np.array([[fx, rng.uniform(-0.02, 0.02) * fx if skew else 0.0, rng.uniform(150, 350)],
                  [0.0, fx * rng.uniform(0.9, 1.1), rng.uniform(100, 250)],
                  [0.0, 0.0, 1.0]])
    scale = np.array([0.2, 0.05, 0.01, 0.01, 0.01, 0.05, 0.01, 0.005, 0.002, 0.001, 0.002, 0.001])[:coefficients]
    dist = np.where(zero[:coefficients], 0.0, rng.uniform(-1, 1, coefficients) * scale)
    R, _ = cv2.Rodrigues(rng.normal(scale=0.4, size=3))
    t = np.array([rng.normal(scale=0.2), rng.normal(scale=0.2), rng.uniform(3, 5)])
    return Camera(name, K, dist, R, t, 400, 300)


def _points(rng: np.random.Generator, n: int) -> np.ndarray:
    """Points about the origin, some far off (behind some cameras, outside the images)."""
    near = rng.normal(scale=0.6, size=(n, 3))
    far = rng.normal(scale=8.0, size=(n // 4, 3))
    return np.concatenate([near, far])


@fused_blas
@settings(max_examples=40, deadline=None)
@given(seed=SEEDS, coefficients=st.sampled_from([4, 5, 8, 12]), zero=st.lists(st.booleans(), min_size=12, max_size=12),
       skew=st.booleans())
def test_seen_pixels_are_the_cameras_projection_bit_for_bit(seed, coefficients, zero, skew):
    # The lean projection drops the lens model's zero terms: wherever the camera's own
    # projection is finite its pixels must be the same numbers, and "seen" its footprint test.
    rng = np.random.default_rng(seed)
    camera = _camera(rng, "c", coefficients, np.array(zero), skew)
    x = _points(rng, 400)
    uv, seen = _seen_pixels(camera, x)
    ref, depth = camera.project(x)
    footprint = ((depth > 0) & (ref[:, 0] >= -0.5) & (ref[:, 0] < camera.width - 0.5)
                 & (ref[:, 1] >= -0.5) & (ref[:, 1] < camera.height - 0.5))
    assert np.array_equal(seen, footprint)
    finite = np.isfinite(ref).all(axis=1)
    assert np.array_equal(uv[finite], ref[finite])
    assert seen.any() and (~seen).any()


def _hull_reference(flat: np.ndarray, cam: Camera, cameras: list[Camera], masks: list[np.ndarray]) -> np.ndarray:
    """The visual-hull test written plainly: every point projected into every other camera."""
    finite = np.isfinite(flat).all(axis=1)
    x = np.nan_to_num(flat)
    inside = finite.copy()
    seen_by = np.zeros(len(x), int)
    for other, mask in zip(cameras, masks):
        if other is cam:
            continue
        uv, depth = other.project(x)
        seen = (depth > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] < other.width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] < other.height - 0.5)
        iu = np.clip(np.nan_to_num(uv[:, 0]), -1, other.width).round().astype(int).clip(0, other.width - 1)
        iv = np.clip(np.nan_to_num(uv[:, 1]), -1, other.height).round().astype(int).clip(0, other.height - 1)
        inside &= ~seen | mask[iv, iu]
        seen_by += seen
    return inside & (seen_by >= max(2, (len(cameras) - 1) // 2))


@fused_blas
@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, count=st.integers(min_value=3, max_value=6))
def test_the_hull_test_is_the_plain_one(seed, count):
    # A sphere's silhouettes (so that the hull holds points); the early rejection and the
    # mask read only where seen must not change any answer, NaN rows included.
    rng = np.random.default_rng(seed)
    cameras = [_camera(rng, f"c{i}", 5, rng.uniform(size=12) < 0.5, False) for i in range(count)]
    masks = []
    for camera in cameras:
        centre, _ = camera.project(np.zeros((1, 3)))
        vs, us = np.mgrid[:camera.height, :camera.width]
        masks.append(np.hypot(us - centre[0, 0], vs - centre[0, 1]) < rng.uniform(40, 120))
    flat = _points(rng, 3000)
    flat[rng.uniform(size=len(flat)) < 0.02] = np.nan
    got = _inside_hull(flat, cameras[0], cameras, masks)
    want = _hull_reference(flat, cameras[0], cameras, masks)
    assert np.array_equal(got, want)
    assert want.any() and (~want).any()


@settings(max_examples=20, deadline=None)
@given(seed=SEEDS, size=st.sampled_from([7, 11, 15]))
def test_texture_on_the_masks_box_is_the_whole_images(seed, size):
    # The texture map computed on the mask's bounding box must equal the whole image's
    # where the mask holds (seed_candidates reads it nowhere else).
    rng = np.random.default_rng(seed)
    h, w = 240, 320
    grey = cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), rng.uniform(0.5, 2.0))
    inner = np.zeros((h, w), bool)
    for _ in range(int(rng.integers(1, 4))):
        v, u = rng.integers(0, h), rng.integers(0, w)
        inner[max(0, v - 30):v + 30, max(0, u - 40):u + 40] = True
    got = _texture(grey, inner, size)
    whole = np.sqrt(np.maximum(cv2.cornerMinEigenVal(grey, size, ksize=3), 0)) * 8
    assert got.dtype == whole.dtype
    assert np.array_equal(got[inner], whole[inner])
    assert np.array_equal(_texture(grey, np.zeros((h, w), bool), size), np.zeros((h, w), np.float32))


def _depths_reference(cam: Camera, seeds: np.ndarray, cameras: list[Camera],
                      masks: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The depth search as numpy did it (before "seedfast1"): every coarse sample tested,
    the first run by a cumulative sum, every fine sample tested, then cleared without a run."""
    origins, dirs = cam.rays(seeds)
    dirs = np.nan_to_num(dirs)
    centres = np.array([c.center for c in cameras])
    reach = np.linalg.norm(centres - cam.center, axis=1).max()
    coarse = np.linspace(0.05 * reach, 1.2 * reach, _COARSE)
    step = coarse[1] - coarse[0]
    points = origins[:, None, :] + coarse[None, :, None] * dirs[:, None, :]
    hull = _hull_reference(points.reshape(-1, 3), cam, cameras, masks).reshape(len(seeds), _COARSE)
    first = np.argmax(hull, axis=1)
    after = np.arange(_COARSE)[None, :] >= first[:, None]
    run = hull & after & (np.cumsum(after & ~hull, axis=1) == 0)
    last = _COARSE - 1 - np.argmax(run[:, ::-1], axis=1)
    near = coarse[first] - step
    far = coarse[last] + step
    t = near[:, None] + (far - near)[:, None] * np.linspace(0, 1, _DEPTHS)[None, :]
    fine = origins[:, None, :] + t[..., None] * dirs[:, None, :]
    inside = _hull_reference(fine.reshape(-1, 3), cam, cameras, masks).reshape(len(seeds), _DEPTHS)
    inside &= np.any(hull, axis=1)[:, None]
    return fine, inside


@fused_blas
@settings(max_examples=15, deadline=None)
@given(seed=SEEDS, count=st.integers(min_value=3, max_value=6))
def test_the_depth_search_is_the_plain_one(seed, count):
    # Two balls' silhouettes (a ray can leave the hull and enter it again: only the first
    # run counts); the search must give numpy's samples and answers, rays that miss included.
    rng = np.random.default_rng(seed)
    cameras = []
    for i in range(count):
        # A ring about the origin (the search's depth range is the rig's span).
        near = _camera(rng, f"c{i}", 5, rng.uniform(size=12) < 0.5, False)
        turn, _ = cv2.Rodrigues(np.array([0.0, 2 * np.pi * (i + rng.uniform(-0.1, 0.1)) / count, 0.0]))
        cameras.append(Camera(near.name, near.K, near.dist, near.R @ turn, near.t, near.width, near.height))
    balls = [np.zeros(3), rng.normal(scale=0.8, size=3)]
    masks = []
    for camera in cameras:
        vs, us = np.mgrid[:camera.height, :camera.width]
        mask = np.zeros((camera.height, camera.width), bool)
        for ball, radius in zip(balls, (rng.uniform(40, 120), rng.uniform(20, 60))):
            centre, _ = camera.project(ball[None])
            mask |= np.hypot(us - centre[0, 0], vs - centre[0, 1]) < radius
        masks.append(mask)
    cam = cameras[0]
    aim, _ = cam.project(np.zeros((1, 3)))
    seeds = np.concatenate([np.column_stack([rng.uniform(-20, cam.width + 20, 150), rng.uniform(-20, cam.height + 20, 150)]),
                            aim + rng.normal(scale=40, size=(150, 2))])
    fine, inside = _hull_depths(cam, seeds, cameras, masks)
    want_fine, want_inside = _depths_reference(cam, seeds, cameras, masks)
    assert fine.shape == (len(seeds), _DEPTHS, 3) and inside.shape == (len(seeds), _DEPTHS)
    assert np.array_equal(fine, want_fine)
    assert np.array_equal(inside, want_inside)
    assert want_inside.any(axis=1).any() and (~want_inside.any(axis=1)).any()


def _numpy_seen_pixels(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pixels and "seen" as numpy computed them before "seedfast1" (the reference the
    core's hull kernels are held to): the BLAS rotation in 16,384-row chunks, then
    ``Camera.project``'s lens terms without the zero ones, in its order."""
    n = len(points)
    x = np.empty((n, 3))
    for i in range(0, n, 16384):
        x[i:i + 16384] = points[i:i + 16384] @ camera.R.T + camera.t
    depth = x[:, 2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ab = x[:, :2] / depth[:, None]
        a, b = ab[:, 0], ab[:, 1]
        k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = (float(v) for v in padded(camera.dist))
        if k1 or k2 or k3 or k4 or k5 or k6 or p1 or p2 or s1 or s2 or s3 or s4:
            r2 = a * a + b * b
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            if k4 or k5 or k6:
                radial = radial / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
            a2 = a * radial
            b2 = b * radial
            if p1:
                a2 = a2 + 2 * p1 * a * b
                b2 = b2 + p1 * (r2 + 2 * b * b)
            if p2:
                a2 = a2 + p2 * (r2 + 2 * a * a)
                b2 = b2 + 2 * p2 * a * b
            if s1 or s2:
                a2 = a2 + r2 * (s1 + r2 * s2)
            if s3 or s4:
                b2 = b2 + r2 * (s3 + r2 * s4)
        else:
            a2, b2 = a, b
        K = camera.K
        uv = np.empty((n, 2))
        uv[:, 0] = K[0, 0] * a2 + K[0, 1] * b2 + K[0, 2]
        uv[:, 1] = K[1, 1] * b2 + K[1, 2]
    seen = ((depth > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] < camera.width - 0.5)
            & (uv[:, 1] >= -0.5) & (uv[:, 1] < camera.height - 0.5))
    return uv, seen


@fused_blas
@settings(max_examples=40, deadline=None)
@given(seed=SEEDS, coefficients=st.sampled_from([4, 5, 8, 12]), zero=st.lists(st.booleans(), min_size=12, max_size=12),
       skew=st.booleans())
def test_seen_pixels_are_numpys_bit_for_bit(seed, coefficients, zero, skew):
    # Every row, also those behind the camera, outside the image and at huge distances
    # (the seed loop scores the partner's pixels of all of them): the same numbers and NaNs.
    rng = np.random.default_rng(seed)
    camera = _camera(rng, "c", coefficients, np.array(zero), skew)
    x = np.concatenate([_points(rng, 997), rng.normal(scale=1e6, size=(5, 3))])
    uv, seen = _seen_pixels(camera, x)
    want_uv, want_seen = _numpy_seen_pixels(camera, x)
    assert np.array_equal(uv, want_uv, equal_nan=True)
    assert np.array_equal(seen, want_seen)
