"""The spatial matches of a frame in one core call (``match_checked_pairs``) against the
per-camera-pair calls they replace (``match_checked``): the same patches give the same
bits, with and without template weights, and ``spatial_match`` built on the batch returns
what its former per-pair loop returned.

Scenes: four "cameras" see one procedural texture under their own affine maps (gain,
offset, noise), so matches across pairs converge; far starts, flat corners and points at
the border fail with their statuses, and both kinds are compared."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from elastocap import InvalidInputError
from elastocap.stereo.matching import MatchStatus, checked_image, checked_weights, match_checked, match_checked_pairs
from elastocap.tracking.views import spatial_match

W, H, C = 96, 72, 4


def scene(seed: int) -> tuple[list[np.ndarray], list[np.ndarray | None], np.ndarray]:
    """C images (H, W) of one texture under per-camera affine maps, a flat band on the
    right (low texture); weights for cameras 0 and 2 (a soft disc, a half-plane), none for
    1 and 3; the maps (C, 2, 3) from texture to pixels."""
    rng = np.random.default_rng(seed)
    k = 16
    angle = rng.uniform(0, 2 * np.pi, k)
    frequency = rng.uniform(2 * np.pi / 30, 2 * np.pi / 8, k)
    phase = rng.uniform(0, 2 * np.pi, k)
    w = np.stack([frequency * np.cos(angle), frequency * np.sin(angle)], axis=1)
    v, u = np.mgrid[0:H, 0:W].astype(float)
    images, maps = [], []
    for _ in range(C):
        a = np.eye(2) + rng.uniform(-0.08, 0.08, (2, 2))
        t = rng.uniform(-4, 4, 2)
        inv = np.linalg.inv(a)
        x = inv[0, 0] * (u - t[0]) + inv[0, 1] * (v - t[1])
        y = inv[1, 0] * (u - t[0]) + inv[1, 1] * (v - t[1])
        grey = 128 + rng.uniform(0.8, 1.2) * 12 * np.sin(x[..., None] * w[:, 0] + y[..., None] * w[:, 1] + phase).sum(-1)
        grey[:, W - 12:] = 128.0
        images.append((grey + rng.normal(0, 1.0, grey.shape)).astype(np.float32))
        maps.append(np.column_stack([a, t]))
    disc = np.clip(1 - np.hypot(u - W / 2, v - H / 2) / (W / 2), 0, 1).astype(np.float32)
    half = (u < 0.6 * W).astype(np.float32)
    weights: list[np.ndarray | None] = [disc, None, half, None]
    return images, weights, np.array(maps)


def patches(seed: int, n: int, maps: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random (reference, target) pairs, points (some at or beyond the border) and start maps
    (the true map's neighbourhood, some far off)."""
    rng = np.random.default_rng(seed + 1)
    r = rng.integers(0, C, n)
    k = (r + rng.integers(1, C, n)) % C
    points = np.column_stack([rng.uniform(-2, W + 2, n), rng.uniform(-2, H + 2, n)])
    # The point's texture coordinate, then its true position in the target.
    inv = np.linalg.inv(maps[r, :, :2])
    x = np.einsum("nij,nj->ni", inv, points - maps[r, :, 2])
    true = np.einsum("nij,nj->ni", maps[k, :, :2], x) + maps[k, :, 2]
    spread = np.where(rng.random(n) < 0.2, 6.0, 1.5)[:, None]
    starts = np.zeros((n, 2, 3))
    starts[:, :, :2] = np.eye(2) + rng.uniform(-0.1, 0.1, (n, 2, 2))
    starts[:, :, 2] = true + rng.uniform(-1, 1, (n, 2)) * spread
    return np.column_stack([r, k]), points, starts


def shared_patches(seed: int, n: int, maps: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` points, each matched from its reference camera into every other camera (as
    re-acquisition and confirmation ask), its rows spread through the batch: the batch
    samples each point's template once for its targets."""
    rng = np.random.default_rng(seed + 2)
    r0 = rng.integers(0, C, n)
    p0 = np.column_stack([rng.uniform(-2, W + 2, n), rng.uniform(-2, H + 2, n)])
    r = np.repeat(r0, C - 1)
    k = (r + np.tile(np.arange(1, C), n)) % C
    points = np.repeat(p0, C - 1, axis=0)
    inv = np.linalg.inv(maps[r, :, :2])
    x = np.einsum("nij,nj->ni", inv, points - maps[r, :, 2])
    true = np.einsum("nij,nj->ni", maps[k, :, :2], x) + maps[k, :, 2]
    starts = np.zeros((len(r), 2, 3))
    starts[:, :, :2] = np.eye(2) + rng.uniform(-0.1, 0.1, (len(r), 2, 2))
    starts[:, :, 2] = true + rng.uniform(-1.5, 1.5, (len(r), 2))
    order = rng.permutation(len(r))
    return np.column_stack([r, k])[order], points[order], starts[order]


def same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal to the bit (NaN where NaN)."""
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a.view(np.uint8), b.view(np.uint8))


@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 2**31), size=st.sampled_from([7, 11]), weighted=st.booleans(),
       n=st.integers(1, 120), shared=st.booleans())
@example(seed=5, size=11, weighted=True, n=90, shared=True)
@example(seed=6, size=7, weighted=False, n=90, shared=True)
def test_the_batch_equals_the_per_pair_calls_to_the_bit(seed: int, size: int, weighted: bool, n: int,
                                                          shared: bool) -> None:
    images, weights, maps = scene(seed)
    # Shared: each point into every other camera (one template for its targets).
    pairs, points, starts = shared_patches(seed, (n + 2) // 3, maps) if shared else patches(seed, n, maps)
    n = len(points)
    checked = [checked_image(image) for image in images]
    checked_w = [None if w is None else checked_weights(w, image.shape) for w, image in zip(weights, images)]
    batch = match_checked_pairs(checked, pairs, points, starts, size=size, min_texture=0.5, max_iterations=20,
                                weights=checked_w if weighted else None)
    seen = set()
    for r, k in {tuple(p) for p in pairs.tolist()}:
        rows = np.flatnonzero((pairs[:, 0] == r) & (pairs[:, 1] == k))
        one = match_checked(checked[r], points[rows], [checked[k]], initial=starts[rows][:, None], size=size,
                            min_texture=0.5, max_iterations=20, weights=checked_w[r] if weighted else None)
        for field in ("status", "positions", "affine", "gain", "offset", "sigma0", "covariance", "correlation",
                      "iterations"):
            assert same(getattr(batch, field)[rows], getattr(one, field)), (field, r, k)
        assert same(batch.position_covariance()[rows], one.position_covariance())
        seen.update(one.status[:, 0].tolist())
    if n >= 60:
        # The comparison covers converged and failed matches alike.
        assert MatchStatus.CONVERGED in seen and len(seen) >= 2, seen


@pytest.mark.parametrize("seed", [3, 4])
def test_spatial_match_returns_what_its_per_pair_loop_returned(seed: int) -> None:
    images, weights, maps = scene(seed)
    n = 150
    pairs, points, starts = patches(seed, n, maps)
    rng = np.random.default_rng(seed)
    reference = pairs[:, 0]
    # Targets: the true positions in two or three other cameras (NaN elsewhere).
    inv = np.linalg.inv(maps[reference, :, :2])
    x = np.einsum("nij,nj->ni", inv, points - maps[reference, :, 2])
    targets = np.full((n, C, 2), np.nan)
    for k in range(C):
        asked = (k != reference) & (rng.random(n) < 0.7)
        true = x @ maps[k, :, :2].T + maps[k, :, 2]
        targets[asked, k] = true[asked] + rng.uniform(-1, 1, (int(asked.sum()), 2))
    tolerance = rng.uniform(0.5, 2.0, n)
    kwargs = dict(size=11, min_correlation=0.8, tolerance=tolerance, min_texture=0.5)
    for w in (None, [w if w is not None else np.ones((H, W), np.float32) for w in weights]):
        uv, cov = spatial_match(images, reference, points, targets, weights=w, **kwargs)
        # The former loop: one call per camera pair, the same gate.
        want_uv, want_cov = np.full((n, C, 2), np.nan), np.full((n, C, 2, 2), np.nan)
        for r in range(C):
            for k in range(C):
                rows = np.flatnonzero((reference == r) & np.isfinite(targets[:, k, 0]))
                if k == r or rows.size == 0:
                    continue
                m = match_checked(checked_image(images[r]), points[rows], [checked_image(images[k])],
                                  initial=targets[rows, k][:, None, :], size=11, min_texture=0.5, max_iterations=20,
                                  weights=None if w is None else checked_weights(w[r], images[r].shape))
                pos = m.positions[:, 0]
                good = ((m.status[:, 0] == MatchStatus.CONVERGED) & (m.correlation[:, 0] >= 0.8)
                        & (np.linalg.norm(pos - targets[rows, k], axis=1) <= tolerance[rows]))
                want_uv[rows[good], k] = pos[good]
                want_cov[rows[good], k] = m.position_covariance()[good]
        assert same(uv, want_uv) and same(cov, want_cov)
        assert np.isfinite(uv[..., 0]).sum() > n // 2  # most asked views found


def test_the_batch_refuses_cameras_it_was_not_given() -> None:
    images, _, _ = scene(0)
    checked: list[np.ndarray | None] = [checked_image(images[0]), None]
    start = np.array([[[1.0, 0, 40], [0, 1.0, 30]]])
    for pairs in ([[0, 1]], [[0, 2]], [[-1, 0]]):
        with pytest.raises(InvalidInputError):
            match_checked_pairs(checked, np.array(pairs), np.array([[40.0, 30.0]]), start, size=11, min_texture=0.0,
                                max_iterations=20)
    flipped = np.array([[[-1.0, 0, 40], [0, 1.0, 30]]])
    with pytest.raises(InvalidInputError):
        match_checked_pairs(checked, np.array([[0, 0]]), np.array([[40.0, 30.0]]), flipped, size=11, min_texture=0.0,
                            max_iterations=20)
    # No patches: empty results.
    empty = match_checked_pairs(checked, np.zeros((0, 2), np.int64), np.zeros((0, 2)), np.zeros((0, 2, 3)), size=11,
                                min_texture=0.0, max_iterations=20)
    assert empty.status.shape == (0, 1) and empty.covariance.shape == (0, 8, 8)


@pytest.mark.parametrize("seed", [5, 6])
def test_the_anchors_batched_correction_equals_one_match_per_camera(seed: int) -> None:
    """``Anchors.correct`` / ``rescue`` (affine, the default) match every camera's mosaic in
    one call; the former loop matched camera by camera with ``match_patches``."""
    from elastocap.stereo import match_patches
    from elastocap.tracking.anchors import Anchors

    images, weights, maps = scene(seed)
    rng = np.random.default_rng(seed)
    n = 80
    x = np.column_stack([rng.uniform(15, W - 15, n), rng.uniform(12, H - 12, n)])
    uv = np.einsum("cij,nj->nci", maps[:, :, :2], x) + maps[:, :, 2]
    held = rng.random((n, C)) < 0.7
    anchors = Anchors(C, 11)
    masks = [w if w is not None else np.ones((H, W), np.float32) for w in weights]
    anchors.cut(images, uv, held, 0, weights=masks)
    # The next frame: the images a little brighter, the tracked positions a little off.
    later = [image * np.float32(1.05) + np.float32(3.0) for image in images]
    tracked = np.where(held[..., None], uv + rng.uniform(-0.8, 0.8, uv.shape), np.nan)
    got, recut = anchors.correct(later, tracked, min_correlation=0.8, reach=2.0, min_texture=0.5)
    got_pos, got_cov = anchors.rescue(later, tracked, held, min_correlation=0.8, reach=2.0, min_texture=0.5)
    want = tracked.copy()
    want_cov = np.full((n, C, 2, 2), np.nan)
    good = np.zeros((n, C), bool)
    for k in range(C):
        rows = np.flatnonzero(held[:, k])
        mosaic, weighs, centres = anchors._mosaic(rows, k)
        m = match_patches(mosaic, centres, [later[k]], initial=tracked[rows, k][:, None, :], size=11, min_texture=0.5,
                          max_iterations=15, max_shift=2.0, weights=weighs)
        pos = m.positions[:, 0]
        ok = ((m.status[:, 0] == MatchStatus.CONVERGED) & (m.correlation[:, 0] >= 0.8)
              & (np.linalg.norm(pos - tracked[rows, k], axis=1) <= 2.0))
        want[rows[ok], k] = pos[ok]
        want_cov[rows[ok], k] = m.covariance[ok, :2, :2]
        good[rows[ok], k] = True
    assert same(got, want) and same(recut, held & ~good)
    assert same(got_pos, np.where(good[..., None], want, np.nan))
    assert same(got_cov, np.where(good[..., None, None], want_cov, np.nan))
    assert good.sum() > held.sum() // 2  # most anchors still match
