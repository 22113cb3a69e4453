"""COLMAP sparse models, binary (``cameras.bin`` + ``images.bin``), little-endian as COLMAP
writes them. Models, names and conventions as in :mod:`.colmap` (the text model).

The principal point is stored as a double in COLMAP's corner-origin convention, so
``cx_colmap = cx + 0.5`` is rounded once on writing: exact unless ``cx + 0.5`` needs one
more bit than ``cx`` (``cx`` just below a power of two with its last bit set), where it is
off by one unit in the last place (about 1e-13 px). The text model is exact always.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, Sequence

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._io import save_bytes
from elastocap.cameras.formats.colmap import (
    MODEL_BY_ID,
    MODELS,
    UNSUPPORTED,
    choose_model,
    intrinsics_from_params,
    params_of,
    quaternion_from_rotation,
    records,
)
from elastocap.cameras.formats.common import CameraRecord

if TYPE_CHECKING:
    from elastocap.cameras.camera import Camera

__all__ = ["read", "write"]

NAME = "colmap-binary"


class _Reader:
    """Little-endian fields of a binary file, with an error naming the file on a short
    read."""

    def __init__(self, handle: BinaryIO, file: Path) -> None:
        self.handle, self.file = handle, file

    def unpack(self, fmt: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        data = self.handle.read(size)
        if len(data) != size:
            raise InvalidInputError(f"{self.file}: truncated (ends inside a record)")
        return struct.unpack("<" + fmt, data)

    def name(self) -> str:
        chars = bytearray()
        while (byte := self.handle.read(1)) != b"\x00":
            if not byte:
                raise InvalidInputError(f"{self.file}: truncated (ends inside an image name)")
            chars += byte
        try:
            return chars.decode("utf-8")
        except UnicodeDecodeError:
            raise InvalidInputError(f"{self.file}: an image name is not UTF-8") from None


def read(folder: Path, size: tuple[int, int] | None) -> list[CameraRecord]:
    """``folder/cameras.bin`` + ``folder/images.bin``."""
    cameras_file, images_file = folder / "cameras.bin", folder / "images.bin"
    for file in (cameras_file, images_file):
        if not file.exists():
            raise FileNotFoundError(f"COLMAP model file missing: {file}")
    intrinsics: dict[int, tuple[NDArray[np.float64], NDArray[np.float64], int, int]] = {}
    with open(cameras_file, "rb") as handle:
        reader = _Reader(handle, cameras_file)
        (count,) = reader.unpack("Q")
        for index in range(count):
            camera_id, model_id, width, height = reader.unpack("iiQQ")
            where = f"{cameras_file}: camera {camera_id}"
            if model_id in UNSUPPORTED:
                raise InvalidInputError(
                    f"{where}: camera model {UNSUPPORTED[model_id]} is not supported (elastocap reads "
                    f"{', '.join(MODELS)})"
                )
            if model_id not in MODEL_BY_ID:
                raise InvalidInputError(f"{where}: unknown camera model id {model_id}")
            model = MODEL_BY_ID[model_id]
            names = MODELS[model][1]
            params = list(reader.unpack(f"{len(names)}d"))
            for i, name in enumerate(names):
                if name in ("cx", "cy"):
                    params[i] -= 0.5
            K, dist = intrinsics_from_params(model, params, where)
            intrinsics[camera_id] = (K, dist, width, height)
    poses = []
    with open(images_file, "rb") as handle:
        reader = _Reader(handle, images_file)
        (count,) = reader.unpack("Q")
        for _ in range(count):
            fields = reader.unpack("idddddddi")
            image_id, camera_id = fields[0], fields[8]
            name = reader.name()
            (points,) = reader.unpack("Q")
            # Checked against what is left of the file before skipping: a corrupt count
            # must not make a read allocate it.
            if 24 * points > os.fstat(handle.fileno()).st_size - handle.tell():
                raise InvalidInputError(
                    f"{images_file}: truncated or corrupt (image {image_id} claims {points} 2-D points, "
                    "more than the file holds)"
                )
            handle.seek(24 * points, os.SEEK_CUR)
            q, t = np.array(fields[1:5]), np.array(fields[5:8])
            poses.append((image_id, q, t, camera_id, name, f"{images_file}: image {image_id}"))
    return records(poses, intrinsics, size, folder)


def write(folder: Path, cameras: Sequence[Camera], *, model: str | None = None) -> None:
    """``folder/cameras.bin``, ``images.bin`` and an empty ``points3D.bin``."""
    models = [choose_model(camera, model) for camera in cameras]
    camera_data = [struct.pack("<Q", len(cameras))]
    image_data = [struct.pack("<Q", len(cameras))]
    for index, (camera, chosen) in enumerate(zip(cameras, models), start=1):
        names = MODELS[chosen][1]
        params = [value + 0.5 if name in ("cx", "cy") else value for name, value in zip(names, params_of(camera, chosen))]
        camera_data.append(struct.pack("<iiQQ", index, MODELS[chosen][0], camera.width, camera.height))
        camera_data.append(struct.pack(f"<{len(params)}d", *params))
        pose = [*quaternion_from_rotation(camera.R), *camera.t]
        image_data.append(struct.pack("<idddddddi", index, *pose, index))
        image_data.append(f"{camera.name}.png".encode("utf-8") + b"\x00")
        image_data.append(struct.pack("<Q", 0))
    save_bytes(folder / "cameras.bin", b"".join(camera_data))
    save_bytes(folder / "images.bin", b"".join(image_data))
    save_bytes(folder / "points3D.bin", struct.pack("<Q", 0))
