"""EasyMocap / ZJU-MoCap ``intri.yml`` + ``extri.yml`` (OpenCV FileStorage YAML).

``intri.yml``: ``names`` (sequence of strings), ``K_<name>`` (3x3), ``dist_<name>`` (1xN
OpenCV coefficients, N = 4, 5, 8, 12 or 14; shorter is padded; missing means none),
optional ``H_<name>``, ``W_<name>`` (image height and width). ``extri.yml``: ``Rot_<name>``
(3x3, preferred) or ``R_<name>`` (3x1 Rodrigues), ``T_<name>`` (3x1); world -> camera
``x = R X + T``. When both rotations are present they must agree to the precision the file
prints them with, and the matrix wins. Holds everything elastocap's camera holds, exactly
(OpenCV prints 17 significant digits).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._io import opencv_storage_text, save_text
from elastocap.cameras.formats.common import CameraRecord, settle_size, size_from_capture
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

NAME = "easymocap"

# Rot_<name> and R_<name> (Rodrigues) of one camera must agree to the precision the file
# prints them with: RODRIGUES_SLACK times the rounding of both (half a unit in the last
# printed digit of their entries), plus Rot_'s own orthonormality error. The matrix wins.
RODRIGUES_SLACK = 4.0
# When the printed digits cannot be read back from the text, assume this many significant
# digits (what real tools print at the least).
ASSUMED_DIGITS = 6


def read(folder: Path, size: tuple[int, int] | None) -> list[CameraRecord]:
    """``folder/intri.yml`` + ``folder/extri.yml`` (EasyMocap / ZJU-MoCap)."""
    intri_path, extri_path = folder / "intri.yml", folder / "extri.yml"
    for file in (intri_path, extri_path):
        if not file.exists():
            raise FileNotFoundError(f"calibration file missing: {file}")
    intri, extri = open_storage(intri_path), open_storage(extri_path)
    extri_text = extri_path.read_text(errors="replace")
    try:
        names = read_names(intri, intri_path)
        assert names is not None  # required=True raises instead
        extri_names = read_names(extri, extri_path, required=False)
        if extri_names is not None and extri_names != names:
            raise InvalidInputError(
                f"{extri_path}: names {extri_names} differ from {intri_path.name}'s {names}"
            )
        cameras: list[CameraRecord] = []
        for name in names:
            K = read_matrix(intri, f"K_{name}", intri_path, required=True)
            dist = read_matrix(intri, f"dist_{name}", intri_path, required=False)
            rot = read_matrix(extri, f"Rot_{name}", extri_path, required=False)
            rvec = read_matrix(extri, f"R_{name}", extri_path, required=False)
            T = read_matrix(extri, f"T_{name}", extri_path, required=True)
            if rot is None and rvec is None:
                raise InvalidInputError(
                    f"{extri_path}: camera {name!r} has neither Rot_{name} (3x3) nor R_{name} (3x1)"
                )
            R = rot if rot is not None else rodrigues(rvec, f"R_{name}", extri_path)
            if rot is not None and rvec is not None and rot.shape == (3, 3):
                _check_rodrigues_agrees(extri_text, name, rot, rvec, extri_path)
            height = read_scalar(intri, f"H_{name}", intri_path)
            width = read_scalar(intri, f"W_{name}", intri_path)
            if (height is None) != (width is None):
                raise InvalidInputError(f"{intri_path}: camera {name!r} has only one of H_{name}, W_{name}")
            file_size = None if width is None else (width, height)
            # Images are opened only when the calibration does not give the size.
            image_size = size_from_capture(folder, name) if file_size is None else None
            w, h = settle_size(name, file_size, image_size, size, intri_path)
            cameras.append(CameraRecord(name, K, dist, R, T, w, h, f"{intri_path} / {extri_path.name}"))
    finally:
        intri.release()
        extri.release()
    return cameras


def write(folder: Path, cameras: Sequence[Camera]) -> None:
    """``intri.yml`` + ``extri.yml`` in the EasyMocap layout, with both ``R_`` (Rodrigues)
    and ``Rot_`` (3x3) and the image size as ``H_`` / ``W_``; OpenCV prints doubles with
    17 significant digits."""
    def write_names(storage: Any) -> None:
        storage.startWriteStruct("names", cv2.FileNode_SEQ)
        for camera in cameras:
            storage.write("", camera.name)
        storage.endWriteStruct()

    def write_intri(storage: Any) -> None:
        write_names(storage)
        for camera in cameras:
            name = camera.name
            storage.write(f"K_{name}", np.array(camera.K))
            storage.write(f"dist_{name}", np.array(camera.dist).reshape(1, -1))
            storage.write(f"H_{name}", camera.height)
            storage.write(f"W_{name}", camera.width)

    def write_extri(storage: Any) -> None:
        write_names(storage)
        for camera in cameras:
            name = camera.name
            rvec, _ = cv2.Rodrigues(np.array(camera.R))
            storage.write(f"R_{name}", rvec)
            storage.write(f"Rot_{name}", np.array(camera.R))
            storage.write(f"T_{name}", np.array(camera.t).reshape(3, 1))

    # Both files are built in memory first, so a failure leaves the folder as it was.
    intri = opencv_storage_text(folder / "intri.yml", write_intri)
    extri = opencv_storage_text(folder / "extri.yml", write_extri)
    save_text(folder / "intri.yml", intri)
    save_text(folder / "extri.yml", extri)


def _check_rodrigues_agrees(
    text: str, name: str, rot: NDArray[np.float64], rvec: Any, file: Path
) -> None:
    """Rot_<name> (3x3) and R_<name> (Rodrigues) must describe one rotation to the precision
    the file prints them with (see RODRIGUES_SLACK)."""
    from_rvec = rodrigues(rvec, f"R_{name}", file)
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
