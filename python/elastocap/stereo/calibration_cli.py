"""``elastocap calibrate IMAGES --board WxH --square-size S --out RIG``: board images in,
a rig file out.

Two layouts of ``IMAGES`` are read:

- one folder per camera, ``IMAGES/<camera>/<view>.png|jpg``: the images of one board
  placement have the same file stem in every camera's folder;
- a flat folder of ``<camera><view>.png|jpg`` files, the camera being the name's leading
  non-digit part and the view its trailing digits: ``left01.jpg`` and ``right01.jpg`` are
  cameras ``left`` and ``right`` seeing view ``01`` (the layout of the shared chessboard
  pairs and of OpenCV's samples).

Cameras are ordered by name; views by key, and the board of the first view is the world
frame unless ``--world CAMERA`` is given.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from elastocap._core import InvalidInputError
from elastocap.stereo.board import Chessboard
from elastocap.stereo.calibration import UnderdeterminedCalibrationWarning
from elastocap.stereo.calibration_detect import BoardView, find_chessboard_corners
from elastocap.stereo.calibration_rig import RigCalibration, calibrate_rig

__all__ = ["board_images", "parse_board", "run_calibrate"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
_FLAT_NAME = re.compile(r"^(?P<camera>.*?[^\d])(?P<view>\d+)$")


def parse_board(text: str) -> tuple[int, int]:
    """``"7x5"`` -> ``(7, 5)`` inner corners."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not match:
        raise InvalidInputError(f"--board must be COLUMNSxROWS of inner corners, e.g. 7x5, got {text!r}")
    columns, rows = int(match.group(1)), int(match.group(2))
    # Checked here, not only by Chessboard, so the message names the option the user typed.
    if columns < 2 or rows < 2:
        raise InvalidInputError(f"--board needs at least 2x2 inner corners, got {text!r}")
    return columns, rows


def board_images(folder: Path) -> dict[str, dict[str, Path]]:
    """``{camera: {view: image path}}`` from either layout (see the module docstring)."""
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder} is not a folder")
    images: dict[str, dict[str, Path]] = {}
    subfolders = sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
    for sub in subfolders:
        files = sorted(p for p in sub.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if files:
            images[sub.name] = {p.stem: p for p in files}
    if images:
        return images
    for path in sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES):
        match = _FLAT_NAME.match(path.stem)
        if match is None:
            raise InvalidInputError(
                f"{path.name}: in a flat folder, image names must be <camera><view digits> (e.g. left01.jpg)"
            )
        images.setdefault(match.group("camera").rstrip("_-. "), {})[match.group("view")] = path
    if not images:
        raise InvalidInputError(f"{folder}: no images (IMAGES/<camera>/*.png|jpg or <camera><view>.png|jpg)")
    return dict(sorted(images.items()))


def run_calibrate(
    images_folder: str | Path,
    board_text: str,
    square_size: float,
    out: str | Path,
    *,
    world: str | None = None,
    focal_length: float | None = None,
    print_line: Any = print,
) -> RigCalibration:
    """Detect the board in every image, calibrate the rig, save it, and report.

    Parameters
    ----------
    images_folder : str or Path
        ``IMAGES`` (see the module docstring).
    board_text : str
        Inner corners, ``"COLUMNSxROWS"``.
    square_size : float
        Square edge in the unit wanted for the rig (e.g. metres).
    out : str or Path
        A folder (receives ``intri.yml`` + ``extri.yml``) or a ``.json`` path.
    world : str, keyword-only
        Camera whose frame is the world; default: the board of the first view.
    focal_length : float, keyword-only
        Focal length (pixels) to hold where the views do not determine it.
    print_line : callable, keyword-only
        Where report lines go.

    Returns
    -------
    RigCalibration
    """
    columns, rows = parse_board(board_text)
    board = Chessboard(columns, rows, square_size)
    paths = board_images(Path(images_folder))
    detections: dict[str, dict[str, BoardView]] = {}
    sizes: dict[str, tuple[int, int]] = {}
    for camera, views in paths.items():
        detections[camera] = {}
        for view, path in views.items():
            image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if image is None:
                raise InvalidInputError(f"{path}: not a readable image")
            size = (image.shape[1], image.shape[0])
            if sizes.setdefault(camera, size) != size:
                raise InvalidInputError(f"{path}: image size {size} differs from camera {camera!r}'s {sizes[camera]}")
            found = find_chessboard_corners(image, board)
            if found is not None:
                detections[camera][view] = found
        print_line(f"{camera}: board found in {len(detections[camera])} of {len(views)} images")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UnderdeterminedCalibrationWarning)
        result = calibrate_rig(detections, board, sizes, world=world, focal_length=focal_length)
    for warning in caught:
        if issubclass(warning.category, UnderdeterminedCalibrationWarning):
            print_line(f"warning: {warning.message}")
        else:
            warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
    for calibrated in result.rig.cameras:
        K, name = calibrated.K, calibrated.name
        print_line(
            f"{name}: RMS {result.rms[name]:.3f} px over {len(result.cameras[name].views)} views; "
            f"fx {K[0, 0]:.2f} fy {K[1, 1]:.2f} cx {K[0, 2]:.2f} cy {K[1, 2]:.2f} px, "
            f"dist {np.array2string(calibrated.dist, precision=4)}; centre {np.array2string(calibrated.center, precision=4)}"
        )
    result.rig.save(out)
    print_line(f"wrote {out} (world frame: {result.world}, units of --square-size)")
    return result
