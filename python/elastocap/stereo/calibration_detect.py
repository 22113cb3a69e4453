"""Finding calibration boards in images: chessboard and ChArUco corners, labelled.

A detection is a :class:`BoardView`: the ids of the board corners found (indices into the
board's ``object_points``) and their sub-pixel image positions. The calibration only ever
sees ``BoardView`` objects, so chessboards and ChArUco boards go through the same code.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from elastocap._core import InvalidInputError
from elastocap.stereo.board import CharucoTarget, Chessboard

__all__ = ["BoardView", "find_board", "find_charuco_corners", "find_chessboard_corners"]

# cornerSubPix stops when a corner moves less than this (pixels) or after SUBPIX_ITERATIONS.
SUBPIX_EPS = 1e-4
SUBPIX_ITERATIONS = 100


@dataclass(frozen=True)
class BoardView:
    """The corners of a board found in one image.

    Attributes
    ----------
    ids : (M,) int64
        Indices into the board's ``object_points``, increasing.
    corners : (M, 2) float64
        Their image positions ``(u, v)``, pixels (origin at the centre of the top-left pixel).
    """

    ids: NDArray[np.int64]
    corners: NDArray[np.float64]

    def __post_init__(self) -> None:
        ids = np.asarray(self.ids, dtype=np.int64).reshape(-1)
        corners = np.asarray(self.corners, dtype=np.float64)
        if corners.shape != (ids.size, 2):
            raise InvalidInputError(f"corners must have shape ({ids.size}, 2) to match ids, got {corners.shape}")
        if not np.isfinite(corners).all():
            raise InvalidInputError("corners must be finite")
        order = np.argsort(ids, kind="stable")
        object.__setattr__(self, "ids", ids[order])
        object.__setattr__(self, "corners", corners[order])


def _grey(image: Any, name: str = "image") -> NDArray[np.uint8]:
    array = np.asarray(image)
    if array.ndim == 3 and array.shape[2] in (3, 4):
        array = cv2.cvtColor(np.ascontiguousarray(array[..., :3]), cv2.COLOR_RGB2GRAY)
    if array.ndim != 2 or array.size == 0:
        raise InvalidInputError(f"{name} must be an (H, W) or (H, W, 3) image, got shape {array.shape}")
    if array.dtype != np.uint8:
        raise InvalidInputError(f"{name} must be uint8, got {array.dtype}")
    return np.ascontiguousarray(array)


def find_chessboard_corners(image: Any, board: Chessboard) -> BoardView | None:
    """The inner corners of a chessboard, sub-pixel, labelled; None when not found.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8
        Grey or RGB.
    board : Chessboard

    Returns
    -------
    BoardView or None
        All ``columns * rows`` corners with their ids.

    Notes
    -----
    OpenCV's ``findChessboardCorners`` (falling back on ``findChessboardCornersSB``), then
    ``cornerSubPix`` with a window of about 0.4 squares. OpenCV may return the grid in any
    of its orientations; the labels are made canonical: the board's x and y axes must turn
    the way the image's do (a board is seen from its front), and the square between corners
    ``(0, 0)`` and ``(1, 1)`` must be the dark one (see :class:`Chessboard`). On a symmetric
    board (``columns + rows`` even) both ends have dark squares, and corner 0 is taken as
    the one nearer the image's top-left, which labels the board consistently between cameras
    that see it upright.
    """
    grey = _grey(image)
    size = board.pattern_size
    found, corners = cv2.findChessboardCorners(
        grey, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    )
    if not found:
        found, corners = cv2.findChessboardCornersSB(grey, size, flags=cv2.CALIB_CB_EXHAUSTIVE)
        if not found:
            return None
    grid = corners.reshape(board.rows, board.columns, 2).astype(np.float64)
    step = min(
        float(np.linalg.norm(np.diff(grid, axis=1), axis=2).min()),
        float(np.linalg.norm(np.diff(grid, axis=0), axis=2).min()),
    )
    half = int(np.clip(round(0.4 * step), 2, 11))
    refined = cv2.cornerSubPix(
        grey, grid.reshape(-1, 1, 2).astype(np.float32), (half, half), (-1, -1),
        (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, SUBPIX_ITERATIONS, SUBPIX_EPS),
    )
    grid = _canonical(refined.reshape(board.rows, board.columns, 2).astype(np.float64), grey, board)
    return BoardView(np.arange(board.columns * board.rows), grid.reshape(-1, 2))


def _canonical(grid: NDArray[np.float64], grey: NDArray[np.uint8], board: Chessboard) -> NDArray[np.float64]:
    """The ``(rows, columns, 2)`` corner grid relabelled to the board's own labels."""
    dx = grid[0, 1] - grid[0, 0]
    dy = grid[1, 0] - grid[0, 0]
    if dx[0] * dy[1] - dx[1] * dy[0] < 0:  # seen mirrored: the rows run the other way
        grid = grid[:, ::-1]
    if board.symmetric:
        first, last = grid[0, 0], grid[-1, -1]
        if first.sum() > last.sum():
            grid = grid[::-1, ::-1]
        return grid
    if _square_grey(grey, grid, 0, 0) > _square_grey(grey, grid, -2, -2):
        grid = grid[::-1, ::-1]
    return grid


def _square_grey(grey: NDArray[np.uint8], grid: NDArray[np.float64], j: int, i: int) -> float:
    """Mean grey level near the centre of the square whose top-left corner is grid[j, i]."""
    quad = grid[[j, j, j + 1, j + 1], [i, i + 1, i + 1, i]]
    centre = quad.mean(axis=0)
    samples = centre + 0.25 * (quad - centre)  # halfway to the corners: inside the square
    points = np.vstack([centre, samples])
    values = ndimage.map_coordinates(grey.astype(np.float32), [points[:, 1], points[:, 0]], order=1, mode="nearest")
    return float(np.mean(values))


def find_charuco_corners(image: Any, board: CharucoTarget, *, minimum: int = 6) -> BoardView | None:
    """The ChArUco corners found in an image, by id; None when fewer than ``minimum``.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8
    board : CharucoTarget
    minimum : int, keyword-only
        Fewest corners worth keeping (a homography needs 4; default 6).

    Returns
    -------
    BoardView or None

    Notes
    -----
    OpenCV's ``CharucoDetector`` (markers, then the chessboard corners between them,
    sub-pixel). The ids are OpenCV's, so partial views of the board are fine.
    """
    grey = _grey(image)
    detector = cv2.aruco.CharucoDetector(board.cv_board)
    corners, ids, _, _ = detector.detectBoard(grey)
    if ids is None or len(ids) < minimum:
        return None
    return BoardView(np.asarray(ids, dtype=np.int64).reshape(-1), np.asarray(corners, dtype=np.float64).reshape(-1, 2))


def find_board(image: Any, board: Chessboard | CharucoTarget) -> BoardView | None:
    """:func:`find_chessboard_corners` or :func:`find_charuco_corners`, by board type."""
    if isinstance(board, Chessboard):
        return find_chessboard_corners(image, board)
    if isinstance(board, CharucoTarget):
        return find_charuco_corners(image, board)
    raise InvalidInputError(f"board must be a Chessboard or CharucoTarget, got {type(board).__name__}")


def find_boards(
    images: Mapping[str, Mapping[str, Any]], board: Chessboard | CharucoTarget
) -> dict[str, dict[str, BoardView]]:
    """:func:`find_board` on ``images[camera][view]``; views where nothing is found are left
    out."""
    found: dict[str, dict[str, BoardView]] = {}
    for camera, views in images.items():
        found[camera] = {}
        for view, image in views.items():
            detection = find_board(image, board)
            if detection is not None:
                found[camera][view] = detection
    return found
