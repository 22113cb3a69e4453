"""What every calibration format shares: the unvalidated camera record a reader returns,
image sizes (from the file, the images beside it or the caller), exact number printing,
and the refusals of what a format cannot hold."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import cv2
import numpy as np

from elastocap._core import InvalidInputError

if TYPE_CHECKING:
    from elastocap.cameras.camera import Camera

__all__ = [
    "IMAGE_SUFFIXES",
    "VIDEO_SUFFIXES",
    "CameraRecord",
    "file_image_size",
    "number",
    "refuse_distortion_beyond",
    "refuse_skew",
    "settle_size",
    "size_from_capture",
]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov")


@dataclass(frozen=True)
class CameraRecord:
    """One camera's fields as read from a file, not yet validated."""

    name: Any
    K: Any
    dist: Any
    R: Any
    t: Any
    width: Any
    height: Any
    where: str


def number(value: float) -> str:
    """``value`` in the shortest decimal form that reads back to the same double."""
    return repr(float(value))


def refuse_skew(cameras: Sequence[Camera], fmt: str) -> None:
    """Refuse cameras with a skewed K for a format whose intrinsics have no skew."""
    for camera in cameras:
        if camera.K[0, 1] != 0.0:
            raise InvalidInputError(
                f"camera {camera.name!r} has skew K[0, 1] = {float(camera.K[0, 1])!r}, which the {fmt} "
                "format cannot hold"
            )


def refuse_distortion_beyond(cameras: Sequence[Camera], count: int, fmt: str, names: str) -> None:
    """Refuse cameras with a non-zero distortion coefficient past the first ``count``."""
    from elastocap.cameras.distortion import NAMES

    for camera in cameras:
        extra = [(NAMES[i], float(v)) for i, v in enumerate(camera.dist) if i >= count and v != 0.0]
        if extra:
            listed = ", ".join(f"{n} = {v!r}" for n, v in extra)
            raise InvalidInputError(
                f"camera {camera.name!r} has distortion {listed}, which the {fmt} format cannot "
                f"hold (it stores {names})"
            )


def settle_size(
    name: str,
    file_size: tuple[Any, Any] | None,
    image_size: tuple[int, int] | None,
    size: tuple[int, int] | None,
    file: Path | str,
) -> tuple[Any, Any]:
    """The one image size of camera ``name`` from the calibration file, its images and the
    ``size`` argument, which must agree where several are given."""
    if size is not None and (not isinstance(size, (tuple, list)) or len(size) != 2):
        raise InvalidInputError(f"size must be (width, height), got {size!r}")
    candidates = [
        (source, value)
        for source, value in (("the calibration", file_size), ("its images", image_size), ("size", size))
        if value is not None
    ]
    if not candidates:
        raise InvalidInputError(
            f"{file}: camera {name!r}: image size unknown (not in the file, no image beside it): "
            "pass size=(width, height)"
        )
    first_source, first = candidates[0]
    for source, value in candidates[1:]:
        if tuple(value) != tuple(first):
            raise InvalidInputError(
                f"{file}: camera {name!r}: image size {tuple(first)} from {first_source} "
                f"disagrees with {tuple(value)} from {source}"
            )
    return first[0], first[1]


def size_from_capture(folder: Path, name: str) -> tuple[int, int] | None:
    """(width, height) of camera ``name``'s first image, mask, background or video in a
    capture folder, or None when there is none."""
    for sub in ("images", "masks", "mask"):
        directory = folder / sub / name
        if directory.is_dir():
            files = sorted(p for p in directory.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if files:
                return file_image_size(files[0])
    for suffix in IMAGE_SUFFIXES:
        background = folder / "background" / f"{name}{suffix}"
        if background.exists():
            return file_image_size(background)
    for sub in ("videos", "masks", "mask"):
        for suffix in VIDEO_SUFFIXES:
            video = folder / sub / f"{name}{suffix}"
            if video.is_file():
                return _video_size(video)
    return None


def _video_size(video: Path) -> tuple[int, int]:
    capture = cv2.VideoCapture(str(video))
    try:
        if capture.isOpened():
            width = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH))
            height = int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
            if width > 0 and height > 0:
                return width, height
    finally:
        capture.release()
    raise InvalidInputError(f"{video}: unreadable video (cannot tell the image size)")


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def file_image_size(file: Path) -> tuple[int, int]:
    """(width, height) of an image file: from the PNG header when it is one (no decoding),
    else by reading the image."""
    with open(file, "rb") as handle:
        head = handle.read(24)
    if head[:8] == _PNG_SIGNATURE and head[12:16] == b"IHDR":
        width, height = struct.unpack(">II", head[16:24])
        return int(width), int(height)
    image = cv2.imread(str(file), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InvalidInputError(f"{file}: unreadable image (cannot tell the image size)")
    return int(image.shape[1]), int(image.shape[0])
