"""Stereo: board calibration, rectification with elastocap's camera model (skew and
distortion), SGBM disparity with a left-right check, and disparity -> world points and masks."""

from elastocap.stereo.board import BoardRenderer, CharucoTarget, Chessboard, random_board_poses
from elastocap.stereo.calibration import CameraCalibration, UnderdeterminedCalibrationWarning, calibrate_camera
from elastocap.stereo.calibration_detect import BoardView, find_board, find_charuco_corners, find_chessboard_corners
from elastocap.stereo.calibration_rig import RigCalibration, calibrate_rig, calibrate_stereo

__all__ = [
    "BoardRenderer",
    "BoardView",
    "CameraCalibration",
    "CharucoTarget",
    "Chessboard",
    "RigCalibration",
    "UnderdeterminedCalibrationWarning",
    "calibrate_camera",
    "calibrate_rig",
    "calibrate_stereo",
    "find_board",
    "find_charuco_corners",
    "find_chessboard_corners",
    "random_board_poses",
]
