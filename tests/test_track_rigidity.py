"""Reported positions pinned by their neighbours' rigid motion (:mod:`elastocap.tracking.rigidity`)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st
from scipy.spatial.transform import Rotation

from elastocap.tracking.rigidity import rigid_fusion, rigid_motions

PIXEL = 0.003  # world units per pixel at the points (3 m, f = 1000 px)


def _limb(rng: np.random.Generator, m: int) -> np.ndarray:
    """``m`` points on the front half of a cylinder of radius 5 cm, 30 cm long."""
    angle = rng.uniform(-1.2, 1.2, m)
    return np.column_stack([0.05 * np.sin(angle), rng.uniform(0.0, 0.3, m), 0.05 * np.cos(angle)])


@given(st.integers(0, 2**32 - 1))
@hsettings(max_examples=25, deadline=None)
def test_rigid_motions_recover_a_rotation_exactly(seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(4, 6, 3))
    rot = Rotation.random(4, random_state=seed)
    t = rng.normal(size=(4, 3))
    b = np.einsum("nij,nkj->nki", rot.as_matrix(), a) + t[:, None]
    r, tr = rigid_motions(a, b)
    np.testing.assert_allclose(r, rot.as_matrix(), atol=1e-9)
    np.testing.assert_allclose(tr, t, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(r), 1.0)


@given(st.integers(0, 2**32 - 1))
@hsettings(max_examples=25, deadline=None)
def test_weighted_rigid_motions_ignore_what_weighs_nothing(seed):
    # Points of weight 0 moved anywhere change nothing; the weighted fit of exact points is
    # exact; weights that are all equal give the unweighted fit.
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(3, 8, 3))
    rot = Rotation.random(3, random_state=seed).as_matrix()
    t = rng.normal(size=(3, 3))
    b = np.einsum("nij,nkj->nki", rot, a) + t[:, None]
    w = rng.uniform(0.1, 2.0, size=(3, 8))
    w[:, 5:] = 0.0
    b[:, 5:] += rng.normal(0, 5.0, size=(3, 3, 3))
    r, tr = rigid_motions(a, b, w)
    np.testing.assert_allclose(r, rot, atol=1e-9)
    np.testing.assert_allclose(tr, t, atol=1e-9)
    b2 = b + rng.normal(0, 0.05, b.shape)
    r1, t1 = rigid_motions(a, b2)
    r2, t2 = rigid_motions(a, b2, np.full((3, 8), 0.3))
    np.testing.assert_allclose(r2, r1, atol=1e-12)
    np.testing.assert_allclose(t2, t1, atol=1e-12)


def test_a_point_drifted_along_its_rays_is_pulled_back_by_its_neighbours():
    rng = np.random.default_rng(3)
    m = 80
    before = _limb(rng, m)
    rot = Rotation.from_euler("xyz", [20, -35, 10], degrees=True).as_matrix()
    now = before @ rot.T + np.array([0.1, -0.05, 0.2])
    # The views of a narrow stereo pair: sd 0.3 px across the rays, 3 px-eq along them (z).
    ray = np.array([0.0, 0.0, 1.0])
    cov = np.tile((0.3 * PIXEL) ** 2 * np.eye(3) + ((3.0 * PIXEL) ** 2 - (0.3 * PIXEL) ** 2) * np.outer(ray, ray), (m, 1, 1))
    x = now + rng.normal(0, 0.1 * PIXEL, now.shape)
    bad = [5, 40]
    x[bad] += 6.0 * PIXEL * ray  # drifted 6 px-eq in depth
    seeded = np.zeros(m, np.int64)
    seeded[-3:] = 7  # seeded on this frame: no history yet
    x[-3:] = now[-3:]
    pixel = np.full(m, PIXEL)
    fused, fcov = rigid_fusion(x, cov, pixel, seeded, {0: before}, neighbours=8, sigma=2.0, passes=1)
    error = np.linalg.norm(fused - now, axis=1) / PIXEL
    # From 6 px-eq to what the Gaussians leave: 6 sigma^2 / (sigma^2 + 3^2) = 1.85 px-eq.
    np.testing.assert_allclose(error[bad], 6.0 * 4 / 13, atol=0.3)
    others = np.setdiff1d(np.arange(m), bad)
    assert np.median(error[others]) < 0.3
    # Across the rays the views decide: the fused point moves (almost) only along z.
    shift = fused[bad] - x[bad]
    assert (np.abs(shift[:, :2]) < 0.1 * np.abs(shift[:, 2:])).all()
    # The covariance shrinks along the rays and stays symmetric positive definite.
    assert (np.einsum("i,nij,j->n", ray, fcov, ray) < 0.5 * np.einsum("i,nij,j->n", ray, cov, ray))[:-3].all()
    np.testing.assert_allclose(fcov, fcov.transpose(0, 2, 1), atol=1e-18)
    assert (np.linalg.eigvalsh(fcov) > 0).all()
    # Points without a history frame are reported as intersected.
    np.testing.assert_array_equal(fused[-3:], x[-3:])
    np.testing.assert_array_equal(fcov[-3:], cov[-3:])
    # Neither a point nor its neighbours untracked then or now breaks it: NaN stays NaN.
    x[10] = np.nan
    history = before.copy()
    history[20] = np.nan
    fused2, _ = rigid_fusion(x, cov, pixel, seeded, {0: history}, neighbours=8, sigma=2.0, passes=1)
    assert np.isnan(fused2[10]).all() and np.isfinite(np.delete(fused2, 10, axis=0)).all()
    np.testing.assert_array_equal(fused2[20], x[20])  # no position on its seeding frame: as it is
    assert np.linalg.norm(fused2[bad] - now[bad], axis=1).max() / PIXEL < 2.2


def test_the_prediction_weighs_less_where_the_intersection_is_sure():
    rng = np.random.default_rng(4)
    m = 40
    before = _limb(rng, m)
    now = before + np.array([0.0, 0.0, 0.05])
    x = now.copy()
    x[0] += 2.0 * PIXEL * np.array([0.0, 0.0, 1.0])
    pixel = np.full(m, PIXEL)
    seeded = np.zeros(m, np.int64)
    sure = np.tile((0.1 * PIXEL) ** 2 * np.eye(3), (m, 1, 1))
    loose = np.tile((5.0 * PIXEL) ** 2 * np.eye(3), (m, 1, 1))
    a, _ = rigid_fusion(x, sure, pixel, seeded, {0: before}, neighbours=8, sigma=2.0, passes=1)
    b, _ = rigid_fusion(x, loose, pixel, seeded, {0: before}, neighbours=8, sigma=2.0, passes=1)
    assert np.linalg.norm(a[0] - x[0]) < 0.01 * PIXEL
    assert np.linalg.norm(b[0] - now[0]) < 0.4 * PIXEL


def test_a_point_by_another_part_that_came_close_is_pulled_to_its_own_parts_motion():
    # An arm (a limb) that has swung in beside the torso (a flat patch) since the points were
    # seeded: now the arm's edge points have torso points among their nearest, whose motion
    # (a small shift) is not theirs (a swing of 40 degrees and 25 cm). A point on the arm's
    # edge drifted 6 px-eq along its rays (the covariance long along them, z).
    rng = np.random.default_rng(7)
    arm_now = _limb(rng, 120)
    edge = np.array([0.05 * np.sin(1.25), 0.15, 0.05 * np.cos(1.25)])  # x 0.047: by the torso
    arm_now = np.vstack([edge, arm_now])
    torso_now = np.column_stack([rng.uniform(0.052, 0.2, 150), rng.uniform(0.0, 0.3, 150), rng.uniform(-0.002, 0.02, 150)])
    swing = Rotation.from_euler("xyz", [40, 0, -25], degrees=True).as_matrix()
    arm_then = (arm_now - np.array([0.25, 0.1, 0.0])) @ swing  # R^T (now - t)
    torso_then = torso_now - np.array([0.0, 0.0, 0.02])
    now, then = np.vstack([arm_now, torso_now]), np.vstack([arm_then, torso_then])
    m = len(now)
    ray = np.array([0.0, 0.0, 1.0])
    cov = np.tile((0.3 * PIXEL) ** 2 * np.eye(3) + ((3.0 * PIXEL) ** 2 - (0.3 * PIXEL) ** 2) * np.outer(ray, ray), (m, 1, 1))
    x = now.copy()
    x[0] += 6.0 * PIXEL * ray
    pixel = np.full(m, PIXEL)
    seeded = np.zeros(m, np.int64)
    # Nearest now only: the torso's shift is mixed into the arm's motion, the point predicted
    # wrong (the test's premise: the two parts do meet at it).
    mixed, _ = rigid_fusion(x, cov, pixel, seeded, {0: then}, neighbours=6, sigma=3.0, passes=1)
    fused, fcov = rigid_fusion(x, cov, pixel, seeded, {0: then}, neighbours=6, sigma=3.0, both_frames=1.0, passes=1)
    # With the seeding frame too, its neighbours are the arm's: from 6 px-eq to what the
    # Gaussians leave, 6 sigma^2 / (sigma^2 + 3^2) = 3 px-eq, pulled along the rays only.
    error = np.linalg.norm(fused[0] - now[0]) / PIXEL
    np.testing.assert_allclose(error, 6.0 * 9 / 18, atol=0.2)
    shift = fused[0] - x[0]
    assert np.abs(shift[:2]).max() < 0.05 * abs(shift[2])
    assert np.linalg.norm(mixed[0] - now[0]) / PIXEL > error + 1.0
    # Every other point is exact but for the drifted one among its neighbours: at most its
    # share of their fit, 6 px-eq / 6 neighbours.
    others = np.linalg.norm(fused[1:] - now[1:], axis=1) / PIXEL
    assert np.median(others) < 1e-9 and others.max() < 6.0 / 6 + 0.1
    assert (np.linalg.eigvalsh(fcov) > 0).all()


def test_neighbours_whose_distance_to_the_point_changed_are_refused():
    # The arm's edge point again, the arm moved 5 cm sideways onto the torso since: among
    # the points nearest now (without the seeding frame's positions) most are the torso's,
    # each of whose distances to the point has changed by centimetres, while a rigid
    # motion keeps distances whatever its rotation.
    rng = np.random.default_rng(8)
    arm_now = np.vstack([[0.05 * np.sin(1.25), 0.15, 0.05 * np.cos(1.25)], _limb(rng, 120)])
    torso_now = np.column_stack([rng.uniform(0.052, 0.2, 300), rng.uniform(0.0, 0.3, 300), rng.uniform(0.0, 0.01, 300)])
    turn = Rotation.from_euler("y", 30, degrees=True).as_matrix()
    arm_then = (arm_now + np.array([0.05, 0.0, 0.0])) @ turn - np.array([0.1, 0.0, 0.0])
    torso_then = torso_now.copy()
    now, then = np.vstack([arm_now, torso_now]), np.vstack([arm_then, torso_then])
    m = len(now)
    ray = np.array([0.0, 0.0, 1.0])
    cov = np.tile((0.3 * PIXEL) ** 2 * np.eye(3) + ((3.0 * PIXEL) ** 2 - (0.3 * PIXEL) ** 2) * np.outer(ray, ray), (m, 1, 1))
    x = now.copy()
    x[0] += 6.0 * PIXEL * ray
    pixel = np.full(m, PIXEL)
    seeded = np.zeros(m, np.int64)
    options = dict(neighbours=8, sigma=2.5)
    plain, _ = rigid_fusion(x, cov, pixel, seeded, {0: then}, **options, passes=1)
    kept, kcov = rigid_fusion(x, cov, pixel, seeded, {0: then}, candidates=16, stretch=8.0, **options, passes=1)
    error = np.linalg.norm(kept[0] - now[0]) / PIXEL
    # 6 sigma^2 / (sigma^2 + 3^2) = 2.46 px-eq left, moved along the rays only.
    np.testing.assert_allclose(error, 6.0 * 6.25 / 15.25, atol=0.25)
    shift = kept[0] - x[0]
    assert np.abs(shift[:2]).max() < 0.05 * abs(shift[2])
    assert np.linalg.norm(plain[0] - now[0]) / PIXEL > error + 1.0
    assert (np.linalg.eigvalsh(kcov) > 0).all()
    # Where fewer than 3 candidates kept their distance (none here), the nearest are taken.
    few, _ = rigid_fusion(x, cov, pixel, seeded, {0: then}, candidates=16, stretch=0.0, **options, passes=1)
    np.testing.assert_allclose(few, plain, rtol=0, atol=1e-12)


def _drifted_neighbours(d: float) -> tuple[np.ndarray, ...]:
    """A limb moved rigidly; every point but the first reported ``d`` px-eq off along the
    rays (z), the first exactly: its neighbours' prediction is ``d`` px-eq off in depth."""
    rng = np.random.default_rng(11)
    m = 60
    before = _limb(rng, m)
    rot = Rotation.from_euler("xyz", [10, 25, -5], degrees=True).as_matrix()
    now = before @ rot.T + np.array([0.05, 0.1, -0.1])
    ray = np.array([0.0, 0.0, 1.0])
    cov = np.tile((0.3 * PIXEL) ** 2 * np.eye(3) + ((3.0 * PIXEL) ** 2 - (0.3 * PIXEL) ** 2) * np.outer(ray, ray), (m, 1, 1))
    x = now.copy()
    x[1:] += d * PIXEL * ray
    return x, cov, np.full(m, PIXEL), np.zeros(m, np.int64), before, now


@pytest.mark.parametrize("d", [3.0, 6.0, 12.0, 20.0, 40.0])
def test_a_prediction_far_from_the_views_is_gated(d):
    # sd 3 px-eq along the rays, the prediction's 2: the disagreement d is m = d / sqrt(13)
    # Mahalanobis units; beyond the gate the prediction's variance is 4 m^2 / gate^2, so the
    # point moves d 9 / (9 + 4 max(1, m^2 / gate^2)) along the rays.
    x, cov, pixel, seeded, before, now = _drifted_neighbours(d)
    plain, _ = rigid_fusion(x, cov, pixel, seeded, {0: before}, neighbours=8, sigma=2.0, gate=float("inf"), passes=1)
    gated, gcov = rigid_fusion(x, cov, pixel, seeded, {0: before}, neighbours=8, sigma=2.0, gate=2.0, passes=1)
    shift = (gated[0] - now[0]) / PIXEL
    np.testing.assert_allclose((plain[0] - now[0]) / PIXEL, [0, 0, d * 9 / 13], atol=1e-6)
    scale = max(1.0, d * d / 13 / 4.0)
    np.testing.assert_allclose(shift, [0, 0, d * 9 / (9 + 4 * scale)], atol=1e-6)
    # The others agree with their (equally drifted) neighbours: untouched by the gate.
    np.testing.assert_allclose(gated[1:], plain[1:], atol=1e-12)
    assert (np.linalg.eigvalsh(gcov) > 0).all()


def test_the_gated_correction_falls_beyond_the_gate_and_is_checked():
    # Redescending: the correction peaks near the gate (d = 2 sqrt(13 * 9 / 4) = 10.8 px-eq
    # here) and falls beyond, where the plain fusion's keeps growing.
    moves = []
    for d in (4.0, 10.8, 20.0, 40.0):
        x, cov, pixel, seeded, before, now = _drifted_neighbours(d)
        gated, _ = rigid_fusion(x, cov, pixel, seeded, {0: before}, neighbours=8, sigma=2.0, gate=2.0, passes=1)
        moves.append(np.linalg.norm(gated[0] - x[0]) / PIXEL)
    assert moves[0] < moves[1] and moves[1] > moves[2] > moves[3]
    assert moves[3] < 0.11 * 40.0 * 9 / 13  # the plain fusion: 27.7 px-eq
    x, cov, pixel, seeded, before, _ = _drifted_neighbours(5.0)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="gate"):
            rigid_fusion(x, cov, pixel, seeded, {0: before}, neighbours=8, sigma=2.0, gate=bad, passes=1)


def test_a_second_pass_takes_the_neighbours_drift_out_of_the_prediction():
    # A limb moved rigidly; every fifth point drifted 6 px-eq along its rays. On the first
    # pass the points next to them are predicted with the drift in their neighbours' motion;
    # the second fits the motion to the neighbours' fused positions, nearer the truth. (The
    # other tests check one pass's closed forms, hence their passes=1.)
    rng = np.random.default_rng(5)
    m = 120
    before = _limb(rng, m)
    rot = Rotation.from_euler("xyz", [15, -20, 30], degrees=True).as_matrix()
    now = before @ rot.T + np.array([0.02, 0.1, 0.05])
    ray = np.array([0.0, 0.0, 1.0])
    cov = np.tile((0.3 * PIXEL) ** 2 * np.eye(3) + ((3.0 * PIXEL) ** 2 - (0.3 * PIXEL) ** 2) * np.outer(ray, ray), (m, 1, 1))
    drifted = np.arange(0, m, 5)
    x = now.copy()
    x[drifted] += 6.0 * PIXEL * ray
    pixel = np.full(m, PIXEL)
    seeded = np.zeros(m, np.int64)
    seeded[-4:] = 3  # seeded on this frame: this frame's intersections are their history
    history = {0: before, 3: x.copy()}
    options = dict(neighbours=8, sigma=2.0, gate=float("inf"))
    one, _ = rigid_fusion(x, cov, pixel, seeded, history, passes=1, **options)
    two, tcov = rigid_fusion(x, cov, pixel, seeded, history, passes=2, **options)
    err1 = np.linalg.norm(one - now, axis=1)[:-4] / PIXEL
    err2 = np.linalg.norm(two - now, axis=1)[:-4] / PIXEL
    right = np.setdiff1d(np.arange(m - 4), drifted)
    # The right point worst misled by drifted neighbours (4.0 px-eq) is helped most (2.5);
    # the drift the first pass left in the others spreads a little, so the mean moves less.
    assert err2[right].max() < 0.7 * err1[right].max()
    assert err2[right].mean() < err1[right].mean()
    assert np.sqrt(np.mean(err2**2)) < np.sqrt(np.mean(err1**2))
    np.testing.assert_array_equal(two[-4:], x[-4:])  # points seeded now: as intersected
    np.testing.assert_array_equal(tcov[-4:], cov[-4:])
    assert (np.linalg.eigvalsh(tcov) > 0).all()
    for bad in (0, -1, 1.5):
        with pytest.raises(ValueError, match="passes"):
            rigid_fusion(x, cov, pixel, seeded, history, passes=bad, **options)


@given(st.integers(0, 2**32 - 1), st.floats(0.0, 14.0))
@hsettings(max_examples=40, deadline=None)
def test_fused_covariances_are_positive_definite_by_construction(seed, condition):
    # Intersections whose covariance is 10^condition times longer along the rays than across
    # (near-parallel rays), in any direction, with any disagreement from the prediction: the
    # fused covariance is symmetric positive definite, below S, and equal to
    # S - S (S + P)^-1 S where that is well conditioned.
    rng = np.random.default_rng(seed)
    m = 60
    before = _limb(rng, m)
    rot = Rotation.random(random_state=seed).as_matrix()
    now = before @ rot.T + rng.normal(0, 0.1, 3)
    ray = rng.normal(size=(m, 3))
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    across = (0.3 * PIXEL) ** 2
    cov = across * np.eye(3) + across * (10.0**condition - 1.0) * np.einsum("ni,nj->nij", ray, ray)
    x = now + rng.normal(0, 3 * PIXEL, now.shape)
    pixel = np.full(m, PIXEL)
    fused, fcov = rigid_fusion(x, cov, pixel, np.zeros(m, np.int64), {0: before}, neighbours=8, sigma=2.0)
    np.testing.assert_array_equal(fcov, fcov.transpose(0, 2, 1))
    w = np.linalg.eigvalsh(fcov)
    assert (w[:, 0] > 0).all()
    assert (np.linalg.eigvalsh(cov - fcov)[:, 0] > -1e-12 * np.linalg.eigvalsh(cov)[:, -1]).all()
    if condition < 6:
        f1, c1 = rigid_fusion(x, cov, pixel, np.zeros(m, np.int64), {0: before}, neighbours=8, sigma=2.0, gate=np.inf,
                              passes=1)
        p = (2.0 * PIXEL) ** 2 * np.eye(3)
        plain = cov - np.einsum("nij,njk->nik", cov, np.linalg.solve(cov + p, cov))
        np.testing.assert_allclose(c1, plain, rtol=1e-6, atol=1e-9 * across)


def _kabsch_svd(a, b, w):
    """Reference: the weighted Kabsch fit by an SVD per set."""
    w = w / w.sum(axis=1, keepdims=True)
    ca, cb = np.einsum("nk,nki->ni", w, a), np.einsum("nk,nki->ni", w, b)
    h = np.einsum("nk,nki,nkj->nij", w, a - ca[:, None], b - cb[:, None])
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.einsum("nji,nkj->nik", vt, u)))
    fix = np.ones((len(a), 3))
    fix[:, 2] = d
    r = np.einsum("nji,nj,nkj->nik", vt, fix, u)
    return r, cb - np.einsum("nij,nj->ni", r, ca)


@given(st.integers(0, 2**32 - 1), st.integers(3, 12), st.floats(0.0, 0.5))
@hsettings(max_examples=40, deadline=None)
def test_rigid_motions_equal_the_svd_kabsch_fit_of_noisy_and_planar_sets(seed, k, noise):
    # The core fits the rotation nearest to H^T (a polar decomposition) instead of an SVD
    # per set: the same proper rotation wherever it is unique, also for planar sets (a
    # limb's neighbours on a surface) and for sets mirrored by the noise.
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(30, k, 3))
    a[:10, :, 2] = 0.0  # planar sets
    rot = Rotation.random(30, random_state=seed).as_matrix()
    b = np.einsum("nij,nkj->nki", rot, a) + rng.normal(size=(30, 1, 3)) + rng.normal(0, noise, (30, k, 3))
    w = rng.uniform(0.0, 2.0, (30, k))
    w[:, :3] += 0.5
    r, t = rigid_motions(a, b, w)
    r0, t0 = _kabsch_svd(a, b, w)
    np.testing.assert_allclose(r, r0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(t, t0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
