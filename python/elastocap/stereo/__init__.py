"""Stereo: board calibration, rectification with elastocap's camera model (skew and
distortion), SGBM disparity with a left-right check, disparity -> world points and masks;
least-squares matching, dense matching by region growing and forward intersection (SPEC 7),
dense points of a pair."""

from elastocap.stereo.board import BoardRenderer, CharucoTarget, Chessboard, random_board_poses
from elastocap.stereo.calibration import CameraCalibration, UnderdeterminedCalibrationWarning, calibrate_camera
from elastocap.stereo.calibration_detect import BoardView, find_board, find_charuco_corners, find_chessboard_corners
from elastocap.stereo.calibration_rig import RigCalibration, calibrate_rig, calibrate_stereo
from elastocap.stereo.disparity import DisparityMap, DisparityWarning, compute_disparity, disparity_range
from elastocap.stereo.disparity_stage import PairDisparity, disparity_mask, disparity_to_points, pair_disparity, write_disparity
from elastocap.stereo.rectify import RectifiedPair, rectify_pair
from elastocap.stereo.intersection import Intersection, intersect, match_observations
from elastocap.stereo.matching import PARAMETERS, Matches, MatchStatus, match_patches, noise_level
from elastocap.stereo.dense import DenseMatches, grow_matches
from elastocap.stereo.points import PairPoints, pair_points

__all__ = [
    "BoardRenderer",
    "BoardView",
    "CameraCalibration",
    "CharucoTarget",
    "Chessboard",
    "DisparityMap",
    "DisparityWarning",
    "PairDisparity",
    "RectifiedPair",
    "RigCalibration",
    "UnderdeterminedCalibrationWarning",
    "calibrate_camera",
    "calibrate_rig",
    "calibrate_stereo",
    "compute_disparity",
    "disparity_mask",
    "disparity_range",
    "disparity_to_points",
    "find_board",
    "find_charuco_corners",
    "find_chessboard_corners",
    "pair_disparity",
    "random_board_poses",
    "rectify_pair",
    "write_disparity",
    "Intersection",
    "intersect",
    "match_observations",
    "PARAMETERS",
    "MatchStatus",
    "Matches",
    "match_patches",
    "noise_level",
    "DenseMatches",
    "grow_matches",
    "PairPoints",
    "pair_points",
]
