"""Reading a capture's pixels: colour frames and masks from image files of any common bit
depth and channel count, and videos through OpenCV (PyAV, when installed, for files OpenCV
cannot open).

Colour (``read_colour``): 8-bit as is; 16-bit scaled to 8 bits (``round(v / 257)``, so 65535
-> 255); float images taken as 0..1 and scaled; grey expanded to three equal channels; an
alpha channel dropped. Masks (``mask_from_pixels``): non-zero = foreground in any colour
channel; an RGBA file whose alpha is not all opaque is a cut-out, and its alpha is the
mask; JPEG files and video frames are thresholded at half range instead, because
compression makes zero noisy.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError

__all__ = ["Video", "mask_from_pixels", "read_colour", "read_pixels", "to_uint8"]


def read_pixels(file: Path) -> NDArray[Any]:
    """The file's pixels as stored (any depth, grey / BGR / BGRA)."""
    data = cv2.imread(str(file), cv2.IMREAD_UNCHANGED)
    if data is None:
        raise InvalidInputError(f"{file}: unreadable image")
    return np.asarray(data)


def to_uint8(data: NDArray[Any], where: Path | str) -> NDArray[np.uint8]:
    """Pixels of any supported depth as 8-bit (see the module notes)."""
    if data.dtype == np.uint8:
        return data
    if data.dtype == np.uint16:
        return ((data.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
    if data.dtype.kind == "f":
        return np.round(np.clip(np.nan_to_num(data), 0.0, 1.0) * 255).astype(np.uint8)
    raise InvalidInputError(f"{where}: pixels of type {data.dtype} are not supported (8- or 16-bit, or float 0..1)")


def read_colour(file: Path) -> NDArray[np.uint8]:
    """(H, W, 3) uint8 RGB of an image file of any supported depth and channel count."""
    return bgr_to_rgb(to_uint8(read_pixels(file), file))


def bgr_to_rgb(data: NDArray[np.uint8]) -> NDArray[np.uint8]:
    if data.ndim == 2:
        return np.ascontiguousarray(np.repeat(data[:, :, None], 3, axis=2))
    if data.shape[2] == 1:
        return np.ascontiguousarray(np.repeat(data, 3, axis=2))
    return np.ascontiguousarray(data[:, :, 2::-1])


def mask_from_pixels(data: NDArray[Any], *, noisy: bool) -> NDArray[np.bool_]:
    """(H, W) bool of a mask's pixels (see the module notes); ``noisy`` for compressed
    sources, thresholded at half range."""
    if data.ndim == 3 and data.shape[2] == 4:
        alpha = data[:, :, 3]
        opaque = np.iinfo(data.dtype).max if data.dtype.kind in "ui" else 1.0
        if (alpha != opaque).any():
            data = alpha
        else:
            data = data[:, :, :3]
    if data.ndim == 3:
        data = data.max(axis=2)
    if noisy:
        half = (np.iinfo(data.dtype).max + 1) // 2 if data.dtype.kind in "ui" else 0.5
        return np.asarray(data >= half)
    return np.asarray(data != 0)


class Video:
    """A video file read frame by frame: OpenCV first, PyAV (``pip install av``) when
    OpenCV cannot open the file and PyAV is installed. Frames are BGR uint8."""

    def __init__(self, file: Path) -> None:
        self.file = file
        self._opencv: cv2.VideoCapture | None = None
        self._av: Any = None
        self._position = 0
        capture = cv2.VideoCapture(str(file))
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) if capture.isOpened() else -1
        if count > 0:
            self._opencv, self.count = capture, count
            return
        capture.release()
        try:
            import av
        except ImportError:
            raise InvalidInputError(
                f"{file}: unreadable video (OpenCV cannot open it; installing PyAV, pip install av, "
                "lets elastocap try FFmpeg's decoders)"
            ) from None
        try:
            container = av.open(str(file))
            frames = sum(1 for _ in container.decode(video=0))
            container.close()
        except (av.error.FFmpegError, IndexError, ValueError) as error:
            raise InvalidInputError(f"{file}: unreadable video (neither OpenCV nor PyAV: {error})") from None
        if frames == 0:
            raise InvalidInputError(f"{file}: the video has no frames")
        self.count = frames

    def frame(self, index: int) -> NDArray[np.uint8]:
        """Frame ``index`` (0-based), BGR uint8; ``InvalidInputError`` when it cannot be
        decoded."""
        if self._opencv is not None:
            if self._position != index:
                self._opencv.set(cv2.CAP_PROP_POS_FRAMES, index)
            ok, bgr = self._opencv.read()
            self._position = index + 1
            if not ok or bgr is None:
                raise InvalidInputError(f"{self.file}: could not decode frame {index}")
            return np.asarray(bgr)
        return self._av_frame(index)

    def _av_frame(self, index: int) -> NDArray[np.uint8]:
        import av

        if self._av is None or self._position > index:
            if self._av is not None:
                self._av[0].close()
            container = av.open(str(self.file))
            self._av = (container, container.decode(video=0))
            self._position = 0
        try:
            while True:
                frame = next(self._av[1])
                self._position += 1
                if self._position - 1 == index:
                    return np.asarray(frame.to_ndarray(format="bgr24"))
        except (StopIteration, av.error.FFmpegError):
            raise InvalidInputError(f"{self.file}: could not decode frame {index}") from None

    def close(self) -> None:
        if self._opencv is not None:
            self._opencv.release()
        if self._av is not None:
            self._av[0].close()
            self._av = None
