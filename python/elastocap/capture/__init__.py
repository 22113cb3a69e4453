"""Capture folders: images, masks, videos and backgrounds per camera, read lazily; frame
offsets and missing frames set in ``capture.toml``."""

from elastocap.capture.config import CaptureWarning
from elastocap.capture.folder import Capture

__all__ = ["Capture", "CaptureWarning"]
