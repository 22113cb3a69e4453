"""Rectification through elastocap's camera model: exact geometry, remap tables, and the
vertical disparity of chessboard corners found in rectified images of a skewed, distorted
pair (where OpenCV's stereoRectify, which ignores skew, misplaces them)."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from elastocap import Camera, InvalidInputError
from elastocap.stereo.board import BoardRenderer, Chessboard, random_board_poses
from elastocap.stereo.calibration_detect import find_chessboard_corners
from elastocap.stereo.rectify import rectify_pair

# Rows of corresponding points in the rectified frame agree to rounding (pixels): the
# rectified cameras share rotation, focal length and cy by construction.
ANALYTIC_ATOL = 1e-8
# The remap tables, bilinearly interpolated between pixel centres, against the exact map
# (pixels): the map is smooth and nearly linear over a pixel.
MAP_ATOL = 0.01
# Corners found by OpenCV in the rectified images (noise 2 grey levels, 3x3 supersampled
# renders, cornerSubPix): RMS vertical disparity and RMS distance to the exact rectified
# projection of the true corners, pixels. The issue asks for < 0.1 px.
VERTICAL_RMS = 0.1
POSITION_RMS = 0.1


def _look_at(centre, target, roll=0.0):
    z = np.asarray(target, float) - centre
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    R = cv2.Rodrigues(np.array([0.0, 0.0, roll]))[0] @ R
    return R, -R @ np.asarray(centre, float)


def skewed_pair():
    """A converging pair with skew (1.5% of the focal length) and barrel distortion."""
    target = np.array([0.0, 0.0, 0.6])
    Ra, ta = _look_at(np.array([-0.06, 0.0, 0.0]), target, 0.02)
    Rb, tb = _look_at(np.array([0.07, 0.01, 0.01]), target, -0.03)
    a = Camera("a", [[420.0, 6.3, 205.0], [0, 415.0, 148.0], [0, 0, 1]], [-0.25, 0.08, 0.001, -0.0008, 0.0], Ra, ta, 400, 300)
    b = Camera("b", [[400.0, -6.0, 195.0], [0, 402.0, 152.0], [0, 0, 1]], [-0.1, 0.02, 0.0005, 0.0002, 0.0], Rb, tb, 400, 300)
    return a, b


def _random_points(n, seed=0):
    return np.random.default_rng(seed).uniform([-0.15, -0.12, 0.45], [0.15, 0.12, 0.8], (n, 3))


def test_rectified_rows_agree_exactly():
    a, b = skewed_pair()
    pair = rectify_pair(a, b)
    X = _random_points(2000)
    left = pair.to_rectified("left", pair.left.project(X)[0])
    right = pair.to_rectified("right", pair.right.project(X)[0])
    assert np.abs(left[:, 1] - right[:, 1]).max() < ANALYTIC_ATOL
    # ... and they are the rectified cameras' own projections.
    assert np.abs(left - pair.left_rectified.project(X)[0]).max() < 1e-6
    # Disparity is f B / Z + (cx_left - cx_right), positive depth -> the right camera is on the right.
    depth = (X - pair.left.center) @ pair.rotation[2]
    expected = pair.focal * pair.baseline / depth + pair.disparity_offset
    np.testing.assert_allclose(left[:, 0] - right[:, 0], expected, atol=1e-6)


def test_pair_order_and_upright():
    a, b = skewed_pair()
    forward, backward = rectify_pair(a, b), rectify_pair(b, a)
    assert forward.left.name == backward.left.name == "a"
    assert backward.swapped and not forward.swapped
    # Upright: the rectified y axis points along the cameras' own y axes.
    assert forward.rotation[1] @ a.R[1] > 0.9
    R = forward.rotation
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_remap_tables_match_the_exact_map():
    a, b = skewed_pair()
    pair = rectify_pair(a, b)
    X = _random_points(500, seed=1)
    for side, original, (mx, my) in (("left", pair.left, pair.maps[0]), ("right", pair.right, pair.maps[1])):
        rect = (pair.left_rectified if side == "left" else pair.right_rectified).project(X)[0]
        inside = (rect >= 1).all(axis=1) & (rect[:, 0] < pair.size[0] - 2) & (rect[:, 1] < pair.size[1] - 2)
        points = rect[inside].astype(np.float32).reshape(-1, 1, 2)
        sampled = np.hstack([
            cv2.remap(mx, points, None, cv2.INTER_LINEAR).reshape(-1, 1),
            cv2.remap(my, points, None, cv2.INTER_LINEAR).reshape(-1, 1),
        ])
        np.testing.assert_allclose(sampled, original.project(X[inside])[0], atol=MAP_ATOL)


def _opencv_rectification(pair):
    """OpenCV's own rectification of the same pair (which ignores the skew)."""
    R = pair.right.R @ pair.left.R.T
    T = pair.right.t - R @ pair.left.t
    size = pair.left.size
    R1, R2, P1, P2, *_ = cv2.stereoRectify(
        pair.left.K.copy(), pair.left.dist.reshape(1, 5).copy(), pair.right.K.copy(), pair.right.dist.reshape(1, 5).copy(),
        size, R.copy(), T.reshape(3, 1).copy(), alpha=1,
    )
    maps = [
        cv2.initUndistortRectifyMap(c.K, c.dist, Ri, Pi, size, cv2.CV_32FC1)
        for c, Ri, Pi in ((pair.left, R1, P1), (pair.right, R2, P2))
    ]

    def project(P, X):
        # P1 and P2 both take points in the first camera's rectified frame.
        x = (X @ pair.left.R.T + pair.left.t) @ R1.T
        uv = x @ P[:, :3].T + P[:, 3]
        return uv[:, :2] / uv[:, 2:]

    return maps, (lambda X: project(P1, X)), (lambda X: project(P2, X))


def test_chessboard_rows_in_rectified_images():
    a, b = skewed_pair()
    pair = rectify_pair(a, b)
    board = Chessboard(9, 6, 0.02)
    renderers = (BoardRenderer(pair.left), BoardRenderer(pair.right))
    rng = np.random.default_rng(5)
    poses = random_board_poses([pair.left, pair.right], board, 6, rng=rng, distance=(0.35, 0.55), max_tilt=35)
    (m1, m2), project_left, project_right = _opencv_rectification(pair)
    ours_dv, ours_pos, cv_pos = [], [], []
    for R, t in poses:
        left = renderers[0].render(board, R, t, rng=rng)
        right = renderers[1].render(board, R, t, rng=rng)
        X = board.object_points @ R.T + t
        rect_left, rect_right = pair.rectify(left, right)
        found_left, found_right = find_chessboard_corners(rect_left, board), find_chessboard_corners(rect_right, board)
        assert found_left is not None and found_right is not None
        ours_dv.append(found_left.corners[:, 1] - found_right.corners[:, 1])
        ours_pos.append(found_left.corners - pair.left_rectified.project(X)[0])
        ours_pos.append(found_right.corners - pair.right_rectified.project(X)[0])
        cv_left = find_chessboard_corners(cv2.remap(left, *m1, cv2.INTER_LINEAR), board)
        cv_right = find_chessboard_corners(cv2.remap(right, *m2, cv2.INTER_LINEAR), board)
        if cv_left is not None and cv_right is not None:  # OpenCV's crop may cut the board
            cv_pos.append(cv_left.corners - project_left(X))
            cv_pos.append(cv_right.corners - project_right(X))
    rms = lambda e: float(np.sqrt(np.mean(np.concatenate(e) ** 2)))  # noqa: E731
    assert rms(ours_dv) < VERTICAL_RMS
    assert rms(ours_pos) < POSITION_RMS
    assert len(cv_pos) >= 4
    # OpenCV drops K[0, 1]: its rectified images put the corners several times further
    # from where its own rectified cameras say they are.
    assert rms(cv_pos) > 3 * rms(ours_pos)


def test_rectify_checks_its_input():
    a, b = skewed_pair()
    with pytest.raises(InvalidInputError, match="same centre"):
        rectify_pair(a, a.replace(name="c"))
    away = b.replace(R=cv2.Rodrigues(np.array([0.0, np.pi, 0.0]))[0] @ a.R, t=-(cv2.Rodrigues(np.array([0.0, np.pi, 0.0]))[0] @ a.R) @ np.array([0.1, 0, 0]))
    with pytest.raises(InvalidInputError, match="no overlap"):
        rectify_pair(a, away)
    pair = rectify_pair(a, b)
    with pytest.raises(InvalidInputError, match="left_image"):
        pair.rectify(np.zeros((10, 10), np.uint8), np.zeros((300, 400), np.uint8))


@settings(max_examples=25)
@given(
    yaw=st.floats(-0.3, 0.3), pitch=st.floats(-0.2, 0.2), roll=st.floats(-0.3, 0.3),
    baseline=st.floats(0.02, 0.5), skew=st.floats(-8, 8), k1=st.floats(-0.3, 0.1),
)
def test_rectification_is_exact_for_random_pairs(yaw, pitch, roll, baseline, skew, k1):
    a = Camera("a", [[500.0, skew, 320.0], [0, 495.0, 240.0], [0, 0, 1]], [k1, 0.01, 0, 0, 0], np.eye(3), np.zeros(3), 640, 480)
    R = cv2.Rodrigues(np.array([pitch, yaw, roll]))[0]
    b = Camera("b", [[480.0, -skew, 330.0], [0, 482.0, 235.0], [0, 0, 1]], [k1 / 2, 0, 0, 0, 0], R, -R @ np.array([baseline, 0.01, 0.0]), 640, 480)
    pair = rectify_pair(a, b)
    X = np.random.default_rng(0).uniform([-0.5, -0.4, 2.0], [0.5, 0.4, 4.0], (300, 3))
    seen = a.visible(X) & b.visible(X)
    left = pair.to_rectified("left", pair.left.project(X[seen])[0])
    right = pair.to_rectified("right", pair.right.project(X[seen])[0])
    ok = np.isfinite(left).all(axis=1) & np.isfinite(right).all(axis=1)
    assert np.abs(left[ok, 1] - right[ok, 1]).max(initial=0.0) < 1e-7
