"""COLMAP sparse models, text (``cameras.txt`` + ``images.txt``): camera models, the
pixel-centre convention, quaternions.

``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]``; ``images.txt``: per image
``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` and a line of 2-D points (ignored); the
pose is world -> camera, ``x = R(q) X + t``. Each image is one elastocap camera, named by
the image name's stem (which must be unique), with its COLMAP camera's intrinsics.

Models read and written: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV and
FULL_OPENCV (their distortion is OpenCV's: k1 [k2]; k1 k2 p1 p2; k1 k2 p1 p2 k3 k4 k5 k6).
The fisheye and FOV models are refused by name. No model has skew or thin-prism terms:
cameras with them are refused on writing.

COLMAP's image origin is the corner of the top-left pixel (its centre is (0.5, 0.5)),
OpenCV's and elastocap's the centre of that pixel: ``cx = cx_colmap - 0.5`` and ``cy =
cy_colmap - 0.5``. Text is read and written with exact decimal arithmetic, so the half
pixel costs no rounding.
"""

from __future__ import annotations

from decimal import Decimal, localcontext
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._io import save_text
from elastocap.cameras.formats.common import CameraRecord, number, settle_size

if TYPE_CHECKING:
    from elastocap.cameras.camera import Camera

__all__ = ["read", "write"]

NAME = "colmap"

# name -> (model id, parameter names)
MODELS: dict[str, tuple[int, tuple[str, ...]]] = {
    "SIMPLE_PINHOLE": (0, ("f", "cx", "cy")),
    "PINHOLE": (1, ("fx", "fy", "cx", "cy")),
    "SIMPLE_RADIAL": (2, ("f", "cx", "cy", "k1")),
    "RADIAL": (3, ("f", "cx", "cy", "k1", "k2")),
    "OPENCV": (4, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")),
    "FULL_OPENCV": (6, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")),
}
# Models COLMAP has that elastocap's camera does not: refused by name.
UNSUPPORTED = {
    5: "OPENCV_FISHEYE",
    7: "FOV",
    8: "SIMPLE_RADIAL_FISHEYE",
    9: "RADIAL_FISHEYE",
    10: "THIN_PRISM_FISHEYE",
    11: "RAD_TAN_THIN_PRISM_FISHEYE",
}
MODEL_BY_ID = {model_id: name for name, (model_id, _) in MODELS.items()}
# Where each OpenCV coefficient sits in elastocap's dist (k1 k2 p1 p2 k3 k4 k5 k6 ...).
_DIST_INDEX = {"k1": 0, "k2": 1, "p1": 2, "p2": 3, "k3": 4, "k4": 5, "k5": 6, "k6": 7}
# Exact decimal arithmetic: a double has at most a few hundred significant decimal digits.
_DECIMAL_DIGITS = 1000


# -- conventions -----------------------------------------------------------------------------


def intrinsics_from_params(
    model: str, params: Sequence[float], where: str
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(K, dist) in OpenCV's convention from a model's parameters with the principal point
    already moved to the pixel-centre origin."""
    names = MODELS[model][1]
    if len(params) != len(names):
        raise InvalidInputError(f"{where}: model {model} takes {len(names)} parameters ({' '.join(names)}), got {len(params)}")
    values = dict(zip(names, params))
    fx = values.get("fx", values.get("f"))
    fy = values.get("fy", values.get("f"))
    K = np.array([[fx, 0.0, values["cx"]], [0.0, fy, values["cy"]], [0.0, 0.0, 1.0]], dtype=np.float64)
    dist = np.zeros(8)
    for key, value in values.items():
        if key in _DIST_INDEX:
            dist[_DIST_INDEX[key]] = value
    return K, dist


def choose_model(camera: Camera, model: str | None) -> str:
    """The simplest COLMAP model that holds ``camera`` (or ``model``, checked)."""
    if camera.K[0, 1] != 0.0:
        raise InvalidInputError(
            f"camera {camera.name!r} has skew K[0, 1] = {float(camera.K[0, 1])!r}, which no COLMAP camera model can hold"
        )
    dist = np.zeros(12)
    dist[: camera.dist.size] = camera.dist
    if np.any(dist[8:] != 0):
        raise InvalidInputError(
            f"camera {camera.name!r} has thin-prism distortion s1-s4 = {dist[8:].tolist()}, which no COLMAP "
            "camera model can hold"
        )
    nonzero = {name for name, i in _DIST_INDEX.items() if dist[i] != 0}
    square = camera.K[0, 0] == camera.K[1, 1]
    if model is None:
        if nonzero - {"k1", "k2", "p1", "p2"}:
            model = "FULL_OPENCV"
        elif nonzero & {"p1", "p2"} or (nonzero and not square):
            model = "OPENCV"
        elif "k2" in nonzero:
            model = "RADIAL"
        elif "k1" in nonzero:
            model = "SIMPLE_RADIAL"
        else:
            model = "SIMPLE_PINHOLE" if square else "PINHOLE"
    if model not in MODELS:
        known = ", ".join(MODELS)
        raise InvalidInputError(f"COLMAP model {model!r} is not one elastocap writes ({known})")
    names = set(MODELS[model][1])
    missing = sorted(nonzero - names, key=_DIST_INDEX.__getitem__)
    if missing:
        listed = ", ".join(f"{n} = {float(dist[_DIST_INDEX[n]])!r}" for n in missing)
        raise InvalidInputError(f"camera {camera.name!r} has distortion {listed}, which COLMAP's {model} model cannot hold")
    if "f" in names and not square:
        raise InvalidInputError(
            f"camera {camera.name!r} has fx = {float(camera.K[0, 0])!r} != fy = {float(camera.K[1, 1])!r}, which COLMAP's "
            f"{model} model (one focal length) cannot hold"
        )
    return model


def params_of(camera: Camera, model: str) -> list[float]:
    """The model's parameters, principal point still in OpenCV's pixel-centre convention."""
    K = camera.K
    values = {"f": K[0, 0], "fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
    dist = np.zeros(12)
    dist[: camera.dist.size] = camera.dist
    values.update({name: dist[i] for name, i in _DIST_INDEX.items()})
    return [float(values[name]) for name in MODELS[model][1]]


def rotation_from_quaternion(q: NDArray[np.float64], where: str) -> NDArray[np.float64]:
    """COLMAP's ``qvec2rotmat`` of the normalised quaternion ``(w, x, y, z)``."""
    norm = float(np.linalg.norm(q))
    if not np.isfinite(q).all() or norm == 0.0:
        raise InvalidInputError(f"{where}: quaternion {q.tolist()} is not a rotation")
    w, x, y, z = q / norm
    return np.array([
        [1 - 2 * y * y - 2 * z * z, 2 * x * y - 2 * w * z, 2 * z * x + 2 * w * y],
        [2 * x * y + 2 * w * z, 1 - 2 * x * x - 2 * z * z, 2 * y * z - 2 * w * x],
        [2 * z * x - 2 * w * y, 2 * y * z + 2 * w * x, 1 - 2 * x * x - 2 * y * y],
    ])


def quaternion_from_rotation(R: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(w, x, y, z)``, ``w >= 0``, by Shepperd's method (the largest of the four
    candidate divisors, for accuracy)."""
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    candidates = [trace, R[0, 0], R[1, 1], R[2, 2]]
    i = int(np.argmax(candidates))
    if i == 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif i == 1:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif i == 2:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    out = np.array(q, dtype=np.float64)
    return -out if out[0] < 0 else out


def camera_names(image_names: Sequence[str], where: str) -> list[str]:
    """Image names' stems, which must be unique."""
    stems = [Path(name).stem for name in image_names]
    seen: dict[str, str] = {}
    for stem, name in zip(stems, image_names):
        if stem in seen:
            raise InvalidInputError(
                f"{where}: images {seen[stem]!r} and {name!r} have the same stem {stem!r}; elastocap names "
                "cameras by image stem, one image per camera"
            )
        seen[stem] = name
    return stems


def _shift_text(token: str, shift: str) -> float:
    """``float(token) + shift`` with the sum done exactly in decimal."""
    with localcontext() as context:
        context.prec = _DECIMAL_DIGITS
        return float(Decimal(token) + Decimal(shift))


def _shifted_number(value: float) -> str:
    """A decimal for ``value + 0.5`` that reads back (minus 0.5, exactly) as ``value``:
    the shortest form when that works, else the exact decimal."""
    short = number(value + 0.5)
    if _shift_text(short, "-0.5") == value:
        return short
    with localcontext() as context:
        context.prec = _DECIMAL_DIGITS
        return str(Decimal(value) + Decimal("0.5"))


# -- text ------------------------------------------------------------------------------------


def _content_lines(file: Path) -> list[tuple[int, str]]:
    if not file.exists():
        raise FileNotFoundError(f"COLMAP model file missing: {file}")
    try:
        text = file.read_text()
    except UnicodeDecodeError as error:
        raise InvalidInputError(f"{file}: not a text file ({error})") from None
    return [(i, line.strip()) for i, line in enumerate(text.splitlines(), start=1)]


def read(folder: Path, size: tuple[int, int] | None) -> list[CameraRecord]:
    """``folder/cameras.txt`` + ``folder/images.txt``."""
    cameras_file, images_file = folder / "cameras.txt", folder / "images.txt"
    intrinsics: dict[int, tuple[NDArray[np.float64], NDArray[np.float64], int, int]] = {}
    for line_number, line in _content_lines(cameras_file):
        if not line or line.startswith("#"):
            continue
        where = f"{cameras_file}, line {line_number}"
        fields = line.split()
        if len(fields) < 4:
            raise InvalidInputError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[], got {line!r}")
        model = fields[1]
        if model not in MODELS:
            raise InvalidInputError(f"{where}: camera model {model} is not supported (elastocap reads {', '.join(MODELS)})")
        try:
            camera_id, width, height = int(fields[0]), int(fields[2]), int(fields[3])
            names = MODELS[model][1]
            params = [
                _shift_text(token, "-0.5") if name in ("cx", "cy") else float(token)
                for name, token in zip(names, fields[4:])
            ]
        except (ValueError, ArithmeticError) as error:
            raise InvalidInputError(f"{where}: malformed number ({error})") from None
        if len(fields) - 4 != len(names):
            raise InvalidInputError(f"{where}: model {model} takes {len(names)} parameters, got {len(fields) - 4}")
        K, dist = intrinsics_from_params(model, params, where)
        intrinsics[camera_id] = (K, dist, width, height)
    poses: list[tuple[int, NDArray[np.float64], NDArray[np.float64], int, str, str]] = []
    lines = _content_lines(images_file)
    index = 0
    while index < len(lines):
        line_number, line = lines[index]
        index += 1
        if not line or line.startswith("#"):
            continue
        index += 1  # the image's line of 2-D points follows, possibly empty
        where = f"{images_file}, line {line_number}"
        fields = line.split()
        if len(fields) < 10:
            raise InvalidInputError(f"{where}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got {line!r}")
        try:
            image_id, camera_id = int(fields[0]), int(fields[8])
            q = np.array([float(v) for v in fields[1:5]])
            t = np.array([float(v) for v in fields[5:8]])
        except ValueError as error:
            raise InvalidInputError(f"{where}: malformed number ({error})") from None
        poses.append((image_id, q, t, camera_id, " ".join(fields[9:]), where))
    return records(poses, intrinsics, size, folder)


def records(
    poses: list[tuple[int, NDArray[np.float64], NDArray[np.float64], int, str, str]],
    intrinsics: dict[int, tuple[NDArray[np.float64], NDArray[np.float64], int, int]],
    size: tuple[int, int] | None,
    folder: Path,
) -> list[CameraRecord]:
    """Camera records of a model's images (in image id order) and cameras."""
    if not poses:
        raise InvalidInputError(f"{folder}: the COLMAP model has no images")
    poses = sorted(poses, key=lambda pose: pose[0])
    names = camera_names([pose[4] for pose in poses], str(folder))
    out = []
    for name, (_, q, t, camera_id, _, where) in zip(names, poses):
        if camera_id not in intrinsics:
            raise InvalidInputError(f"{where}: image {name!r} refers to camera {camera_id}, which the model lacks")
        K, dist, width, height = intrinsics[camera_id]
        w, h = settle_size(name, (width, height), None, size, where)
        out.append(CameraRecord(name, K, dist, rotation_from_quaternion(q, where), t, w, h, where))
    return out


def write(folder: Path, cameras: Sequence[Camera], *, model: str | None = None) -> None:
    """``folder/cameras.txt``, ``images.txt`` and an empty ``points3D.txt`` (COLMAP needs
    all three to import a model); one COLMAP camera per elastocap camera, in rig order."""
    models = [choose_model(camera, model) for camera in cameras]
    for camera in cameras:
        if any(ch.isspace() for ch in camera.name):
            raise InvalidInputError(f"camera {camera.name!r}: a COLMAP text image name cannot hold white space")
    camera_lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
                    f"# Number of cameras: {len(cameras)}"]
    image_lines = ["# Image list with two lines of data per image:",
                   "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
                   "#   POINTS2D[] as (X, Y, POINT3D_ID)", f"# Number of images: {len(cameras)}"]
    for index, (camera, chosen) in enumerate(zip(cameras, models), start=1):
        params = params_of(camera, chosen)
        tokens = [
            _shifted_number(value) if name in ("cx", "cy") else number(value)
            for name, value in zip(MODELS[chosen][1], params)
        ]
        camera_lines.append(" ".join([str(index), chosen, str(camera.width), str(camera.height), *tokens]))
        pose = [*quaternion_from_rotation(camera.R), *camera.t]
        image_lines.append(" ".join([str(index), *map(number, pose), str(index), f"{camera.name}.png"]))
        image_lines.append("")
    save_text(folder / "cameras.txt", "\n".join(camera_lines) + "\n")
    save_text(folder / "images.txt", "\n".join(image_lines) + "\n")
    save_text(folder / "points3D.txt", "# 3D point list (empty: elastocap writes cameras only)\n")
