"""The step's prediction from the neighbourhood's rigid 3-D motion
(elastocap.tracking.rigid_prediction): a textured disc turning in its plane and drifting,
seen by one camera, its points at one depth; new points on its rim have no motion of their
own to predict from."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from elastocap import Camera
from elastocap.tracking.depth_weights import rust_step
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.rigid_prediction import predicting_before, rigid_predictions

W, H = 400, 320
F = 600.0
Z = 2.0
CAMERA = Camera("c", [[F, 0.0, W / 2], [0.0, F, H / 2], [0.0, 0.0, 1.0]], None, np.eye(3), np.zeros(3), W, H)
CENTRE = np.array([200.0, 160.0])
TURN = np.deg2rad(10.0)  # per frame: a forearm turns 13 degrees a frame in the image at the median
DRIFT = np.array([1.0, -0.5])  # px per frame
PIXEL = Z / F  # world units per pixel on the disc


def _motion(frame: int) -> np.ndarray:
    """(2, 3) image map of the disc from frame 0 to ``frame``: ``frame`` times the step
    that turns it by TURN about CENTRE and moves it by DRIFT (a constant rigid motion)."""
    c, s = np.cos(TURN), np.sin(TURN)
    r = np.array([[c, -s], [s, c]])
    step = np.eye(3)
    step[:2] = np.column_stack([r, CENTRE + DRIFT - r @ CENTRE])
    return np.linalg.matrix_power(step, frame)[:2]


def _apply(m: np.ndarray, uv: np.ndarray) -> np.ndarray:
    return uv @ m[:, :2].T + m[:, 2]


def _back(uv: np.ndarray) -> np.ndarray:
    return np.column_stack([(uv[:, 0] - W / 2) * Z / F, (uv[:, 1] - H / 2) * Z / F, np.full(len(uv), Z)])


def _image(frame: int) -> np.ndarray:
    noise = np.random.default_rng(5).normal(0.0, 1.0, (H, W)).astype(np.float32)
    texture = cv2.GaussianBlur(noise, (0, 0), 1.5)
    texture = 128.0 + 50.0 * texture / texture.std()
    return np.ascontiguousarray(cv2.warpAffine(texture, _motion(frame), (W, H), flags=cv2.INTER_CUBIC), dtype=np.float32)


def _scene():
    """Views on frame 0 (M, 1, 2) and their positions on frame -1 (NaN for the new points),
    3-D positions on frames 0 and -1, the truth on frame 1 and which points are new: tracked
    points on a grid within 45 px of the centre, new points on a ring at 70 px."""
    g = np.arange(-45.0, 46.0, 9.0)
    gu, gv = np.meshgrid(g, g)
    grid = np.column_stack([gu.ravel(), gv.ravel()])
    grid = CENTRE + grid[np.linalg.norm(grid, axis=1) <= 45.0]
    angle = np.deg2rad(np.arange(0.0, 360.0, 30.0))
    ring = CENTRE + 70.0 * np.column_stack([np.cos(angle), np.sin(angle)])
    uv = np.concatenate([grid, ring])
    new = np.arange(len(uv)) >= len(grid)
    previous = _apply(_motion(-1), uv)
    x_last = _back(uv)
    x_before = np.where(new[:, None], np.nan, _back(previous))
    before = np.where(new[:, None], np.nan, previous)[:, None]
    return uv[:, None], before, x_last, x_before, _apply(_motion(1), uv), new


def _predict(uv, x_last, x_before, **options):
    return rigid_predictions([CAMERA], uv, x_last, x_before, np.full(len(uv), PIXEL), **options)


def test_the_turning_disc_is_predicted_exactly_and_the_linear_prediction_is_not():
    uv, before, x_last, x_before, truth, new = _scene()
    rigid = _predict(uv, x_last, x_before, reach=60.0)[:, 0]
    linear = np.where(np.isfinite(before[:, 0]), 2 * uv[:, 0] - before[:, 0], uv[:, 0])
    rigid_error = np.linalg.norm(rigid - truth, axis=1)
    linear_error = np.linalg.norm(linear - truth, axis=1)
    # The rim's new points: no velocity of their own (the linear prediction is no motion,
    # 11-13 px off: beyond the box's 6 px), the disc's rotation carries them exactly.
    assert rigid_error[new].max() < 1e-6
    assert linear_error[new].min() > 8.0
    # The tracked points' constant image velocity misses the arc by up to r TURN^2.
    assert rigid_error[~new].max() < 1e-6
    assert linear_error[~new].max() > 0.7
    # Without the rotation (the neighbours' mean translation) the rim is pixels off.
    translation = _predict(uv, x_last, x_before, reach=60.0, rotation=False)[:, 0]
    assert np.linalg.norm(translation - truth, axis=1)[new].min() > 3.0


def test_the_step_finds_the_rim_at_the_rigid_prediction_and_loses_it_at_the_linear_one():
    uv, before, x_last, x_before, truth, new = _scene()
    step = rust_step([_image(0)], [_image(1)])
    options = dict(size=15, radius=6, min_correlation=0.5, forward_backward=0.6, min_texture=0.0, max_iterations=15)

    def held(b: np.ndarray) -> np.ndarray:
        pos, flags, _, corr = step(uv, b, weights=None, **options)
        return (flags[:, 0] == TrackFlag.TRACKED) & (corr[:, 0] >= 0.75) & (np.linalg.norm(pos[:, 0] - truth, axis=1) < 0.5)

    plain = held(before)
    use = ~np.isfinite(before[..., 0])
    rigid = held(predicting_before(uv, before, _predict(uv, x_last, x_before, reach=60.0), use))
    assert plain[new].mean() <= 0.25
    assert rigid[new].all()
    # The tracked points keep their linear prediction (use is only the new views): the same.
    np.testing.assert_array_equal(rigid[~new], plain[~new])


def test_points_without_enough_neighbours_within_reach_are_not_predicted():
    uv, _, x_last, x_before, _, new = _scene()
    # At a reach of 15 px the rim (25 px from the grid) has no neighbour: NaN.
    out = _predict(uv, x_last, x_before, reach=15.0)
    assert np.isnan(out[new]).all() and np.isfinite(out[~new]).all()
    # Too few movers at all: nothing predicted.
    few = x_before.copy()
    few[3:] = np.nan
    assert np.isnan(_predict(uv, x_last, few, reach=60.0, min_neighbours=4)).all()
    # Views not held are not predicted; the others are.
    held = uv.copy()
    held[::2] = np.nan
    out = _predict(held, x_last, x_before, reach=60.0)
    assert np.isnan(out[::2]).all() and np.isfinite(out[1::2][~new[1::2]]).all()


@settings(max_examples=40, deadline=None)
@given(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(-0.2, 0.2), st.floats(-0.2, 0.2),
       st.floats(-0.2, 0.2))
def test_a_rigid_motion_of_the_whole_cloud_is_predicted_for_any_point(rx, ry, rz, tx, ty, tz):
    """Any rigid motion (rotation vector in degrees, translation in world units) of a 3-D
    cloud in front of the camera: every held view predicted at the moved point's projection."""
    rng = np.random.default_rng(0)
    before = rng.uniform([-0.3, -0.2, 1.8], [0.3, 0.2, 2.2], (60, 3))
    rotation, _ = cv2.Rodrigues(np.deg2rad([rx, ry, rz]))
    move = np.array([tx, ty, tz])
    last = before @ rotation.T + move
    following = last @ rotation.T + move
    uv = CAMERA.project(last)[0][:, None]
    # Half of the points are new (no position before): predicted all the same.
    x_before = before.copy()
    x_before[::2] = np.nan
    out = rigid_predictions([CAMERA], uv, last, x_before, np.full(60, PIXEL), reach=1e4, neighbours=12)
    np.testing.assert_allclose(out[:, 0], CAMERA.project(following)[0], atol=1e-6)


@given(st.integers(0, 2**32 - 1))
def test_predicting_before_makes_the_steps_linear_prediction_the_given_one(seed):
    rng = np.random.default_rng(seed)
    uv = rng.uniform(0, 300, (20, 3, 2))
    uv[rng.random((20, 3)) < 0.2] = np.nan
    before = np.where(rng.random((20, 3, 1)) < 0.5, np.nan, uv + rng.normal(0, 3, (20, 3, 2)))
    prediction = np.where(rng.random((20, 3, 1)) < 0.2, np.nan, uv + rng.normal(0, 5, (20, 3, 2)))
    use = rng.random((20, 3)) < 0.6
    out = predicting_before(uv, before, prediction, use)
    take = use & np.isfinite(prediction[..., 0]) & np.isfinite(uv[..., 0])
    np.testing.assert_allclose((2 * uv - out)[take], prediction[take], atol=1e-9)
    np.testing.assert_array_equal(out[~take], before[~take])


def test_the_linear_prediction_with_the_option_off_and_a_bad_setting_refused(monkeypatch):
    from elastocap.tracking import settings as tracking_settings
    from elastocap.tracking.step import FrameTracker

    assert tracking_settings.RIGID_PREDICTION == "new"  # the default (benches/README.md, session 21)
    tracker = FrameTracker.__new__(FrameTracker)
    tracker.uv = np.zeros((1, 1, 2))
    tracker.uv_last = np.full((1, 1, 2), np.nan)
    tracker.x_last = np.zeros((1, 3)) + [0, 0, 2]
    tracker.x_before = np.full((1, 3), np.nan)
    tracker.cameras = [CAMERA]
    monkeypatch.setattr(tracking_settings, "RIGID_PREDICTION", None)
    assert tracker._before() is tracker.uv_last
    monkeypatch.setattr(tracking_settings, "RIGID_PREDICTION", "sideways")
    with pytest.raises(ValueError, match="RIGID_PREDICTION"):
        tracker._before()
