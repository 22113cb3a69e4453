"""OpenCV stereo calibration YAML / XML (``cv2.FileStorage``): what ``stereoCalibrate`` /
``stereoRectify`` scripts save.

Keys read: the intrinsics ``M1`` ``D1`` ``M2`` ``D2`` (OpenCV's ``stereo_calib`` sample), or
``K1`` / ``K2``, or ``cameraMatrix1`` / ``distCoeffs1``...; the second camera's pose
relative to the first, ``R`` (3x3, or a 3x1 Rodrigues vector) and ``T`` (3x1):
``x2 = R x1 + T``. The first camera is the world frame (R = I, t = 0). Rectification
results (``R1 R2 P1 P2 Q E F``) are ignored. The image size comes from ``imageSize`` /
``image_size`` ([width, height]), ``image_width`` + ``image_height``, the images beside
the file, or ``size=``. Camera names from ``names`` when present, else ``left`` and
``right``. A folder with OpenCV sample's ``intrinsics.yml`` + ``extrinsics.yml`` reads as
one file.

Writing refuses rigs of other than two cameras, or whose first camera is not the world
frame (re-express the rig with :meth:`Rig.relative_to` first). Round trips are exact
(OpenCV prints 17 significant digits).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, TYPE_CHECKING, Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._io import opencv_storage_text, save_text
from elastocap.cameras.formats.common import CameraRecord, file_image_size, settle_size
from elastocap.cameras.formats.filestorage import (
    open_storage,
    read_matrix,
    read_names,
    read_scalar,
    rodrigues,
)

if TYPE_CHECKING:
    from elastocap.cameras.camera import Camera

__all__ = ["read", "write"]

NAME = "opencv-stereo"

INTRINSIC_KEYS = {
    "K": ("M{i}", "K{i}", "cameraMatrix{i}", "camera_matrix_{i}", "CM{i}"),
    "dist": ("D{i}", "distCoeffs{i}", "dist_coeffs_{i}", "dist{i}"),
}
SIZE_KEYS = ("imageSize", "image_size", "ImageSize")
DEFAULT_NAMES = ["left", "right"]
SAMPLE_FILES = ("intrinsics.yml", "extrinsics.yml")


def _find(storages: list[tuple[cv2.FileStorage, Path]], keys: Sequence[str]) -> tuple[NDArray[np.float64] | None, str, Path]:
    for key in keys:
        for storage, file in storages:
            value = read_matrix(storage, key, file, required=False)
            if value is not None:
                return value, key, file
    return None, keys[0], storages[0][1]


def read(path: Path, size: tuple[int, int] | None) -> list[CameraRecord]:
    """A stereo calibration file, or a folder holding ``intrinsics.yml`` +
    ``extrinsics.yml``."""
    files = [path / name for name in SAMPLE_FILES] if path.is_dir() else [path]
    for file in files:
        if not file.exists():
            raise FileNotFoundError(f"stereo calibration file missing: {file}")
    storages = [(open_storage(file), file) for file in files]
    where = " / ".join(str(file) for file in files)
    try:
        names = None
        for storage, file in storages:
            names = names or read_names(storage, file, required=False)
        names = names or DEFAULT_NAMES
        if len(names) != 2:
            raise InvalidInputError(f"{where}: 'names' must name two cameras, got {names}")
        intrinsics = []
        for i in (1, 2):
            K, _, _ = _find(storages, [k.format(i=i) for k in INTRINSIC_KEYS["K"]])
            if K is None:
                raise InvalidInputError(f"{where}: no camera matrix M{i} (or K{i}, cameraMatrix{i})")
            dist, _, _ = _find(storages, [k.format(i=i) for k in INTRINSIC_KEYS["dist"]])
            intrinsics.append((K, dist))
        R, _, _ = _find(storages, ["R"])
        T, _, _ = _find(storages, ["T"])
        if R is None or T is None:
            raise InvalidInputError(f"{where}: no R and T (the second camera's pose relative to the first)")
        if R.size == 3:
            R = rodrigues(R, "R", files[0])
        sizes = [_size(storages, i, where) for i in (1, 2)]
    finally:
        for storage, _ in storages:
            storage.release()
    poses = [(np.eye(3), np.zeros(3)), (R, T)]
    cameras = []
    for name, (K, dist), (rotation, translation), file_size in zip(names, intrinsics, poses, sizes):
        image_size = _image_beside(files[0].parent, name) if file_size is None else None
        w, h = settle_size(name, file_size, image_size, size, where)
        cameras.append(CameraRecord(name, K, dist, rotation, translation, w, h, where))
    return cameras


def _size(storages: list[tuple[cv2.FileStorage, Path]], i: int, where: str) -> tuple[int, int] | None:
    value, key, _ = _find(storages, [f"imageSize{i}", *SIZE_KEYS])
    if value is not None:
        flat = value.ravel()
        if flat.size != 2 or not all(np.isfinite(flat)) or not all(float(v).is_integer() and v > 0 for v in flat):
            raise InvalidInputError(f"{where}: {key} must be [width, height] in pixels, got {flat.tolist()}")
        return int(flat[0]), int(flat[1])
    found: dict[str, int] = {}
    for key in ("image_width", "image_height"):
        for storage, file in storages:
            scalar = read_scalar(storage, key, file)
            if scalar is not None and key not in found:
                found[key] = scalar
    if not found:
        return None
    if len(found) != 2:
        raise InvalidInputError(f"{where}: give both image_width and image_height")
    return found["image_width"], found["image_height"]


def _image_beside(folder: Path, name: str) -> tuple[int, int] | None:
    for suffix in (".png", ".jpg"):
        if (folder / f"{name}{suffix}").exists():
            return file_image_size(folder / f"{name}{suffix}")
    return None


def write(file: Path, cameras: Sequence[Camera]) -> None:
    """``file`` (``.yml``, ``.yaml`` or ``.xml``) with ``names``, ``M1 D1 M2 D2 R T`` and
    the image size (``imageSize``, or ``imageSize1`` + ``imageSize2`` when they differ)."""
    if len(cameras) != 2:
        raise InvalidInputError(
            f"the OpenCV stereo format holds two cameras, the rig has {len(cameras)}: pick a pair "
            "(Rig([rig[a], rig[b]]))"
        )
    first, second = cameras
    if not (np.array_equal(first.R, np.eye(3)) and not np.any(first.t)):
        raise InvalidInputError(
            f"the OpenCV stereo format puts the world at the first camera, but camera {first.name!r} is "
            f"not at the origin (R = I, t = 0): re-express the rig with rig.relative_to({first.name!r})"
        )

    def fill(storage: Any) -> None:
        storage.startWriteStruct("names", cv2.FileNode_SEQ)
        for camera in cameras:
            storage.write("", camera.name)
        storage.endWriteStruct()
        for i, camera in enumerate(cameras, start=1):
            storage.write(f"M{i}", np.array(camera.K))
            storage.write(f"D{i}", np.array(camera.dist).reshape(1, -1))
        storage.write("R", np.array(second.R))
        storage.write("T", np.array(second.t).reshape(3, 1))
        if first.size == second.size:
            storage.write("imageSize", np.array(first.size, dtype=np.float64).reshape(1, 2))
        else:
            for i, camera in enumerate(cameras, start=1):
                storage.write(f"imageSize{i}", np.array(camera.size, dtype=np.float64).reshape(1, 2))

    save_text(file, opencv_storage_text(file, fill))
