"""Capture folders: images, masks, videos and backgrounds per camera, read lazily."""

from elastocap.capture.folder import Capture

__all__ = ["Capture"]
