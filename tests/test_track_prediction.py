"""The frame-to-frame failures searched again where their neighbours went
(elastocap.tracking.prediction): a limb turning fast, points on it with and without a
velocity history."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from elastocap import _core
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.prediction import neighbour_predictions, research_failed_views

SIZE, RADIUS = 15, 6
PIVOT = np.array([40.0, 200.0])


def _texture(seed: int, shape: tuple[int, int] = (320, 400)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.normal(0.0, 1.0, shape).astype(np.float32)
    image = cv2.GaussianBlur(noise, (0, 0), 2.0)
    return np.ascontiguousarray(128.0 + 60.0 * image / image.std(), dtype=np.float32)


def _turn(angle_deg: float) -> np.ndarray:
    """The affine (2, 3) of a turn about PIVOT: a limb swinging about its joint."""
    return cv2.getRotationMatrix2D((float(PIVOT[0]), float(PIVOT[1])), angle_deg, 1.0)


def _moved(points: np.ndarray, m: np.ndarray) -> np.ndarray:
    return points @ m[:, :2].T + m[:, 2]


def _scene(angle: float = -7.0):
    """Two frames of a textured limb turned by ``angle`` degrees about PIVOT; a grid of
    points 130-200 px from the pivot (they move 16-24 px)."""
    previous = _texture(3)
    m = _turn(angle)
    current = np.ascontiguousarray(cv2.warpAffine(previous, m, previous.shape[::-1], flags=cv2.INTER_CUBIC,
                                                  borderMode=cv2.BORDER_REFLECT), dtype=np.float32)
    u, v = np.meshgrid(np.arange(170.0, 241.0, 10.0), np.arange(170.0, 231.0, 10.0))
    last = np.column_stack([u.ravel(), v.ravel()])
    return previous, current, last, _moved(last, m)


def _step(previous, current, last, before, radius=RADIUS):
    pos, flags, cov, corr = _core.track_step([previous], [current], last[None], before[None], size=SIZE, radius=radius,
                                             min_correlation=0.5, forward_backward=0.6, min_texture=0.0, max_iterations=8)
    return pos[0][:, None], flags[0][:, None], cov[0][:, None], corr[0][:, None]


def _research(previous, current, last, before, step, *, wide_radius=0):
    uv, flags, cov, corr = step
    x_last = np.column_stack([last, np.zeros(len(last))])  # 3-D neighbours = image neighbours here
    return research_failed_views([previous], [current], last[:, None], before[:, None], uv, flags, cov, corr, x_last,
                                 np.full(len(last), 40.0), size=SIZE, radius=RADIUS, wide_radius=wide_radius,
                                 min_correlation=0.75, box_correlation=0.5, forward_backward=0.6, min_texture=0.0,
                                 max_iterations=8, weights=None, neighbours=8, min_neighbours=3)


def test_new_points_on_a_fast_turning_limb_are_followed_from_their_neighbours_motion():
    previous, current, last, truth = _scene()
    speed = np.linalg.norm(truth - last, axis=1)
    assert speed.min() > 2 * RADIUS  # beyond the box around a no-motion prediction
    # Every other point has a velocity history (the same turn a frame before: its linear
    # prediction is right); the others were seeded on the previous frame (none).
    old = np.arange(len(last)) % 2 == 0
    back = _moved(last, _turn(7.0))
    before = np.where(old[:, None], back, np.nan)
    step = _step(previous, current, last, before)
    right = np.linalg.norm(step[0][:, 0] - truth, axis=1) < 0.5
    assert right[old].mean() > 0.9
    assert right[~old].mean() < 0.1  # the step alone loses the new points (or matches them wrong)
    out = _research(previous, current, last, before, step)
    new = ~old & (step[1][:, 0] != TrackFlag.TRACKED)
    assert new.sum() >= 0.5 * (~old).sum()
    assert out.found[new, 0].mean() > 0.9 and out.by_neighbours[new, 0].all() == out.found[new, 0].all()
    hit = new & out.found[:, 0]
    error = np.linalg.norm(out.uv[hit, 0] - truth[hit], axis=1)
    assert np.median(error) < 0.1 and error.max() < 0.5
    # What the step had found is untouched.
    kept = old & (step[1][:, 0] == TrackFlag.TRACKED)
    np.testing.assert_array_equal(out.uv[kept, 0], step[0][kept, 0])


def test_without_any_motion_history_the_wide_box_finds_the_limb():
    previous, current, last, truth = _scene()
    before = np.full_like(last, np.nan)
    step = _step(previous, current, last, before)
    # The step's few finds at the no-motion prediction are wrong matches nearby: taken out,
    # so that no neighbour's motion is known.
    assert (np.linalg.norm(step[0][:, 0] - truth, axis=1) < 0.5).mean() < 0.1
    step[1][:] = np.where(step[1] == TrackFlag.TRACKED, TrackFlag.LOW_CORRELATION, step[1])
    assert not _research(previous, current, last, before, step).found.any()
    out = _research(previous, current, last, before, step, wide_radius=24)
    assert out.found.mean() > 0.9
    error = np.linalg.norm(out.uv[out.found[:, 0], 0] - truth[out.found[:, 0]], axis=1)
    assert np.median(error) < 0.1 and error.max() < 0.5
    assert out.flags2d[out.found].tolist() == [TrackFlag.TRACKED] * int(out.found.sum())


def test_a_point_on_another_limb_crossing_in_the_image_lends_no_motion():
    # Two groups of points interleaved in the image, 1 m apart in depth, moving opposite
    # ways: each failed point is predicted by its own group's motion.
    rng = np.random.default_rng(0)
    n = 60
    last = rng.uniform(100, 140, size=(n, 1, 2))
    group = np.arange(n) % 2
    motion = np.where(group[:, None], [15.0, 0.0], [-15.0, 3.0])
    now = last + motion[:, None]
    x_last = np.column_stack([last[:, 0], 1000.0 * group])
    wanted = (np.arange(n) % 5 == 0)[:, None]
    confident = ~wanted
    prediction, spread = neighbour_predictions(last, np.where(confident[..., None], now, np.nan), confident, x_last,
                                               np.full(n, 50.0), wanted, neighbours=8, min_neighbours=3)
    rows = wanted[:, 0]
    np.testing.assert_allclose(prediction[rows, 0], now[rows, 0], atol=1e-9)
    assert np.all(spread[rows, 0] < 1e-9)
    assert np.isnan(prediction[~rows]).all()


@settings(max_examples=30, deadline=None)
@given(st.floats(-30, 30), st.floats(-30, 30), st.integers(0, 10_000))
def test_a_translation_is_predicted_exactly_and_too_few_neighbours_predict_nothing(du, dv, seed):
    rng = np.random.default_rng(seed)
    n = 40
    last = rng.uniform(0, 300, size=(n, 2, 2))
    now = last + np.array([du, dv])
    x_last = rng.uniform(0, 1, size=(n, 3))
    wanted = np.zeros((n, 2), bool)
    wanted[:5, 0] = True
    confident = ~wanted
    prediction, _ = neighbour_predictions(last, now, confident, x_last, np.full(n, 10.0), wanted, neighbours=8,
                                          min_neighbours=3)
    np.testing.assert_allclose(prediction[:5, 0], now[:5, 0], atol=1e-9)
    # Out of reach of every neighbour: no prediction (not a guess).
    prediction, _ = neighbour_predictions(last, now, confident, x_last, np.full(n, 1e-9), wanted, neighbours=8,
                                          min_neighbours=3)
    assert np.isnan(prediction).all()


@pytest.mark.parametrize("flag", [TrackFlag.IMAGE_BORDER, TrackFlag.NOT_SEEDED])
def test_views_lost_for_other_reasons_are_not_searched_again(flag):
    previous, current, last, _ = _scene()
    before = np.full_like(last, np.nan)
    uv, flags, cov, corr = _step(previous, current, last, before)
    flags[:] = flag
    out = _research(previous, current, last, before, (uv, flags, cov, corr), wide_radius=24)
    assert not out.found.any() and (out.flags2d == flag).all()


def test_a_view_searched_again_that_breaks_its_points_intersection_is_dropped_not_the_point():
    from elastocap.synth.capture import ring_rig
    from elastocap.tracking.prediction import drop_breaking_views
    from elastocap.tracking.views import intersect_views

    cameras = ring_rig(8, width=640, height=480).cameras
    truth = np.array([[0.05, 0.9, 0.02], [0.0, 1.0, 0.1]])
    uv = np.full((2, 8, 2), np.nan)
    uv[:, :3] = np.stack([c.project(truth)[0] for c in cameras[:3]], axis=1)
    # Camera 0's view found 3 px off with an uncertain match: not refused as a blunder by
    # its normalised residual, beyond the residual bound, so the whole point fails.
    uv[:, 0] += [3.0, 0.0]
    cov = np.where(np.isfinite(uv)[..., None], np.eye(2) * 0.01, np.nan)
    cov[:, 0] = np.eye(2)
    x, xcov, used, rejected = intersect_views(cameras, uv, cov, max_residual=1.5, floor=0.1)
    assert not np.isfinite(x).any()
    researched = np.zeros((2, 8), bool)
    researched[0, 0] = True  # point 1's bad view is the step's own: its failure stands
    flags = np.zeros((2, 8), np.uint8)
    x2, _, used2, rejected2 = drop_breaking_views(cameras, uv, cov, flags, researched, x, xcov, used, rejected,
                                                  max_residual=1.5, floor=0.1)
    np.testing.assert_allclose(x2[0], truth[0], atol=1e-6)
    assert np.isnan(uv[0, 0]).all() and flags[0, 0] == TrackFlag.EPIPOLAR and rejected2[0, 0] and not used2[0, 0]
    assert used2[0, 1:3].all()
    assert not np.isfinite(x2[1]).any() and np.isfinite(uv[1, 0]).all()


def test_a_wide_box_find_farther_than_the_tolerance_from_its_point_is_dropped():
    from elastocap.synth.capture import ring_rig
    from elastocap.tracking.prediction import drop_far_views
    from elastocap.tracking.views import intersect_views

    cameras = ring_rig(8, width=640, height=480).cameras
    truth = np.array([[0.05, 0.9, 0.02], [0.0, 1.0, 0.1], [0.02, 1.1, 0.0]])
    uv = np.full((3, 8, 2), np.nan)
    uv[:, :4] = np.stack([c.project(truth)[0] for c in cameras[:4]], axis=1)
    # Camera 0's view 1 px off with an uncertain match: within the intersection's 1.5 px
    # bound and not a blunder by its normalised residual, so it is kept.
    uv[:, 0] += [1.0, 0.0]
    cov = np.where(np.isfinite(uv)[..., None], np.eye(2) * 0.01, np.nan)
    cov[:, 0] = np.eye(2)
    x, xcov, used, rejected = intersect_views(cameras, uv, cov, max_residual=1.5, floor=0.1)
    assert used[:, 0].all() and np.isfinite(x).all()
    wide = np.zeros((3, 8), bool)
    wide[0, 0] = wide[2, 0] = True
    flags = np.zeros((3, 8), np.uint8)
    x2, _, used2, rejected2 = drop_far_views(cameras, uv, cov, flags, wide, x, xcov, used, rejected, tolerance=0.3,
                                             max_residual=1.5, floor=0.1)
    np.testing.assert_allclose(x2[0], truth[0], atol=1e-6)
    assert np.isnan(uv[0, 0]).all() and flags[0, 0] == TrackFlag.EPIPOLAR and rejected2[0, 0] and not used2[0, 0]
    # Point 1's off view is the step's own (not suspect): kept.
    np.testing.assert_array_equal(x2[1], x[1])
    assert used2[1, 0] and flags[1, 0] == 0
    # Point 2's off view was dropped too (its projection is farther than 0.3 px).
    assert not used2[2, 0]
    np.testing.assert_allclose(x2[2], truth[2], atol=1e-6)
    # A tolerance the view meets keeps it.
    uv3 = np.stack([c.project(truth)[0] for c in cameras[:4]], axis=1)
    uv3 = np.concatenate([uv3, np.full((3, 4, 2), np.nan)], axis=1)
    x3, xc3, u3, r3 = intersect_views(cameras, uv3, cov, max_residual=1.5, floor=0.1)
    f3 = np.zeros((3, 8), np.uint8)
    x4, _, u4, _ = drop_far_views(cameras, uv3, cov, f3, wide, x3, xc3, u3, r3, tolerance=0.3, max_residual=1.5, floor=0.1)
    np.testing.assert_array_equal(x4, x3)
    assert (u4 == u3).all() and not f3.any()


def test_a_wide_box_find_below_the_wide_correlation_is_not_taken():
    previous, current, last, truth = _scene()
    before = np.full_like(last, np.nan)
    step = _step(previous, current, last, before)
    step[1][:] = np.where(step[1] == TrackFlag.TRACKED, TrackFlag.LOW_CORRELATION, step[1])
    uv, flags, cov, corr = step
    x_last = np.column_stack([last, np.zeros(len(last))])
    common = dict(size=SIZE, radius=RADIUS, wide_radius=24, min_correlation=0.75, box_correlation=0.5,
                  forward_backward=0.6, min_texture=0.0, max_iterations=8, weights=None, neighbours=8, min_neighbours=3)
    out = research_failed_views([previous], [current], last[:, None], before[:, None], uv, flags, cov, corr, x_last,
                                np.full(len(last), 40.0), **common)
    wide = out.found & ~out.by_neighbours
    assert wide.any()
    # Above every find's correlation: the wide box takes none, so no neighbour lends motion either.
    strict = research_failed_views([previous], [current], last[:, None], before[:, None], uv, flags, cov, corr, x_last,
                                   np.full(len(last), 40.0), wide_correlation=float(np.nanmax(out.corr[wide])) + 1e-6,
                                   **common)
    assert not strict.found.any()
