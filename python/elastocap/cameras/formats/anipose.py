"""Anipose / Pose2Sim ``calib.toml``: one table per camera, ``[cam_0]``, ``[cam_1]``, ...::

    [cam_0]
    name = "A"
    size = [1280, 1024]                      # width, height (pixels)
    matrix = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    distortions = [k1, k2, p1, p2, k3]       # OpenCV order; Pose2Sim writes 4
    rotation = [rx, ry, rz]                  # Rodrigues vector, world -> camera
    translation = [tx, ty, tz]               # world -> camera, in the calibration's units
    fisheye = false                          # optional; true is refused

plus an optional ``[metadata]`` table, which is ignored on reading and written as
``adjusted = false, error = 0.0``. Units: anipose's are those of its board's square size
(often millimetres), Pose2Sim's metres; say which with ``Rig.load(..., units=...)``.

The rotation is a Rodrigues vector, so a round trip changes R by rounding only (a few units
in the last place); everything else round-trips exactly. Read with the standard library's
``tomllib`` (``tomli`` before Python 3.11); written by hand.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import cv2
import numpy as np

from elastocap._core import InvalidInputError
from elastocap._io import save_text
from elastocap.cameras.formats.common import CameraRecord, number, settle_size

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

if TYPE_CHECKING:
    from elastocap.cameras.camera import Camera

__all__ = ["read", "write"]

NAME = "anipose"


def read(file: Path, size: tuple[int, int] | None) -> list[CameraRecord]:
    """The cameras of an Anipose / Pose2Sim ``calib.toml``, in the file's order."""
    try:
        document = tomllib.loads(file.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise InvalidInputError(f"{file}: not valid TOML ({error})") from None
    cameras: list[CameraRecord] = []
    for key, table in document.items():
        if key == "metadata" or not isinstance(table, dict):
            continue
        where = f"{file}: [{key}]"
        missing = [field for field in ("matrix", "rotation", "translation") if field not in table]
        if missing:
            raise InvalidInputError(f"{where} lacks {', '.join(missing)}")
        if table.get("fisheye", False):
            raise InvalidInputError(
                f"{where}: fisheye = true: the fisheye lens model is not supported (elastocap models "
                "OpenCV's pinhole distortion)"
            )
        name = table.get("name", key)
        if not isinstance(name, str):
            name = str(name)
        file_size = None
        if "size" in table:
            value = table["size"]
            if not isinstance(value, list) or len(value) != 2:
                raise InvalidInputError(f"{where}: size must be [width, height], got {value!r}")
            file_size = (value[0], value[1])
        w, h = settle_size(name, file_size, None, size, where)
        R = _rotation(table["rotation"], where)
        cameras.append(
            CameraRecord(name, table["matrix"], table.get("distortions"), R, table["translation"], w, h, where)
        )
    if not cameras:
        raise InvalidInputError(f"{file}: no camera table (expected [cam_0] with matrix, rotation, translation)")
    return cameras


def _rotation(value: Any, where: str) -> np.ndarray:
    try:
        vector = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{where}: rotation must be a Rodrigues vector [rx, ry, rz], got {value!r}") from None
    if vector.size == 9:  # some exporters write the matrix itself
        return vector.reshape(3, 3)
    if vector.size != 3 or not np.isfinite(vector).all():
        raise InvalidInputError(f"{where}: rotation must be a finite Rodrigues vector [rx, ry, rz], got {value!r}")
    return np.asarray(cv2.Rodrigues(vector.reshape(3, 1))[0], dtype=np.float64)


def toml_string(text: str) -> str:
    """A TOML basic string: quotes, backslashes and control characters escaped."""
    out = ['"']
    for char in text:
        code = ord(char)
        if char in '"\\':
            out.append("\\" + char)
        elif code < 0x20 or code == 0x7F:
            out.append(f"\\u{code:04x}")
        else:
            out.append(char)
    out.append('"')
    return "".join(out)


def _array(values: Any) -> str:
    return "[" + ", ".join(number(v) for v in np.asarray(values, dtype=np.float64).ravel()) + "]"


def write(file: Path, cameras: Sequence[Camera]) -> None:
    """``file`` as a ``calib.toml``, one ``[cam_<i>]`` table per camera in rig order."""
    lines: list[str] = []
    for index, camera in enumerate(cameras):
        rvec = np.asarray(cv2.Rodrigues(np.array(camera.R))[0], dtype=np.float64).ravel()
        matrix = "[" + ", ".join(_array(row) for row in camera.K) + "]"
        lines += [
            f"[cam_{index}]",
            f"name = {toml_string(camera.name)}",
            f"size = [{camera.width}, {camera.height}]",
            f"matrix = {matrix}",
            f"distortions = {_array(camera.dist)}",
            f"rotation = {_array(rvec)}",
            f"translation = {_array(camera.t)}",
            "",
        ]
    lines += ["[metadata]", "adjusted = false", "error = 0.0", ""]
    save_text(file, "\n".join(lines))
