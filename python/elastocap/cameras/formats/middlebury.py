"""Middlebury multi-view ``*_par.txt``: a camera count, then one line per image
``name.png k11 k12 k13 k21 k22 k23 k31 k32 k33 r11 .. r33 t1 t2 t3`` (P = K [R | t]).

Camera names are the image names' stems; the image size is not in the file (it comes from
the image beside it, or ``size=``). No distortion: a camera with distortion is refused on
writing. The full K (skew too) is kept, exactly (shortest exact decimals)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from elastocap._core import InvalidInputError
from elastocap._io import save_text
from elastocap.cameras.formats.common import (
    CameraRecord,
    file_image_size,
    number,
    settle_size,
)

if TYPE_CHECKING:
    from elastocap.cameras.camera import Camera

__all__ = ["read", "write"]

NAME = "middlebury"


def read(file: Path, size: tuple[int, int] | None) -> list[CameraRecord]:
    """A Middlebury multi-view ``*_par.txt``: a count, then ``name.png k11 .. k33 r11 .. r33
    t1 t2 t3`` per camera; the size from the image beside the file."""
    try:
        lines = [line for line in file.read_text().splitlines() if line.strip()]
    except UnicodeDecodeError as error:
        raise InvalidInputError(f"{file}: not a text file ({error})") from None
    if not lines:
        raise InvalidInputError(f"{file}: empty, expected a camera count and one line per camera")
    try:
        count = int(lines[0])
    except ValueError:
        raise InvalidInputError(f"{file}: line 1 must be the camera count, got {lines[0]!r}") from None
    if count != len(lines) - 1:
        raise InvalidInputError(f"{file}: line 1 says {count} cameras, but {len(lines) - 1} lines follow")
    cameras: list[CameraRecord] = []
    for line_number, line in enumerate(lines[1:], start=2):
        fields = line.split()
        where = f"{file}, line {line_number}"
        if len(fields) != 22:
            raise InvalidInputError(
                f"{where}: expected an image name and 21 numbers (K, R, t), got {len(fields)} fields"
            )
        try:
            values = np.array([float(v) for v in fields[1:]])
        except ValueError as error:
            raise InvalidInputError(f"{where}: malformed number ({error})") from None
        image = file.parent / fields[0]
        name = Path(fields[0]).stem
        image_size = file_image_size(image) if image.exists() else None
        w, h = settle_size(name, None, image_size, size, file)
        cameras.append(
            CameraRecord(name, values[:9].reshape(3, 3), None, values[9:18].reshape(3, 3), values[18:], w, h, where)
        )
    return cameras


def write(file: Path, cameras: Sequence[Camera]) -> None:
    """``file`` in the Middlebury layout, one line ``<name>.png K R t`` per camera; refuses
    cameras with distortion (the format has none)."""
    for camera in cameras:
        if camera.has_distortion:
            raise InvalidInputError(
                f"camera {camera.name!r} has distortion {camera.dist.tolist()}, which the "
                "Middlebury *_par.txt format cannot hold (it stores K, R and t only)"
            )
        if any(ch.isspace() for ch in camera.name):
            raise InvalidInputError(
                f"camera {camera.name!r}: a Middlebury image name cannot hold white space"
            )
    lines = [str(len(cameras))]
    for camera in cameras:
        values = np.concatenate([camera.K.ravel(), camera.R.ravel(), camera.t])
        lines.append(" ".join([f"{camera.name}.png", *map(number, values)]))
    save_text(file, "\n".join(lines) + "\n")
