"""NeRF / Blender / instant-ngp / nerfstudio ``transforms.json``.

Intrinsics, at the top level or per frame (a frame's own values win): ``fl_x`` ``fl_y``
``cx`` ``cy`` ``w`` ``h`` and distortion ``k1 k2 k3 p1 p2`` (nerfstudio's ``camera_model``
``OPENCV`` or ``PINHOLE``), or the original Blender sets' ``camera_angle_x`` (and
``camera_angle_y``) with the principal point at the image centre. The image origin is the
corner of the top-left pixel, as in COLMAP (these tools cast rays through pixel ``i + 0.5``):
``cx = cx_file - 0.5``. Numbers are read and written with exact decimal arithmetic, so the
half pixel costs no rounding.

Each frame ``{"file_path", "transform_matrix"}`` is one camera, named by the stem of its
``file_path`` (unique); ``transform_matrix`` is camera -> world (4x4) with OpenGL camera
axes: x right, y up, looking down -z. So ``R = (M[:3, :3] diag(1, -1, -1))^T`` and ``t =
-R M[:3, 3]``. The world frame is the file's as stored (nerfstudio's
``applied_transform`` is not undone). The image size comes from ``w`` / ``h``, the image at
``file_path``, or ``size=``.

Refused: skew, rational and thin-prism distortion on writing; fisheye and other camera
models, and nerfstudio's ``k4`` (an ``r^8`` term OpenCV's model lacks), on reading. R and t
round-trip to rounding (t is stored as the camera centre), the rest exactly.
"""

from __future__ import annotations

import json
import math
from decimal import Decimal, localcontext
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from elastocap._core import InvalidInputError
from elastocap._io import save_text
from elastocap.cameras.formats.colmap import camera_names
from elastocap.cameras.formats.common import (
    IMAGE_SUFFIXES,
    CameraRecord,
    file_image_size,
    refuse_distortion_beyond,
    refuse_skew,
    settle_size,
)

if TYPE_CHECKING:
    from elastocap.cameras.camera import Camera

__all__ = ["read", "write"]

NAME = "nerf"

# OpenGL camera axes (x right, y up, z back) to OpenCV's (x right, y down, z forward).
GL_TO_CV = np.diag([1.0, -1.0, -1.0])
MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE")
INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "k3", "k4", "p1", "p2",
                  "camera_angle_x", "camera_angle_y", "camera_model")
_DECIMAL_DIGITS = 1000


def _float(value: Any, key: str, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, Decimal)):
        raise InvalidInputError(f"{where}: {key} must be a number, got {value!r}")
    return float(value)


def _minus_half(value: Any, key: str, where: str) -> float:
    _float(value, key, where)
    with localcontext() as context:
        context.prec = _DECIMAL_DIGITS
        return float(Decimal(value) - Decimal("0.5"))


def read(file: Path, size: tuple[int, int] | None) -> list[CameraRecord]:
    """The cameras of a ``transforms.json``, in frame order."""
    try:
        document = json.loads(file.read_text(), parse_float=Decimal)
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise InvalidInputError(f"{file}: not valid JSON ({error})") from None
    frames = document.get("frames") if isinstance(document, dict) else None
    if not isinstance(frames, list) or not frames:
        raise InvalidInputError(f'{file}: expected {{"frames": [...]}} with at least one frame')
    shared = {key: document[key] for key in INTRINSIC_KEYS if key in document}
    for index, frame in enumerate(frames):
        if not isinstance(frame, dict) or "file_path" not in frame or "transform_matrix" not in frame:
            raise InvalidInputError(f"{file}: frames[{index}] must hold file_path and transform_matrix")
    names = camera_names([str(frame["file_path"]) for frame in frames], str(file))
    cameras = []
    for index, (name, frame) in enumerate(zip(names, frames)):
        where = f"{file}: frames[{index}]"
        values = {**shared, **{key: frame[key] for key in INTRINSIC_KEYS if key in frame}}
        file_size = None
        if "w" in values or "h" in values:
            file_size = (values.get("w"), values.get("h"))
        image_size = _image_size(file.parent, str(frame["file_path"])) if file_size is None else None
        w, h = settle_size(name, file_size, image_size, size, where)
        K, dist = _intrinsics(values, w, h, where)
        R, t = _pose(frame["transform_matrix"], where)
        cameras.append(CameraRecord(name, K, dist, R, t, w, h, where))
    return cameras


def _intrinsics(values: dict[str, Any], width: Any, height: Any, where: str) -> tuple[np.ndarray, np.ndarray]:
    model = values.get("camera_model", "OPENCV")
    if model not in MODELS:
        raise InvalidInputError(f"{where}: camera_model {model!r} is not supported (elastocap reads {', '.join(MODELS)})")
    if "k4" in values and _float(values["k4"], "k4", where) != 0.0:
        raise InvalidInputError(
            f"{where}: k4 = {values['k4']} (nerfstudio's r^8 radial term) is not part of OpenCV's model, "
            "which elastocap uses"
        )
    try:
        width_, height_ = float(width), float(height)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{where}: image size must be numbers, got {width!r} x {height!r}") from None
    if "fl_x" in values:
        fx = _float(values["fl_x"], "fl_x", where)
    elif "camera_angle_x" in values:
        fx = 0.5 * width_ / math.tan(0.5 * _float(values["camera_angle_x"], "camera_angle_x", where))
    else:
        raise InvalidInputError(f"{where}: no focal length (fl_x or camera_angle_x)")
    if "fl_y" in values:
        fy = _float(values["fl_y"], "fl_y", where)
    elif "camera_angle_y" in values:
        fy = 0.5 * height_ / math.tan(0.5 * _float(values["camera_angle_y"], "camera_angle_y", where))
    else:
        fy = fx
    cx = _minus_half(values["cx"], "cx", where) if "cx" in values else 0.5 * width_ - 0.5
    cy = _minus_half(values["cy"], "cy", where) if "cy" in values else 0.5 * height_ - 0.5
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    dist = np.array([_float(values.get(key, 0.0), key, where) for key in ("k1", "k2", "p1", "p2", "k3")])
    return K, dist


def _pose(value: Any, where: str) -> tuple[np.ndarray, np.ndarray]:
    try:
        matrix = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{where}: transform_matrix must be a 4x4 matrix of numbers") from None
    if matrix.shape not in ((4, 4), (3, 4)) or not np.isfinite(matrix).all():
        raise InvalidInputError(f"{where}: transform_matrix must be a finite 4x4 matrix, got shape {matrix.shape}")
    if matrix.shape == (4, 4) and np.abs(matrix[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-6:
        raise InvalidInputError(f"{where}: transform_matrix's last row must be [0, 0, 0, 1], got {matrix[3].tolist()}")
    R = (matrix[:3, :3] @ GL_TO_CV).T
    return R, -R @ matrix[:3, 3]


def _image_size(folder: Path, file_path: str) -> tuple[int, int] | None:
    image = folder / file_path
    candidates = [image] if image.suffix.lower() in IMAGE_SUFFIXES else [image.with_name(image.name + s) for s in IMAGE_SUFFIXES]
    for candidate in candidates:
        if candidate.is_file():
            return file_image_size(candidate)
    return None


def _plus_half(value: float) -> Decimal:
    """A decimal for ``value + 0.5`` that reads back (minus 0.5, exactly) as ``value``."""
    short = Decimal(repr(value + 0.5))
    with localcontext() as context:
        context.prec = _DECIMAL_DIGITS
        if float(short - Decimal("0.5")) == value:
            return short
        return Decimal(value) + Decimal("0.5")


def write(file: Path, cameras: Sequence[Camera]) -> None:
    """``file`` as a ``transforms.json``: shared intrinsics at the top level when every
    camera has the same (with ``camera_angle_x`` for the original NeRF loaders), else per
    frame; one frame per camera, ``file_path`` ``<name>.png``."""
    refuse_skew(cameras, "NeRF transforms.json")
    refuse_distortion_beyond(cameras, 5, "NeRF transforms.json", "k1 k2 p1 p2 k3")
    intrinsics = [_intrinsics_of(camera) for camera in cameras]
    shared = all(i == intrinsics[0] for i in intrinsics)
    document: dict[str, Any] = {}
    if shared:
        first = cameras[0]
        document["camera_angle_x"] = 2.0 * math.atan(0.5 * first.width / first.K[0, 0])
        document.update(intrinsics[0])
    frames = []
    for camera, own in zip(cameras, intrinsics):
        c2w = np.eye(4)
        c2w[:3, :3] = camera.R.T @ GL_TO_CV
        c2w[:3, 3] = camera.center
        frame: dict[str, Any] = {"file_path": f"{camera.name}.png", "transform_matrix": c2w.tolist()}
        if not shared:
            frame.update(own)
        frames.append(frame)
    document["frames"] = frames
    save_text(file, _dumps(document) + "\n")


def _intrinsics_of(camera: Camera) -> dict[str, Any]:
    dist = np.zeros(5)
    dist[: min(5, camera.dist.size)] = camera.dist[:5]
    k1, k2, p1, p2, k3 = (float(v) for v in dist)
    return {
        "camera_model": "OPENCV",
        "fl_x": float(camera.K[0, 0]), "fl_y": float(camera.K[1, 1]),
        "cx": _plus_half(float(camera.K[0, 2])), "cy": _plus_half(float(camera.K[1, 2])),
        "w": camera.width, "h": camera.height,
        "k1": k1, "k2": k2, "k3": k3, "p1": p1, "p2": p2,
    }


def _dumps(document: dict[str, Any]) -> str:
    """JSON with Decimals written as their exact digits (json cannot print them)."""
    exact: list[str] = []

    def placeholder(value: Any) -> str:
        if isinstance(value, Decimal):
            exact.append(str(value))
            return f"@@exact{len(exact) - 1}@@"
        raise TypeError(f"not JSON serialisable: {type(value).__name__}")

    text = json.dumps(document, indent=2, default=placeholder)
    for index, digits in enumerate(exact):
        text = text.replace(f'"@@exact{index}@@"', digits)
    return text
