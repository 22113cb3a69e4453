"""The spatial matches' plane starts batched (issue 15's speed line, branch pyfast1): the
four rays of ``plane_offset_points`` in one call, the start maps of every camera pair into
a target camera from one projection, the distortion's coefficients converted once, and the
frame's images checked once. Each is held to the code it replaced, to the bit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from elastocap._core import InvalidInputError
from elastocap.cameras import distortion
from elastocap.stereo.matching import MatchStatus, checked_image, checked_weights, match_checked
from elastocap.synth.capture import ring_rig
from elastocap.tracking.frame_images import CheckedImages, checked
from elastocap.tracking.views import plane_affine_from, plane_offset_points, spatial_match
from test_track_consistency import _textured_plane


def same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal to the bit (NaN where NaN)."""
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a.view(np.uint8), b.view(np.uint8))


def offset_points_per_shift(camera, uv, points, normals):
    """plane_offset_points as it was: one ``rays`` call per one-pixel shift."""
    out = np.empty((len(uv), 4, 3))
    for j, (e, sign) in enumerate(((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0))):
        shift = np.zeros(2)
        shift[e] = sign
        o, d = camera.rays(uv + shift)
        t = np.einsum("ij,ij->i", points - o, normals) / np.einsum("ij,ij->i", d, normals)
        out[:, j] = o + t[:, None] * d
    return out


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), m=st.integers(0, 70), distorted=st.booleans())
@example(seed=1, m=1, distorted=True)
@example(seed=2, m=2, distorted=True)
@example(seed=3, m=0, distorted=False)
def test_offset_points_in_one_call_equal_the_four_calls(seed: int, m: int, distorted: bool) -> None:
    rng = np.random.default_rng(seed)
    cam = ring_rig(8, width=320, height=240, seed=0).cameras[int(rng.integers(8))]
    if distorted:
        cam = cam.replace(dist=np.array([-0.2, 0.05, 0.001, -0.002, 0.01]))
    uv = rng.uniform(-5, 330, (m, 2))
    points = rng.normal(0, 0.3, (m, 3)) + np.array([0.0, 0.9, 0.0])
    normals = rng.normal(size=(m, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    if m > 3:
        normals[0] = np.nan  # a failed normal
        uv[1] = [1e6, 1e6]  # beyond every ray
    assert same(plane_offset_points(cam, uv, points, normals), offset_points_per_shift(cam, uv, points, normals))


def test_one_row_keeps_its_own_rounding() -> None:
    # Why plane_offset_points keeps the per-shift calls for a single point: numpy's product of
    # one row by a matrix is BLAS's matrix-vector product, which need not round as the
    # matrix-matrix product of two or more rows does. From two rows on, each row's product
    # does not depend on the rows beside it (what the batches rely on).
    rng = np.random.default_rng(7)
    rotation = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    x = rng.normal(size=(500, 3)) * 3
    whole = x @ rotation.T
    for n in (2, 3, 5, 17, 64, 129):
        for start in (0, 1, 7):
            assert same(x[start : start + n] @ rotation.T, whole[start : start + n])


def starts_per_pair(cameras, reference, template_uv, targets, points, normals):
    """spatial_match's start maps as they were built: per camera pair, plane_affine_from
    (two projections), its centre replaced by the target, failed maps the identity."""
    n, c = targets.shape[:2]
    wanted = np.all(np.isfinite(targets), axis=2)
    identity = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    pairs, starts, rows_of = [], [], []
    for r in range(c):
        mine = (reference == r) & wanted.any(axis=1)
        if not mine.any():
            continue
        ends = np.full((n, 4, 3), np.nan)
        ends[mine] = offset_points_per_shift(cameras[r], template_uv[mine], points[mine], normals[mine])
        for k in range(c):
            rows = np.flatnonzero(mine & wanted[:, k])
            if k == r or rows.size == 0:
                continue
            affine = plane_affine_from(cameras[k], ends[rows], points[rows])
            affine[:, :, 2] = targets[rows, k]
            det = affine[:, 0, 0] * affine[:, 1, 1] - affine[:, 0, 1] * affine[:, 1, 0]
            if not (np.isfinite(affine).all() and (det > 0).all()):
                affine[~(np.isfinite(affine).all(axis=(1, 2)) & (det > 0))] = identity
                affine[:, :, 2] = targets[rows, k]
            pairs.append((r, k))
            starts.append(affine)
            rows_of.append(rows)
    return pairs, starts, rows_of


@pytest.mark.parametrize("seed", [0, 1])
def test_plane_started_spatial_match_equals_the_per_pair_starts(seed: int) -> None:
    # Four cameras of a ring around a textured plane; points referenced in every camera (one
    # camera with a single point: its pairs' projections of one row), asked in two or three
    # others; some normals edge-on or missing (their starts the identity). The matches equal
    # those started from the per-pair maps, match by match.
    rig = ring_rig(36, width=320, height=240, seed=0)
    cams = [rig.cameras[i] for i in (0, 1, 5, 6)]
    c = len(cams)
    centre = np.array([0.0, 0.9, 0.0])
    normal = np.array([np.cos(np.radians(46.0)), 0.0, np.sin(np.radians(46.0))])
    images, e1, e2 = _textured_plane(cams, centre, normal, seed=seed)
    rng = np.random.default_rng(seed)
    g = rng.uniform(-0.15, 0.15, (70, 2))
    points = centre + g[:, :1] * e1 + g[:, 1:] * e2
    n = len(points)
    reference = rng.integers(0, c - 1, n)
    reference[0] = c - 1  # the only point referenced in the last camera
    truth = np.stack([cam.project(points)[0] for cam in cams], axis=1)
    template_uv = truth[np.arange(n), reference]
    targets = np.where(rng.random((n, c, 1)) < 0.8, truth + rng.uniform(-0.7, 0.7, (n, c, 2)), np.nan)
    targets[np.arange(n), reference] = np.nan
    normals = np.tile(normal, (n, 1)) + rng.normal(0, 0.1, (n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals[3] = np.cross(normal, [0.0, 1.0, 0.0])  # edge-on to some cameras
    normals[5] = np.nan
    tolerance = 1.5
    kwargs = dict(size=11, min_correlation=0.7, tolerance=tolerance, min_texture=0.5)
    for weights in (None, [np.ones(image.shape, np.float32) for image in images]):
        uv, cov = spatial_match(images, reference, template_uv, targets, cameras=cams, points=points,
                                normals=normals, weights=weights, **kwargs)
        want_uv, want_cov = np.full((n, c, 2), np.nan), np.full((n, c, 2, 2), np.nan)
        pairs, starts, rows_of = starts_per_pair(cams, reference, template_uv, targets, points, normals)
        assert any(rows.size == 1 for rows in rows_of)
        for (r, k), start, rows in zip(pairs, starts, rows_of):
            m = match_checked(checked_image(images[r]), template_uv[rows], [checked_image(images[k])],
                              initial=start[:, None], size=11, min_texture=0.5, max_iterations=20,
                              weights=None if weights is None else checked_weights(weights[r], images[r].shape))
            pos = m.positions[:, 0]
            good = ((m.status[:, 0] == MatchStatus.CONVERGED) & (m.correlation[:, 0] >= 0.7)
                    & (np.linalg.norm(pos - targets[rows, k], axis=1) <= tolerance))
            want_uv[rows[good], k] = pos[good]
            want_cov[rows[good], k] = m.position_covariance()[good]
        assert same(uv, want_uv) and same(cov, want_cov)
        assert np.isfinite(uv[..., 0]).sum() > 0.5 * np.isfinite(targets[..., 0]).sum()


def test_distortion_coefficients_converted_once_per_value() -> None:
    # The cached conversion returns what the conversion returns, for equal arrays the same
    # tuple, for another value another; the distortion is the stacked formula's, to the bit.
    a = np.array([-0.2, 0.05, 0.001, -0.002, 0.01])
    b = a.copy()
    assert distortion._split(a) == tuple(float(x) for x in distortion.padded(a))
    assert distortion._split(a) is distortion._split(b)
    assert distortion._split(np.array([-0.2, 0.05, 0.001, -0.002])) == distortion._split(a[:4])
    assert distortion._split(a)[4] == 0.01 and distortion._split(a[:4])[4] == 0.0
    rng = np.random.default_rng(0)
    ab = rng.normal(0, 0.5, (200, 2))
    ab[3] = np.nan
    k1, k2, p1, p2, k3 = a
    x, y = ab[:, 0], ab[:, 1]
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (0.0 + r2 * (0.0 + r2 * 0.0)))
    want = np.stack([x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + r2 * (0.0 + r2 * 0.0),
                     y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + r2 * (0.0 + r2 * 0.0)], axis=1)
    assert same(distortion.distort(ab, a), want)
    complex_probe = ab[:5] + 1e-20j
    assert distortion.distort(complex_probe, a).dtype == np.complex128


def test_the_frame_images_are_checked_once_and_used_as_they_are() -> None:
    rng = np.random.default_rng(0)
    grey = [rng.uniform(0, 255, (6, 8)).astype(np.float32) for _ in range(3)]
    listed = CheckedImages(grey)
    assert all(checked(listed, k) is grey[k] for k in range(3))
    # A plain list is checked each time, as before.
    assert all(checked(grey, k) is grey[k] for k in range(3))
    bad = grey[1].copy()
    bad[2, 3] = np.nan
    with pytest.raises(InvalidInputError):
        CheckedImages([grey[0], bad])
    with pytest.raises(InvalidInputError):
        checked([grey[0], bad], 1)
    # Other dtypes are converted as checked_image converts them.
    assert checked(CheckedImages([np.zeros((4, 4), np.uint8)]), 0).dtype == np.float32


def test_the_frame_weights_are_checked_once_and_their_shape_still_is() -> None:
    from elastocap.tracking.frame_images import checked_weights_of

    masks = [np.ones((6, 8), np.float32), np.zeros((6, 8), np.float32)]
    listed = CheckedImages(masks)
    assert all(checked_weights_of(listed, k, (6, 8)) is masks[k] for k in range(2))
    assert all(checked_weights_of(masks, k, (6, 8)) is masks[k] for k in range(2))
    # The template's shape is still held to: a listed array of another shape is refused.
    with pytest.raises(InvalidInputError):
        checked_weights_of(listed, 0, (8, 6))
    # Bool masks as checked_weights takes them (converted), listed or not.
    assert checked_weights_of([np.ones((3, 3), bool)], 0, (3, 3)).dtype == np.float32
    nan = masks[0].copy()
    nan[1, 1] = np.nan
    with pytest.raises(InvalidInputError):
        checked_weights_of([nan], 0, (6, 8))


def visible_apart(cameras, masks, points, normals, cloud, where, *, facing=0.0, radius=6.0, gap=12.0):
    """predicted_visible as it was: the asked points and the occluders projected apart."""
    from scipy.spatial import cKDTree

    n, c = where.shape
    out = np.zeros((n, c), bool)
    where = where & np.all(np.isfinite(points), axis=1)[:, None] & np.all(np.isfinite(normals), axis=1)[:, None]
    occluders = cloud[np.isfinite(cloud).all(axis=1)]
    for k, (cam, mask) in enumerate(zip(cameras, masks)):
        rows = np.flatnonzero(where[:, k])
        if rows.size == 0:
            continue
        x = points[rows]
        uv, depth = cam.project(x)
        iu, iv = np.round(uv[:, 0]), np.round(uv[:, 1])
        ok = (depth > 0) & (iu >= 0) & (iv >= 0) & (iu <= mask.shape[1] - 1) & (iv <= mask.shape[0] - 1)
        ok[ok] = mask[iv[ok].astype(np.intp), iu[ok].astype(np.intp)]
        view = cam.center - x
        view /= np.linalg.norm(view, axis=1, keepdims=True)
        ok &= np.einsum("ij,ij->i", view, normals[rows]) > facing
        if len(occluders) and ok.any():
            ouv, odepth = cam.project(occluders)
            front = odepth > 0
            ouv, odepth = ouv[front], odepth[front]
            if len(odepth):
                k_near = min(12, len(odepth))
                dist, near = cKDTree(ouv).query(uv[ok], k=k_near, distance_upper_bound=radius)
                dist, near = dist.reshape(-1, k_near), near.reshape(-1, k_near)
                hit = np.isfinite(dist)
                pixel = depth[ok] / float(cam.K[0, 0])
                nearer = np.where(hit, odepth[np.minimum(near, len(odepth) - 1)], np.inf) < (depth[ok] - gap * pixel)[:, None]
                ok[np.flatnonzero(ok)[nearer.any(axis=1)]] = False
        out[rows[ok], k] = True
    return out


@pytest.mark.parametrize("seed", [3, 4])
def test_visibility_with_the_projections_joined_equals_them_apart(seed: int) -> None:
    # predicted_visible projects a camera's asked points and the occluders together where
    # each part has two rows or more: its answers equal the former separate projections'
    # (every branch: one asked point, one occluder, none).
    from elastocap.tracking.visibility import predicted_visible

    cams = list(ring_rig(8, width=160, height=120, seed=0).cameras)
    rng = np.random.default_rng(seed)
    cloud = rng.normal(0, 0.25, (400, 3)) + np.array([0.0, 0.9, 0.0])
    cloud[::17] = np.nan
    normals = cloud - np.array([0.0, 0.9, 0.0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    masks = [rng.random((cam.height, cam.width)) < 0.9 for cam in cams]
    for asked, occluders in ((400, cloud), (1, cloud), (400, cloud[1:2]), (400, cloud[:0]), (2, cloud[1:3])):
        where = np.zeros((len(cloud), len(cams)), bool)
        where[:asked] = rng.random((asked, len(cams))) < 0.6
        for radius, gap in ((3.0, 2.0), (6.0, 12.0)):
            got = predicted_visible(cams, masks, cloud, normals, occluders, where, radius=radius, gap=gap)
            assert np.array_equal(got, visible_apart(cams, masks, cloud, normals, occluders, where, radius=radius, gap=gap))
            if asked == 400 and len(occluders) > 2:
                assert 0 < got.sum() < where.sum()  # some hidden, some seen


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(1, 60), size=st.sampled_from([7, 15]))
@example(seed=0, n=1, size=15)
@example(seed=1, n=12, size=7)
def test_anchor_mosaics_written_in_place_equal_the_padded_stack(seed: int, n: int, size: int) -> None:
    # The anchors' mosaic of a camera's rows (tiles in row-major order, zeros past the last)
    # equals the former padded stack reshaped and copied, patches and weights alike, and the
    # two are separate arrays (one tile once aliased them).
    from elastocap.tracking.anchors import Anchors

    rng = np.random.default_rng(seed)
    anchors = Anchors(3, size)
    anchors.grow(n + 5)
    anchors.patches[:] = rng.uniform(0, 255, anchors.patches.shape).astype(np.float32)
    anchors.weights[:] = (rng.random(anchors.weights.shape) < 0.8).astype(np.float32)
    rows = np.sort(rng.choice(n + 5, n, replace=False))
    k = int(rng.integers(3))
    mosaic, weighs, centres = anchors._mosaic(rows, k)
    side = anchors.side
    per_row = int(np.ceil(np.sqrt(n)))
    for stored, got in ((anchors.patches, mosaic), (anchors.weights, weighs)):
        tiles = np.zeros((per_row * per_row, side, side), np.float32)
        tiles[:n] = stored[rows, k]
        want = np.array(tiles.reshape(per_row, per_row, side, side).transpose(0, 2, 1, 3)
                        .reshape(per_row * side, per_row * side), copy=True)
        assert same(got, want) and got.flags.c_contiguous
    assert not np.shares_memory(mosaic, weighs)
    empty = anchors._mosaic(np.zeros(0, np.int64), k)
    assert [a.shape for a in empty] == [(0, 0), (0, 0), (0, 2)]
    index = np.arange(n)
    assert same(centres, np.column_stack([(index % per_row) * side + side // 2,
                                          (index // per_row) * side + side // 2]).astype(float))
