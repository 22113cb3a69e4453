"""Cameras and rigs: the pinhole camera with OpenCV distortion and skew, rigs of named
cameras, and the calibration file formats they load from and save to."""

from elastocap.cameras.camera import Camera
from elastocap.cameras.checks import CalibrationWarning
from elastocap.cameras.rig import Rig

__all__ = ["CalibrationWarning", "Camera", "Rig"]
