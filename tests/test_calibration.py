"""Calibration: board detection against OpenCV, the shared chessboard pairs (whose views do
not determine the focal length, and must say so), and recovery of a known rig from boards
rendered through its lens model."""

import warnings

import cv2
import numpy as np
import pytest
from data_paths import SHARED_DATA

from elastocap import Camera, InvalidInputError, Rig
from elastocap.pipeline.cli import main
from elastocap.stereo.board import BoardRenderer, CharucoTarget, Chessboard, random_board_poses, subpixel_rays
from elastocap.stereo.calibration import UnderdeterminedCalibrationWarning, calibrate_camera
from elastocap.stereo.calibration_cli import board_images
from elastocap.stereo.calibration_detect import find_charuco_corners, find_chessboard_corners
from elastocap.stereo.calibration_rig import calibrate_rig

CHESSBOARD = SHARED_DATA / "chessboard_stereo"
needs_chessboard = pytest.mark.skipif(not CHESSBOARD.is_dir(), reason="shared chessboard pairs not found")

# Recovery of a known rig of 3 cameras from 16 rendered board poses (320x240, noise 2 grey
# levels, corners found to ~0.08 px RMS). Observed on this set: focal lengths +0.14% to
# +0.22%, principal points within 0.41 px, lens maps within 0.71 px at the edge of the area
# the boards covered, relative rotations within 0.077 degrees, baselines within 0.14%. The
# tolerances leave a factor of 2 or more.
FOCAL_RTOL = 0.005  # fx, fy relative to their value
PRINCIPAL_POINT_ATOL = 1.5  # px
LENS_ATOL = 1.5  # px: largest difference of the lens maps (K and distortion) where boards were seen
ROTATION_ATOL_DEG = 0.2  # relative rotation between cameras
BASELINE_RTOL = 0.005  # camera centre distance error relative to the baseline
RMS_ATOL = 0.2  # px: reprojection RMS of a rendered set
# Our bundle adjustment and cv2.stereoCalibrate minimise the same cost: they agree to the
# optimisers' tolerances.
STEREO_T_RTOL = 1e-4
# The renderer's interpolated sub-pixel rays against exact projection (pixels).
RAY_ATOL = 1e-3


# --------------------------------------------------------------------------- shared pairs


def _shared_detections(board):
    images = board_images(CHESSBOARD)
    return {
        camera: {view: find_chessboard_corners(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), board) for view, path in views.items()}
        for camera, views in images.items()
    }


@needs_chessboard
def test_shared_pairs_detection_matches_opencv():
    board = Chessboard(7, 5)
    detections = _shared_detections(board)
    assert sorted(detections) == ["left", "right"]
    for camera, views in detections.items():
        assert len(views) == 14
        for view, found in views.items():
            assert found is not None, f"{camera}{view}"
            grey = cv2.imread(str(CHESSBOARD / f"{camera}{view}.jpg"), cv2.IMREAD_GRAYSCALE)
            ok, corners = cv2.findChessboardCorners(grey, (7, 5))
            assert ok
            # The detector's window: 0.4 of the smallest corner spacing.
            grid = corners.reshape(5, 7, 2)
            step = min(np.linalg.norm(np.diff(grid, axis=1), axis=2).min(), np.linalg.norm(np.diff(grid, axis=0), axis=2).min())
            half = int(np.clip(round(0.4 * step), 2, 11))
            refined = cv2.cornerSubPix(grey, corners, (half, half), (-1, -1), (3, 100, 1e-4)).reshape(-1, 2)
            # Same corners as OpenCV's, relabelled: each of ours is one of OpenCV's.
            distance = np.linalg.norm(found.corners[:, None] - refined[None], axis=2).min(axis=1)
            assert distance.max() < 1e-4
            # Canonical labels: corner 0 top-left, the rows run right, the columns down.
            grid = found.corners.reshape(5, 7, 2)
            assert grid[0, -1, 0] > grid[0, 0, 0] and grid[-1, 0, 1] > grid[0, 0, 1]


@needs_chessboard
def test_shared_pairs_warn_that_the_focal_length_is_not_determined():
    board = Chessboard(7, 5, 0.025)
    detections = _shared_detections(board)
    # What OpenCV alone makes of these views: focal lengths of 29 and 50 px (fields of view
    # near 160 degrees) with non-square pixels, different for two cameras of one rig.
    claimed = []
    for camera in ("left", "right"):
        views = list(detections[camera].values())
        _, K, *_ = cv2.calibrateCameraExtended(
            [board.object_points[v.ids].astype(np.float32) for v in views], [v.corners.astype(np.float32) for v in views],
            (320, 240), None, None,
        )
        claimed.append(K[0, 0])
    assert max(claimed) < 0.5 * 320 and max(claimed) > 1.5 * min(claimed)
    with pytest.warns(UnderdeterminedCalibrationWarning, match="do not determine the focal length") as caught:
        result = calibrate_rig(detections, board, (320, 240))
    assert len([w for w in caught if issubclass(w.category, UnderdeterminedCalibrationWarning)]) == 2
    for name in ("left", "right"):
        assert "focal" in result.cameras[name].fixed
        assert result.cameras[name].perspective < 20 * result.cameras[name].scatter
        assert result.rig[name].K[0, 0] == pytest.approx(320 / 2 / np.tan(np.radians(30)))
        assert np.isfinite(result.rms[name])
    assert result.world == "board:01"
    # A focal length from elsewhere is held instead of the guess.
    with pytest.warns(UnderdeterminedCalibrationWarning, match="the given focal_length"):
        given = calibrate_rig(detections, board, (320, 240), focal_length=400.0)
    assert given.rig["left"].K[0, 0] == 400.0


@needs_chessboard
def test_calibrate_command_on_the_shared_pairs(tmp_path, capsys):
    out = tmp_path / "rig"
    status = main(["calibrate", str(CHESSBOARD), "--board", "7x5", "--square-size", "0.025", "--out", str(out)])
    assert status == 0
    text = capsys.readouterr().out
    assert "left: RMS" in text and "right: RMS" in text
    assert "warning:" in text and "focal length" in text
    rig = Rig.load(out)
    assert rig.names == ["left", "right"]
    assert main(["calibrate", str(tmp_path), "--board", "7x5", "--out", str(tmp_path / "x")]) == 2


@pytest.mark.parametrize("board", ["1x1", "7x1", "seven", "7x"])
def test_a_bad_board_is_refused_naming_the_option(tmp_path, capsys, board):
    assert main(["calibrate", str(tmp_path), "--board", board, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert "--board" in err and board in err and "\n" not in err


# --------------------------------------------------------------------------- rendered rigs


def _known_rig():
    def camera(name, K, dist, rvec, centre):
        R = cv2.Rodrigues(np.asarray(rvec, float))[0]
        return Camera(name, K, dist, R, -R @ np.asarray(centre, float), 320, 240)

    return [
        camera("c0", [[330.0, 0, 162.0], [0, 328.0, 118.0], [0, 0, 1]], [-0.22, 0.07, 0.0008, -0.0005, 0], [0, 0, 0], [0, 0, 0]),
        camera("c1", [[315.0, 0, 157.0], [0, 317.0, 123.0], [0, 0, 1]], [-0.08, 0.02, -0.0004, 0.0006, 0], [0.02, 0.15, -0.01], [0.12, 0.005, 0.01]),
        camera("c2", [[340.0, 0, 165.0], [0, 338.0, 121.0], [0, 0, 1]], [-0.15, 0.03, 0, 0, 0], [-0.03, -0.12, 0.02], [-0.11, 0.01, 0.02]),
    ]


@pytest.fixture(scope="module")
def rendered_views():
    cameras = _known_rig()
    board = Chessboard(9, 6, 0.03)
    rng = np.random.default_rng(11)
    poses = random_board_poses(cameras, board, 16, rng=rng, distance=(0.5, 0.9), max_tilt=50)
    detections = {}
    for camera in cameras:
        renderer = BoardRenderer(camera)
        detections[camera.name] = {}
        for i, (R, t) in enumerate(poses):
            found = find_chessboard_corners(renderer.render(board, R, t, rng=rng), board)
            if found is not None:
                detections[camera.name][f"{i:02d}"] = found
    return cameras, board, poses, detections


def _lens_shift(estimated: Camera, truth: Camera, seen: np.ndarray) -> float:
    """Largest distance between where the estimated and the true intrinsics (K and
    distortion) put the same ray, over the pixels inside the hull of the corners ``seen``
    (beyond them the data say nothing about the lens), pixels."""
    v, u = np.mgrid[0 : truth.height : 4, 0 : truth.width : 4]
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).astype(float)
    hull = cv2.convexHull(seen.astype(np.float32))
    inside = np.array([cv2.pointPolygonTest(hull, (float(x), float(y)), False) >= 0 for x, y in pixels])
    pixels = pixels[inside]
    _, rays = truth.replace(R=np.eye(3), t=np.zeros(3)).rays(pixels)
    ours, _ = estimated.replace(R=np.eye(3), t=np.zeros(3)).project(rays)
    return float(np.linalg.norm(ours - pixels, axis=1).max())


def test_rendered_rig_is_recovered(rendered_views):
    cameras, board, poses, detections = rendered_views
    assert all(len(v) >= 14 for v in detections.values())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = calibrate_rig(detections, board, (320, 240))
    # Only unused higher-order distortion may be reported as undetermined, never the focal
    # length or the principal point.
    for w in caught:
        assert "focal length" not in str(w.message) and "principal point" not in str(w.message)
    first = sorted(detections["c0"])[0]
    R0, t0 = poses[int(first)]
    for truth in cameras:
        got = result.rig[truth.name]
        assert got.K[0, 0] == pytest.approx(truth.K[0, 0], rel=FOCAL_RTOL)
        assert got.K[1, 1] == pytest.approx(truth.K[1, 1], rel=FOCAL_RTOL)
        np.testing.assert_allclose(got.K[:2, 2], truth.K[:2, 2], atol=PRINCIPAL_POINT_ATOL)
        seen = np.concatenate([view.corners for view in detections[truth.name].values()])
        assert _lens_shift(got, truth, seen) < LENS_ATOL
        assert result.rms[truth.name] < RMS_ATOL
        # World frame = the first board: the true camera seen from that board.
        np.testing.assert_allclose(got.R, truth.R @ R0, atol=np.radians(ROTATION_ATOL_DEG))
    for a, b in ((0, 1), (0, 2), (1, 2)):
        ta, tb = cameras[a], cameras[b]
        ga, gb = result.rig[ta.name], result.rig[tb.name]
        relative = (gb.R @ ga.R.T) @ (tb.R @ ta.R.T).T
        assert np.degrees(np.linalg.norm(cv2.Rodrigues(relative)[0])) < ROTATION_ATOL_DEG
        true_baseline = np.linalg.norm(tb.center - ta.center)
        assert np.linalg.norm(gb.center - ga.center) == pytest.approx(true_baseline, rel=BASELINE_RTOL)


def test_bundle_adjustment_equals_stereo_calibrate(rendered_views):
    _, board, _, detections = rendered_views
    shared = sorted(set(detections["c0"]) & set(detections["c1"]))
    pair = {n: {v: detections[n][v] for v in shared} for n in ("c0", "c1")}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnderdeterminedCalibrationWarning)
        result = calibrate_rig(pair, board, (320, 240), world="c0")
    a, b = result.cameras["c0"], result.cameras["c1"]
    assert np.array_equal(result.rig["c0"].R, np.eye(3)) and np.array_equal(result.rig["c0"].t, np.zeros(3))
    # cv2.stereoCalibrate from our single-camera results, everything that was estimated free.
    flags = cv2.CALIB_USE_INTRINSIC_GUESS
    for name, flag in (("k3", cv2.CALIB_FIX_K3), ("k2", cv2.CALIB_FIX_K2), ("p1", cv2.CALIB_ZERO_TANGENT_DIST)):
        if name in a.fixed:
            assert name in b.fixed or name == "k2"
            flags |= flag
    if "k2" in a.fixed or "k2" in b.fixed:
        pytest.skip("distortion models differ between the two cameras")
    objects = [board.object_points[pair["c0"][v].ids].astype(np.float32) for v in shared]
    out = cv2.stereoCalibrate(
        objects, [pair["c0"][v].corners.astype(np.float32) for v in shared], [pair["c1"][v].corners.astype(np.float32) for v in shared],
        a.camera.K.copy(), a.camera.dist.copy(), b.camera.K.copy(), b.camera.dist.copy(), (320, 240),
        flags=flags, criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 500, 1e-14),
    )
    T = out[6].ravel()
    np.testing.assert_allclose(result.rig["c1"].t, T, rtol=0, atol=STEREO_T_RTOL * np.linalg.norm(T))
    np.testing.assert_allclose(result.rig["c1"].K, out[3], rtol=1e-4)


def test_views_without_perspective_are_detected(rendered_views):
    """Boards far away in one orientation (as in the shared pairs) look affine: the warning
    must come, and the focal length held at the given K; boards in many poses must not."""
    cameras, board, poses, detections = rendered_views
    camera = cameras[0]
    renderer = BoardRenderer(camera)
    rng = np.random.default_rng(3)
    facing = camera.R.T
    views = {}
    for i in range(8):
        tilt = cv2.Rodrigues(np.array([0.0, np.radians(1.0 + 0.1 * i), 0.0]))[0]
        R = facing @ tilt
        centre = camera.center + 1.6 * camera.R[2] + facing @ np.array([0.01 * i, -0.005 * i, 0.0])
        t = centre - R @ np.array([0.12, 0.075, 0.0])
        found = find_chessboard_corners(renderer.render(board, R, t, rng=rng), board)
        if found is not None:
            views[str(i)] = found
    assert len(views) >= 6
    with pytest.warns(UnderdeterminedCalibrationWarning, match="focal length"):
        held = calibrate_camera(views, board, (320, 240), K=camera.K)
    assert "focal" in held.fixed and held.camera.K[0, 0] == camera.K[0, 0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        free = calibrate_camera(detections[camera.name], board, (320, 240))
    assert "focal" not in free.fixed and not any("focal" in str(w.message) for w in caught)


def test_asymmetric_board_labels_follow_the_board():
    """A 9x6 board (no 180-degree symmetry) is labelled by its own pattern, whichever way up
    it is seen: each corner lands where its object point projects."""
    camera = _known_rig()[0]
    board = Chessboard(9, 6, 0.03)
    renderer = BoardRenderer(camera)
    rng = np.random.default_rng(4)
    for roll in (0.0, 90.0, 180.0, 250.0):
        spin = cv2.Rodrigues(np.array([0.0, 0.0, np.radians(roll)]))[0]
        R = camera.R.T @ cv2.Rodrigues(np.array([0.2, -0.3, 0.0]))[0] @ spin
        centre = camera.center + 0.75 * camera.R[2]
        t = centre - R @ np.array([0.12, 0.075, 0.0])
        found = find_chessboard_corners(renderer.render(board, R, t, rng=rng), board)
        assert found is not None
        truth, _ = camera.project(board.object_points[found.ids] @ R.T + t)
        assert np.abs(found.corners - truth).max() < 0.5, roll


def test_renderer_rays_are_exact():
    camera = Camera("c", [[420.0, 3.5, 205], [0, 415, 148], [0, 0, 1]], [-0.25, 0.08, 0.001, -0.0008, 0.01],
                    cv2.Rodrigues(np.array([0.1, -0.2, 0.05]))[0], [0.1, 0, 0], 160, 120)
    n = 3
    directions = subpixel_rays(camera, n)
    index = np.random.default_rng(0).integers(0, len(directions), 3000)
    pixel, sub = index // (n * n), index % (n * n)
    u = pixel % camera.width + (sub % n + 0.5) / n - 0.5
    v = pixel // camera.width + (sub // n + 0.5) / n - 0.5
    uv, _ = camera.project(camera.center + directions[index])
    np.testing.assert_allclose(uv, np.stack([u, v], axis=1), atol=RAY_ATOL)


@pytest.mark.skipif(not hasattr(cv2, "aruco"), reason="cv2.aruco missing")
def test_charuco_corners_are_found_with_their_ids():
    camera = _known_rig()[0]
    board = CharucoTarget(7, 5, 0.04, 0.03)
    rng = np.random.default_rng(2)
    (R, t), = random_board_poses([camera], board, 1, rng=rng, distance=(0.45, 0.6), max_tilt=30)
    found = find_charuco_corners(BoardRenderer(camera).render(board, R, t, rng=rng), board)
    assert found is not None and len(found.ids) >= 20
    truth, _ = camera.project(board.object_points[found.ids] @ R.T + t)
    assert np.sqrt(np.mean((found.corners - truth) ** 2)) < 0.15


def test_calibration_rejects_bad_input(rendered_views):
    _, board, _, detections = rendered_views
    with pytest.raises(InvalidInputError, match="no view"):
        calibrate_camera({}, board, (320, 240))
    lonely = {"c0": detections["c0"], "c1": {"zz": next(iter(detections["c1"].values()))}}
    lonely["c1"] = {f"x{k}": v for k, v in detections["c1"].items()}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnderdeterminedCalibrationWarning)
        with pytest.raises(InvalidInputError, match="share no view"):
            calibrate_rig(lonely, board, (320, 240))
    with pytest.raises(InvalidInputError, match="world"):
        calibrate_rig(detections, board, (320, 240), world="nobody")
