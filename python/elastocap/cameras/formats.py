"""Calibration files: reading and writing EasyMocap / ZJU-MoCap ``intri.yml`` +
``extri.yml`` (OpenCV FileStorage YAML), elastocap's ``rig.json`` and Middlebury
``*_par.txt``. :meth:`elastocap.Rig.load` and :meth:`elastocap.Rig.save` are the public
entry points; readers here return unvalidated :class:`CameraRecord` s, which the Rig turns
into cameras (validating them, with ``where`` in the message)."""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError

if TYPE_CHECKING:
    from elastocap.cameras.camera import Camera

# Rot_<name> and R_<name> (Rodrigues) of one camera must agree to the precision the file
# prints them with: RODRIGUES_SLACK times the rounding of both (half a unit in the last
# printed digit of their entries), plus Rot_'s own orthonormality error. The matrix wins.
RODRIGUES_SLACK = 4.0
# When the printed digits cannot be read back from the text, assume this many significant
# digits (what real tools print at the least).
ASSUMED_DIGITS = 6

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


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


def read(path: Path, size: tuple[int, int] | None) -> list[CameraRecord]:
    """The cameras of the calibration at ``path`` (see :meth:`elastocap.Rig.load`)."""
    if not path.exists():
        raise FileNotFoundError(f"calibration not found: {path} does not exist")
    if path.is_dir():
        if (path / "intri.yml").exists() or (path / "extri.yml").exists():
            return read_yaml(path, size)
        if (path / "rig.json").exists():
            return read_json(path / "rig.json", size)
        par = sorted(path.glob("*_par.txt"))
        if len(par) == 1:
            return read_middlebury(par[0], size)
        if len(par) > 1:
            raise InvalidInputError(
                f"{path} holds several Middlebury files ({', '.join(p.name for p in par)}): "
                "pass one of them"
            )
        raise FileNotFoundError(
            f"no calibration in {path}: expected intri.yml + extri.yml, rig.json or a *_par.txt"
        )
    if path.name in ("intri.yml", "extri.yml"):
        return read_yaml(path.parent, size)
    if path.suffix.lower() == ".json":
        return read_json(path, size)
    if path.suffix.lower() == ".txt":
        return read_middlebury(path, size)
    raise InvalidInputError(
        f"path {path}: not a calibration this reads (a folder, intri.yml / extri.yml, "
        "*.json or a Middlebury *_par.txt)"
    )


def read_yaml(folder: Path, size: tuple[int, int] | None) -> list[CameraRecord]:
    """``folder/intri.yml`` + ``folder/extri.yml`` (EasyMocap / ZJU-MoCap)."""
    intri_path, extri_path = folder / "intri.yml", folder / "extri.yml"
    for file in (intri_path, extri_path):
        if not file.exists():
            raise FileNotFoundError(f"calibration file missing: {file}")
    intri, extri = _open_storage(intri_path), _open_storage(extri_path)
    extri_text = extri_path.read_text(errors="replace")
    try:
        names = _read_names(intri, intri_path)
        assert names is not None  # required=True raises instead
        extri_names = _read_names(extri, extri_path, required=False)
        if extri_names is not None and extri_names != names:
            raise InvalidInputError(
                f"{extri_path}: names {extri_names} differ from {intri_path.name}'s {names}"
            )
        cameras: list[CameraRecord] = []
        for name in names:
            K = _read_matrix(intri, f"K_{name}", intri_path, required=True)
            dist = _read_matrix(intri, f"dist_{name}", intri_path, required=False)
            rot = _read_matrix(extri, f"Rot_{name}", extri_path, required=False)
            rvec = _read_matrix(extri, f"R_{name}", extri_path, required=False)
            T = _read_matrix(extri, f"T_{name}", extri_path, required=True)
            if rot is None and rvec is None:
                raise InvalidInputError(
                    f"{extri_path}: camera {name!r} has neither Rot_{name} (3x3) nor R_{name} (3x1)"
                )
            R = rot if rot is not None else _rodrigues(rvec, f"R_{name}", extri_path)
            if rot is not None and rvec is not None and rot.shape == (3, 3):
                _check_rodrigues_agrees(extri_text, name, rot, rvec, extri_path)
            height = _read_scalar(intri, f"H_{name}", intri_path)
            width = _read_scalar(intri, f"W_{name}", intri_path)
            if (height is None) != (width is None):
                raise InvalidInputError(f"{intri_path}: camera {name!r} has only one of H_{name}, W_{name}")
            file_size = None if width is None else (width, height)
            # Images are opened only when the calibration does not give the size.
            image_size = _size_from_capture(folder, name) if file_size is None else None
            w, h = _settle_size(name, file_size, image_size, size, intri_path)
            cameras.append(CameraRecord(name, K, dist, R, T, w, h, f"{intri_path} / {extri_path.name}"))
    finally:
        intri.release()
        extri.release()
    return cameras


def read_json(file: Path, size: tuple[int, int] | None) -> list[CameraRecord]:
    """``{"cameras": [{"name", "K", "dist", "R", "t", "width", "height"}, ...]}``."""
    try:
        data = json.loads(file.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise InvalidInputError(f"{file}: not valid JSON ({error})") from None
    entries = data.get("cameras") if isinstance(data, dict) else None
    if not isinstance(entries, list) or not entries:
        raise InvalidInputError(f'{file}: expected {{"cameras": [...]}} with at least one camera')
    cameras: list[CameraRecord] = []
    for index, entry in enumerate(entries):
        where = f"{file}: cameras[{index}]"
        if not isinstance(entry, dict):
            raise InvalidInputError(f"{where} must be an object, got {type(entry).__name__}")
        missing = [key for key in ("name", "K", "R", "t") if key not in entry]
        if missing:
            raise InvalidInputError(f"{where} lacks {', '.join(missing)}")
        name = entry["name"]
        file_size = None
        if "width" in entry or "height" in entry:
            file_size = (entry.get("width"), entry.get("height"))
        image_size = _size_from_capture(file.parent, str(name)) if file_size is None else None
        w, h = _settle_size(str(name), file_size, image_size, size, file)
        cameras.append(
            CameraRecord(name, entry["K"], entry.get("dist"), entry["R"], entry["t"], w, h, where)
        )
    return cameras


def read_middlebury(file: Path, size: tuple[int, int] | None) -> list[CameraRecord]:
    """A Middlebury multi-view ``*_par.txt``: a count, then ``name.png k11 .. k33 r11 .. r33
    t1 t2 t3`` per camera; the size from the image beside the file."""
    lines = [line for line in file.read_text().splitlines() if line.strip()]
    if not lines:
        raise InvalidInputError(f"{file}: empty, expected a camera count and one line per camera")
    try:
        count = int(lines[0])
    except ValueError:
        raise InvalidInputError(f"{file}: line 1 must be the camera count, got {lines[0]!r}") from None
    if count != len(lines) - 1:
        raise InvalidInputError(f"{file}: line 1 says {count} cameras, but {len(lines) - 1} lines follow")
    cameras: list[CameraRecord] = []
    for number, line in enumerate(lines[1:], start=2):
        fields = line.split()
        where = f"{file}, line {number}"
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
        image_size = _file_image_size(image) if image.exists() else None
        w, h = _settle_size(name, None, image_size, size, file)
        cameras.append(
            CameraRecord(name, values[:9].reshape(3, 3), None, values[9:18].reshape(3, 3), values[18:], w, h, where)
        )
    return cameras


def write_json(file: Path, cameras: Sequence[Camera]) -> None:
    """``{"cameras": [...]}`` with every field; Python prints floats in their shortest
    form that reads back exactly."""
    file.parent.mkdir(parents=True, exist_ok=True)
    document = {"cameras": [_camera_json(camera) for camera in cameras]}
    file.write_text(json.dumps(document, indent=2) + "\n")


def write_yaml(folder: Path, cameras: Sequence[Camera]) -> None:
    """``intri.yml`` + ``extri.yml`` in the EasyMocap layout, with both ``R_`` (Rodrigues)
    and ``Rot_`` (3x3) and the image size as ``H_`` / ``W_``; OpenCV prints doubles with
    17 significant digits."""
    folder.mkdir(parents=True, exist_ok=True)
    intri = cv2.FileStorage(str(folder / "intri.yml"), cv2.FILE_STORAGE_WRITE)
    extri = cv2.FileStorage(str(folder / "extri.yml"), cv2.FILE_STORAGE_WRITE)
    try:
        for storage in (intri, extri):
            storage.startWriteStruct("names", cv2.FileNode_SEQ)
            for camera in cameras:
                storage.write("", camera.name)
            storage.endWriteStruct()
        for camera in cameras:
            name = camera.name
            intri.write(f"K_{name}", np.array(camera.K))
            intri.write(f"dist_{name}", np.array(camera.dist).reshape(1, 5))
            intri.write(f"H_{name}", camera.height)
            intri.write(f"W_{name}", camera.width)
            rvec, _ = cv2.Rodrigues(np.array(camera.R))
            extri.write(f"R_{name}", rvec)
            extri.write(f"Rot_{name}", np.array(camera.R))
            extri.write(f"T_{name}", np.array(camera.t).reshape(3, 1))
    finally:
        intri.release()
        extri.release()


def _camera_json(camera: Camera) -> dict[str, Any]:
    return {
        "name": camera.name,
        "K": camera.K.tolist(),
        "dist": camera.dist.tolist(),
        "R": camera.R.tolist(),
        "t": camera.t.tolist(),
        "width": camera.width,
        "height": camera.height,
    }


# ------------------------------------------------------------------------------------------
# helpers: OpenCV FileStorage
# ------------------------------------------------------------------------------------------


def _open_storage(file: Path) -> cv2.FileStorage:
    try:
        storage = cv2.FileStorage(str(file), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as error:
        # A parse error surfaces as cv2.error, or as a SystemError wrapping it.
        cause = error.__cause__ or error.__context__ or error
        text = str(cause).strip()
        found = re.search(r"\((\d+)\): ([^']+)'?\s*$", text)
        message = f"line {found[1]}: {found[2].strip()}" if found else (text.splitlines() or ["parse error"])[-1]
        raise InvalidInputError(f"{file}: not a readable OpenCV YAML file ({message})") from None
    if not storage.isOpened():
        raise InvalidInputError(f"{file}: not a readable OpenCV YAML file")
    return storage


def _read_names(storage: cv2.FileStorage, file: Path, *, required: bool = True) -> list[str] | None:
    node = storage.getNode("names")
    if node.empty() or node.isNone():
        if required:
            raise InvalidInputError(f"{file}: no 'names' list of cameras")
        return None
    if not node.isSeq():
        raise InvalidInputError(f"{file}: 'names' must be a sequence of camera names")
    names = []
    for index in range(node.size()):
        item = node.at(index)
        if item.isString():
            names.append(item.string())
        elif item.isInt():
            names.append(str(int(item.real())))
        else:
            raise InvalidInputError(f"{file}: names[{index}] is not a camera name")
    if not names:
        raise InvalidInputError(f"{file}: 'names' is empty")
    return names


def _read_matrix(
    storage: cv2.FileStorage, key: str, file: Path, *, required: bool
) -> NDArray[np.float64] | None:
    node = storage.getNode(key)
    if node.empty() or node.isNone():
        if required:
            raise InvalidInputError(f"{file}: {key} is missing")
        return None
    if node.isMap():
        try:
            matrix = node.mat()
        except cv2.error:
            matrix = None
        if matrix is None:
            raise InvalidInputError(f"{file}: {key} is not a readable matrix (malformed numbers?)")
        return np.asarray(matrix, dtype=np.float64)
    if node.isSeq():
        values = [node.at(i) for i in range(node.size())]
        if all(v.isReal() or v.isInt() for v in values):
            return np.array([v.real() for v in values], dtype=np.float64)
    raise InvalidInputError(f"{file}: {key} is not a matrix (expected !!opencv-matrix)")


def _read_scalar(storage: cv2.FileStorage, key: str, file: Path) -> int | None:
    node = storage.getNode(key)
    if node.empty() or node.isNone():
        return None
    if node.isInt() or node.isReal():
        value = node.real()
    else:
        matrix = _read_matrix(storage, key, file, required=True)
        assert matrix is not None
        if matrix.size != 1:
            raise InvalidInputError(f"{file}: {key} must be a single number, got shape {matrix.shape}")
        value = float(matrix.ravel()[0])
    if not (np.isfinite(value) and value > 0 and float(value).is_integer()):
        raise InvalidInputError(f"{file}: {key} must be a positive integer, got {value}")
    return int(value)


def _check_rodrigues_agrees(
    text: str, name: str, rot: NDArray[np.float64], rvec: Any, file: Path
) -> None:
    """Rot_<name> (3x3) and R_<name> (Rodrigues) must describe one rotation to the precision
    the file prints them with (see RODRIGUES_SLACK)."""
    from_rvec = _rodrigues(rvec, f"R_{name}", file)
    disagreement = float(np.abs(from_rvec - rot).max())
    rot_rounding = _printed_rounding(text, f"Rot_{name}", rot)
    # A Rodrigues vector's rounding moves the rotation by at most its norm (in angle).
    rvec_rounding = float(np.linalg.norm(_printed_rounding_entries(text, f"R_{name}", rvec)))
    orthonormality = float(np.abs(rot.T @ rot - np.eye(3)).max())
    tolerance = RODRIGUES_SLACK * (rot_rounding + rvec_rounding) + orthonormality + 1e-12
    if disagreement > tolerance:
        raise InvalidInputError(
            f"{file}: camera {name!r}: Rot_{name} and R_{name} (Rodrigues) disagree by "
            f"{disagreement:.3g}, more than the {tolerance:.3g} their printed precision explains"
        )


def _printed_rounding(text: str, key: str, values: Any) -> float:
    """Largest rounding error of the entries of matrix ``key`` as printed in ``text``."""
    return float(_printed_rounding_entries(text, key, values).max())


def _printed_rounding_entries(text: str, key: str, values: Any) -> NDArray[np.float64]:
    """Per entry of matrix ``key`` in an OpenCV YAML ``text``: its rounding error, half a
    unit in the last significant digit the writer kept. The writer's precision is the most
    significant digits any entry shows ("%g" drops trailing zeros, so a short entry is not a
    coarse one); when the entries cannot be read back, ASSUMED_DIGITS are assumed."""
    flat = np.asarray(values, dtype=np.float64).ravel()
    match = re.search(
        rf"^\s*{re.escape(key)}\s*:[^\n]*\n(?:[^\n]*\n){{0,6}}?\s*data\s*:\s*\[([^\]]*)\]",
        text,
        re.MULTILINE,
    )
    tokens = match.group(1).replace(",", " ").split() if match else []
    digits = max(map(_significant_digits, tokens)) if len(tokens) == flat.size else ASSUMED_DIGITS
    magnitude = np.floor(np.log10(np.maximum(np.abs(flat), 1e-300)))
    rounding = 0.5 * 10.0 ** (magnitude - (digits - 1))
    return np.asarray(np.where(flat == 0.0, 0.0, rounding), dtype=np.float64)


def _significant_digits(token: str) -> int:
    """Significant digits of a number written like ``-1.2345e-02`` or ``0.00120``."""
    mantissa = token.lower().partition("e")[0].lstrip("+-").replace(".", "").lstrip("0")
    return max(len(mantissa), 1)


def _rodrigues(rvec: Any, key: str, file: Path) -> NDArray[np.float64]:
    vector = np.asarray(rvec, dtype=np.float64)
    if vector.size != 3:
        raise InvalidInputError(f"{file}: {key} must be a 3x1 Rodrigues vector, got shape {vector.shape}")
    if not np.isfinite(vector).all():
        raise InvalidInputError(f"{file}: {key} must be finite, got {vector.ravel().tolist()}")
    matrix, _ = cv2.Rodrigues(vector.reshape(3, 1))
    return np.asarray(matrix, dtype=np.float64)


# ------------------------------------------------------------------------------------------
# helpers: image sizes
# ------------------------------------------------------------------------------------------


def _settle_size(
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
            f"{file}: camera {name!r}: image size unknown (no H_/W_ or width/height in the file, "
            "no image beside it): pass size=(width, height)"
        )
    first_source, first = candidates[0]
    for source, value in candidates[1:]:
        if tuple(value) != tuple(first):
            raise InvalidInputError(
                f"{file}: camera {name!r}: image size {tuple(first)} from {first_source} "
                f"disagrees with {tuple(value)} from {source}"
            )
    return first[0], first[1]


def _size_from_capture(folder: Path, name: str) -> tuple[int, int] | None:
    """(width, height) of camera ``name``'s first image, mask, background or video in a
    capture folder, or None when there is none."""
    for sub in ("images", "masks", "mask"):
        directory = folder / sub / name
        if directory.is_dir():
            files = sorted(p for p in directory.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if files:
                return _file_image_size(files[0])
    for suffix in IMAGE_SUFFIXES:
        background = folder / "background" / f"{name}{suffix}"
        if background.exists():
            return _file_image_size(background)
    video = folder / "videos" / f"{name}.mp4"
    if video.exists():
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
    return None


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _file_image_size(file: Path) -> tuple[int, int]:
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

