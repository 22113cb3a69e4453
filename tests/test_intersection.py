"""Forward intersection: exactness against OpenCV, precision against the N-view linear
method, covariance calibration, blunder rejection, bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from elastocap import InvalidInputError
from elastocap.cameras import Camera
from elastocap.stereo import Intersection, intersect, match_observations

DISTORTION = [-0.25, 0.08, 0.0015, -0.002, -0.01]


def _camera(i: int, yaw: float, *, skew: float = 0.0, dist: list[float] | None = None) -> Camera:
    """A camera 5 units from the origin looking at it, rolled a little, with skew."""
    R = cv2.Rodrigues(np.array([0.03 * i, yaw, 0.05 * i]))[0]
    centre = np.array([-5 * np.sin(yaw), 0.2 * i, -5 * np.cos(yaw)])
    K = np.array([[810.0, skew, 330.0], [0.0, 790.0, 245.0], [0.0, 0.0, 1.0]])
    return Camera(f"c{i}", K, dist, R, -R @ centre, 640, 480)


def _rig(count: int, *, skew: float = 2.5, dist: list[float] | None = DISTORTION) -> list[Camera]:
    return [_camera(i, 0.12 * i - 0.25, skew=skew, dist=dist) for i in range(count)]


def _dlt(cameras: list[Camera], uv: np.ndarray) -> np.ndarray:
    """N-view linear triangulation (Hartley & Zisserman 12.2) on undistorted normalised
    coordinates: the SVD null vector of the stacked cross-product rows."""
    rows = []
    for k, cam in enumerate(cameras):
        _, d = cam.rays(uv[:, k])
        ab = (d @ cam.R.T)[:, :2] / (d @ cam.R.T)[:, 2:]
        P = np.hstack([cam.R, cam.t[:, None]])
        rows.append(ab[:, 0:1] * P[2] - P[0])
        rows.append(ab[:, 1:2] * P[2] - P[1])
    A = np.stack(rows, axis=1)
    _, _, vt = np.linalg.svd(A)
    h = vt[:, -1]
    return h[:, :3] / h[:, 3:]


def test_two_noise_free_views_equal_cv2_triangulate_points() -> None:
    rng = np.random.default_rng(3)
    cams = _rig(2, skew=4.0, dist=None)
    X = rng.uniform(-1, 1, (200, 3))
    uv = np.stack([c.project(X)[0] for c in cams], axis=1)
    result = intersect(cams, uv)
    h = cv2.triangulatePoints(cams[0].projection_matrix, cams[1].projection_matrix, uv[:, 0].T.copy(), uv[:, 1].T.copy())
    peer = (h[:3] / h[3]).T
    assert result.valid.all()
    np.testing.assert_allclose(result.points, peer, rtol=0, atol=1e-9)
    np.testing.assert_allclose(result.residuals, 0, atol=1e-9)


def test_noise_free_views_with_distortion_and_skew_meet_at_the_point() -> None:
    rng = np.random.default_rng(4)
    cams = _rig(4)
    X = rng.uniform(-1, 1, (100, 3))
    uv = np.stack([c.project(X)[0] for c in cams], axis=1)
    result = intersect(cams, uv)
    np.testing.assert_allclose(result.points, X, atol=1e-9)


@pytest.mark.parametrize("views", [3, 4, 5])
def test_noisy_views_beat_the_n_view_linear_method(views: int) -> None:
    # Seeds 10.. were used while writing; the figure asserted is a plain inequality.
    rng = np.random.default_rng(100 + views)
    cams = _rig(views)
    X = rng.uniform(-1, 1, (400, 3))
    uv = np.stack([c.project(X)[0] for c in cams], axis=1)
    sigma = rng.uniform(0.2, 2.0, views)
    noisy = uv + rng.normal(size=uv.shape) * sigma[None, :, None]
    cov = np.broadcast_to(np.diag(np.repeat(sigma**2, 2)), (len(X), 2 * views, 2 * views))
    ours = intersect(cams, noisy, covariance=cov, reject=False).points
    peer = _dlt(cams, noisy)
    rms = lambda e: float(np.sqrt(np.mean(np.sum(e**2, axis=1))))  # noqa: E731
    assert rms(ours - X) < 0.95 * rms(peer - X)


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**31), views=st.integers(2, 5))
def test_normalised_errors_have_unit_variance_with_correlated_observations(seed: int, views: int) -> None:
    rng = np.random.default_rng(seed)
    cams = _rig(views)
    n = 600
    X = rng.uniform(-1, 1, (n, 3))
    uv = np.stack([c.project(X)[0] for c in cams], axis=1)
    # A joint covariance with cross terms between views, different per point.
    m = 2 * views
    L = rng.normal(size=(n, m, m)) * 0.3 + np.eye(m) * rng.uniform(0.3, 1.2, (n, 1, m))
    cov = L @ np.swapaxes(L, 1, 2)
    noise = np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=(n, m)))
    result = intersect(cams, uv + noise.reshape(n, views, 2), covariance=cov, reject=False)
    e = result.points - X
    chi2 = np.einsum("ni,nij,nj->n", e, np.linalg.inv(result.covariance), e)
    # chi-square with 3 degrees of freedom: mean 3, standard error sqrt(6 / n) = 0.1.
    assert abs(chi2.mean() - 3) < 0.45
    if views >= 3:
        assert abs(np.nanmean(result.sigma0**2) - 1) < 0.25


def test_blunders_are_rejected_by_normalised_residuals() -> None:
    rng = np.random.default_rng(7)
    cams = _rig(5)
    n = 500
    X = rng.uniform(-1, 1, (n, 3))
    uv = np.stack([c.project(X)[0] for c in cams], axis=1)
    noisy = uv + rng.normal(size=uv.shape) * 0.5
    blunder = rng.random((n, 5)) < 0.06
    blunder[blunder.sum(axis=1) > 1] = False
    direction = rng.normal(size=(n, 5, 2))
    direction /= np.linalg.norm(direction, axis=2, keepdims=True)
    noisy += blunder[..., None] * 15 * direction
    result = intersect(cams, noisy, sigma=0.5)
    rejected = ~result.used
    assert (rejected & blunder).sum() >= 0.9 * blunder.sum()
    assert (rejected & ~blunder).sum() <= 0.01 * (~blunder).sum()
    kept = intersect(cams, noisy, sigma=0.5, reject=False)
    err = lambda r: np.sqrt(np.mean(np.sum((r.points - X) ** 2, axis=1)))  # noqa: E731
    assert err(result) < 0.5 * err(kept)


def test_views_missing_or_failed() -> None:
    rng = np.random.default_rng(8)
    cams = _rig(3)
    X = rng.uniform(-1, 1, (4, 3))
    uv = np.stack([c.project(X)[0] for c in cams], axis=1)
    uv[0, 1:] = np.nan  # one view only: no point
    uv[1, 2] = np.nan  # two views: fine
    cov = np.broadcast_to(np.eye(6), (4, 6, 6)).copy()
    cov[2, 4:, 4:] = np.nan  # a failed match: its view is ignored
    result = intersect(cams, uv, covariance=cov)
    assert isinstance(result, Intersection)
    assert result.valid.tolist() == [False, True, True, True]
    assert np.isnan(result.points[0]).all()
    assert result.used[1].tolist() == [True, True, False] and result.used[2].tolist() == [True, True, False]
    np.testing.assert_allclose(result.points[1:], X[1:], atol=1e-9)


def test_match_observations_put_the_template_first() -> None:
    tp = np.array([[10.0, 20.0], [30.0, 40.0]])
    pos = np.array([[[11.0, 21.0]], [[31.0, 41.0]]])
    pc = np.array([np.eye(2) * 0.01, np.eye(2) * 0.04])
    uv, cov = match_observations(tp, pos, pc)
    assert uv.shape == (2, 2, 2) and cov.shape == (2, 4, 4)
    np.testing.assert_array_equal(uv[:, 0], tp)
    np.testing.assert_allclose(cov[:, 0, 0], [1e-8, 4e-8])
    np.testing.assert_array_equal(cov[:, 2:, 2:], pc)


def test_bad_input() -> None:
    cams = _rig(2)
    good = np.zeros((3, 2, 2))
    with pytest.raises(InvalidInputError, match="cameras"):
        intersect(cams[:1], good[:, :1])
    with pytest.raises(InvalidInputError, match="uv"):
        intersect(cams, np.zeros((3, 3, 2)))
    with pytest.raises(InvalidInputError, match="uv"):
        intersect(cams, np.full((3, 2, 2), np.inf))
    with pytest.raises(InvalidInputError, match="covariance"):
        intersect(cams, good, covariance=np.zeros((3, 3, 3)))
    with pytest.raises(InvalidInputError, match="critical"):
        intersect(cams, good, critical=-1)
    with pytest.raises(InvalidInputError, match="cameras"):
        intersect([cams[0], "not a camera"], good)  # type: ignore[list-item]


@given(st.integers(0, 2**32 - 1), st.floats(-8.0, -1.0), st.floats(0.0, 5.0))
@settings(max_examples=60, deadline=None)
def test_the_covariance_is_positive_definite_however_near_parallel_the_rays(seed: int, baseline: float,
                                                                           far: float) -> None:
    # Two cameras 10^baseline units apart looking at points up to 10^far units away: the
    # normal matrix is near singular along the rays. Its plain inverse came out indefinite
    # in floating point (a third of such matrices at 1e-9..1e-2 rad between the rays); the
    # covariance must be symmetric positive definite wherever it is given, and its weak
    # direction the rays'.
    rng = np.random.default_rng(seed)
    b = 10.0**baseline
    cams = [Camera(f"c{i}", np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]]), None, np.eye(3),
                   -np.array([b * i, 0.0, 0.0]), 640, 480) for i in range(2)]
    depth = 5.0 * 10.0 ** rng.uniform(0, far, 20)
    X = np.column_stack([rng.uniform(-0.2, 0.2, 20) * depth, rng.uniform(-0.2, 0.2, 20) * depth, depth])
    uv = np.stack([c.project(X)[0] for c in cams], axis=1) + rng.normal(0, 0.3, (20, 2, 2))
    a = rng.normal(size=(20, 4, 4))
    cov = np.einsum("nij,nkj->nik", a, a) * 0.05 + 0.01 * np.eye(4)
    result = intersect(cams, uv, covariance=cov, reject=False)
    c = result.covariance
    fin = np.isfinite(c).all(axis=(1, 2))
    assert fin.any()
    np.testing.assert_array_equal(c[fin], c[fin].transpose(0, 2, 1))
    w, v = np.linalg.eigh(c[fin])
    assert (w[:, 0] > 0).all()
    ray = X[fin] / np.linalg.norm(X[fin], axis=1, keepdims=True)
    assert np.median(np.abs(np.einsum("ni,ni->n", v[:, :, -1], ray))) > 0.9


def _ring(count: int) -> list[Camera]:
    """Cameras on an arc 5 units from the origin, all looking at it (0.25 rad apart), with
    distortion and skew."""
    cams = []
    for i in range(count):
        yaw = 0.25 * i - 0.125 * (count - 1)
        R = cv2.Rodrigues(np.array([0.0, -yaw, 0.02 * i]))[0]
        centre = np.array([-5 * np.sin(yaw), 0.0, -5 * np.cos(yaw)])
        K = np.array([[810.0, 2.5, 330.0], [0.0, 790.0, 245.0], [0.0, 0.0, 1.0]])
        cams.append(Camera(f"r{i}", K, DISTORTION, R, -R @ centre, 640, 480))
    return cams


def _per_view_as_joint(cov: np.ndarray) -> np.ndarray:
    """(N, C, 2, 2) per-view covariances as the (N, 2C, 2C) joint matrix, zero between views."""
    n, c = cov.shape[:2]
    full = np.zeros((n, 2 * c, 2 * c))
    for k in range(c):
        full[:, 2 * k:2 * k + 2, 2 * k:2 * k + 2] = cov[:, k]
    return full


@given(st.integers(0, 2**32 - 1), st.integers(2, 8))
@settings(max_examples=40, deadline=None)
def test_per_view_covariances_solve_as_the_joint_matrix_does(seed: int, views: int) -> None:
    # The tracker passes one 2x2 covariance per view, solved in blocks
    # (stereo/intersection_blocks.py); the joint path on the same matrix written out in full
    # is the reference: the same points, covariances, residuals, rejections and validity to
    # rounding, with missing views, failed matches (NaN covariance) and blunders to reject.
    rng = np.random.default_rng(seed)
    cams = _ring(views)
    X = rng.uniform(-0.6, 0.6, (300, 3))
    X = X[np.all([c.visible(X) for c in cams], axis=0)][:60]
    n = len(X)
    uv = np.stack([c.project(X)[0] for c in cams], axis=1)
    a = rng.normal(size=(n, views, 2, 2))
    cov = np.einsum("nkij,nklj->nkil", a, a) * 0.05 + 0.02 * np.eye(2)
    uv += np.einsum("nkij,nkj->nki", np.linalg.cholesky(cov), rng.normal(size=(n, views, 2)))
    blunder = rng.random((n, views)) < 0.1
    uv += blunder[..., None] * rng.choice([-12.0, 12.0], size=(n, views, 2))
    uv[rng.random((n, views)) < 0.2] = np.nan
    cov[rng.random((n, views)) < 0.05] = np.nan
    blocks = intersect(cams, uv, covariance=cov)
    joint = intersect(cams, uv, covariance=_per_view_as_joint(cov))
    # Points whose Gauss-Newton does not converge (a blunder among two or three views) are
    # invalid in both, wherever their last iterate lies; the rest agree to rounding.
    np.testing.assert_array_equal(blocks.valid, joint.valid)
    ok = blocks.valid & joint.valid
    assert n >= 30 and ok.sum() >= 10
    np.testing.assert_array_equal(blocks.used[ok], joint.used[ok])
    np.testing.assert_allclose(blocks.points[ok], joint.points[ok], rtol=0, atol=1e-9)
    # The covariances relative to each point's largest variance (the depth direction's).
    size = np.abs(joint.covariance[ok]).max(axis=(1, 2))[:, None, None]
    assert (np.abs(blocks.covariance[ok] - joint.covariance[ok]) <= 1e-7 * size).all()
    np.testing.assert_allclose(blocks.residuals[ok], joint.residuals[ok], rtol=0, atol=1e-8)
    np.testing.assert_allclose(blocks.normalised[ok], joint.normalised[ok], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(blocks.sigma0[ok], joint.sigma0[ok], rtol=1e-6, atol=1e-12)
    # The blunders were there to reject: some view was dropped.
    if views >= 3:
        assert blocks.used.sum() < (np.isfinite(uv[..., 0]) & np.isfinite(cov).all(axis=(2, 3))).sum()


@given(st.integers(0, 2**32 - 1))
@settings(max_examples=20, deadline=None)
def test_per_view_points_are_solved_each_on_its_own(seed: int) -> None:
    # The core solves each point on its own (rayon over points): a point's result must not
    # depend on which other points share the call, to the bit.
    rng = np.random.default_rng(seed)
    cams = _ring(5)
    X = rng.uniform(-0.5, 0.5, (40, 3))
    uv = np.stack([c.project(X)[0] for c in cams], axis=1) + rng.normal(0, 0.4, (40, 5, 2))
    uv[rng.random((40, 5)) < 0.1] += 15.0
    uv[rng.random((40, 5)) < 0.2] = np.nan
    cov = np.tile(0.16 * np.eye(2), (40, 5, 1, 1))
    whole = intersect(cams, uv, covariance=cov)
    order = rng.permutation(40)[:17]
    part = intersect(cams, uv[order], covariance=cov[order])
    for field in whole._fields:
        np.testing.assert_array_equal(getattr(part, field), getattr(whole, field)[order], err_msg=field)
