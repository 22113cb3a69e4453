"""Calibration boards: their geometry, and images of them rendered through a camera model.

A :class:`Chessboard` knows where its inner corners are (board frame, world units) and what
it looks like (reflectance at any board point). :class:`BoardRenderer` makes the image a
:class:`~elastocap.Camera` (distortion and skew included) sees of a board in a given pose,
by inverse mapping: every pixel is cut into ``supersample x supersample`` sub-pixels, each
sub-pixel's ray (the camera model's exact back-projection) is intersected with the board's
plane, and the reflectances are averaged. Calibration is then tested against a known rig.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_positive
from elastocap.cameras import Camera

__all__ = ["Board", "BoardRenderer", "Chessboard", "CharucoTarget", "random_board_poses", "subpixel_rays"]

# Grey levels of the printed board and of the empty scene (0..255 scale).
DARK, LIGHT = 25.0, 225.0


class Board(Protocol):
    """What the calibration and the renderer need of a board."""

    @property
    def object_points(self) -> NDArray[np.float64]: ...

    @property
    def extent(self) -> NDArray[np.float64]: ...

    def reflectance(self, xy: NDArray[np.float64]) -> NDArray[np.float64]: ...


@dataclass(frozen=True)
class Chessboard:
    """A chessboard of ``columns x rows`` inner corners and square edge ``square_size``.

    Parameters
    ----------
    columns, rows : int
        Inner corners along the board's x and y axes (OpenCV's ``patternSize``); a board of
        ``columns x rows`` inner corners has ``(columns + 1) x (rows + 1)`` squares.
    square_size : float
        Edge of a square, world units (the calibration's unit of length).
    margin : float
        White border around the squares, in squares (OpenCV's detector needs one).

    Notes
    -----
    Board frame: corner ``(i, j)`` (column i, row j) is at ``(i, j, 0) * square_size``; the
    squares cover ``[-1, columns] x [-1, rows]`` squares and the square with corners
    ``(0, 0)`` and ``(1, 1)`` is dark. When ``columns + rows`` is odd the pattern has no
    180-degree symmetry, so every corner's label can be read off an image; when it is even
    (e.g. 7x5) a corner and its opposite look alike and only the image layout can label them.
    """

    columns: int
    rows: int
    square_size: float = 1.0
    margin: float = 1.0

    def __post_init__(self) -> None:
        as_count("columns", self.columns, 2)
        as_count("rows", self.rows, 2)
        as_positive("square_size", self.square_size)
        if not (np.isfinite(self.margin) and self.margin >= 0):
            raise InvalidInputError(f"margin must be a finite number >= 0, got {self.margin!r}")

    @property
    def pattern_size(self) -> tuple[int, int]:
        """``(columns, rows)``, OpenCV's ``patternSize``."""
        return (self.columns, self.rows)

    @property
    def symmetric(self) -> bool:
        """Whether a 180-degree turn maps the pattern onto itself (``columns + rows`` even)."""
        return (self.columns + self.rows) % 2 == 0

    @cached_property
    def object_points(self) -> NDArray[np.float64]:
        """``(columns * rows, 3)`` float64: inner corners in the board frame (world units),
        row by row (corner ``(i, j)`` at index ``j * columns + i``), as OpenCV orders them."""
        j, i = np.mgrid[0 : self.rows, 0 : self.columns]
        points = np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], axis=1) * self.square_size
        points.flags.writeable = False
        return points

    @property
    def extent(self) -> NDArray[np.float64]:
        """``(2, 2)``: lower and upper ``(x, y)`` corners of the printed board, margin
        included (world units)."""
        low = -(1.0 + self.margin)
        return np.array([[low, low], [self.columns + self.margin, self.rows + self.margin]]) * self.square_size

    def reflectance(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Grey level (0..255) of board points ``(N, 2)`` (board frame); NaN off the board."""
        q = np.floor(xy / self.square_size)
        dark = (q[:, 0] + q[:, 1]) % 2 == 0
        squares = (q[:, 0] >= -1) & (q[:, 0] <= self.columns - 1) & (q[:, 1] >= -1) & (q[:, 1] <= self.rows - 1)
        (x0, y0), (x1, y1) = self.extent
        on_board = (xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)
        grey = np.where(squares & dark, DARK, LIGHT)
        return np.where(on_board, grey, np.nan)


@dataclass(frozen=True)
class CharucoTarget:
    """A ChArUco board (chessboard with ArUco markers in the light squares).

    Parameters
    ----------
    squares_x, squares_y : int
        Squares along x and y (so ``(squares_x - 1) x (squares_y - 1)`` inner corners).
    square_size, marker_size : float
        Edges of a square and of a marker, world units; ``marker_size < square_size``.
    dictionary : str
        An OpenCV ArUco dictionary name, e.g. ``"DICT_5X5_100"``.
    margin : float
        White border around the squares, in squares.

    Notes
    -----
    Needs ``cv2.aruco``. Board frame as OpenCV's ``CharucoBoard``: corner id ``k`` at
    ``board.getChessboardCorners()[k]``, origin at the board's outer corner; the rendered
    texture is OpenCV's own ``generateImage``.
    """

    squares_x: int
    squares_y: int
    square_size: float
    marker_size: float
    dictionary: str = "DICT_5X5_100"
    margin: float = 0.5

    def __post_init__(self) -> None:
        as_count("squares_x", self.squares_x, 3)
        as_count("squares_y", self.squares_y, 3)
        as_positive("square_size", self.square_size)
        as_positive("marker_size", self.marker_size)
        if self.marker_size >= self.square_size:
            raise InvalidInputError(
                f"marker_size must be below square_size, got {self.marker_size} >= {self.square_size}"
            )
        if not hasattr(cv2, "aruco"):
            raise InvalidInputError("ChArUco boards need cv2.aruco, which this OpenCV build lacks")
        if not hasattr(cv2.aruco, self.dictionary):
            raise InvalidInputError(f"dictionary must name a cv2.aruco dictionary, got {self.dictionary!r}")

    @cached_property
    def cv_board(self) -> Any:
        """The ``cv2.aruco.CharucoBoard``."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(
            (self.squares_x, self.squares_y), self.square_size, self.marker_size, dictionary
        )

    @cached_property
    def object_points(self) -> NDArray[np.float64]:
        """``(N, 3)`` float64: inner corners by id, board frame, world units."""
        points = np.asarray(self.cv_board.getChessboardCorners(), dtype=np.float64).reshape(-1, 3)
        points.flags.writeable = False
        return points

    @property
    def extent(self) -> NDArray[np.float64]:
        """``(2, 2)``: lower and upper ``(x, y)`` of the printed board, margin included."""
        m = self.margin * self.square_size
        return np.array([[-m, -m], [self.squares_x * self.square_size + m, self.squares_y * self.square_size + m]])

    @cached_property
    def _texture(self) -> tuple[NDArray[np.float32], float]:
        pixels_per_square = 64
        size = (self.squares_x * pixels_per_square, self.squares_y * pixels_per_square)
        image = self.cv_board.generateImage(size, marginSize=0, borderBits=1)
        texture = np.where(image > 127, LIGHT, DARK).astype(np.float32)
        return texture, pixels_per_square / self.square_size

    def reflectance(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Grey level (0..255) of board points ``(N, 2)`` (board frame); NaN off the board."""
        texture, scale = self._texture
        # Texture pixel (c, r) covers board [c, c + 1) / scale: centres at (c + 0.5) / scale.
        # Bilinear lookup (cv2.remap cannot take more than 32767 points per row or column).
        with np.errstate(invalid="ignore"):
            at = np.nan_to_num(xy * scale - 0.5, nan=-1.0, posinf=-1.0, neginf=-1.0)
        rows, columns = texture.shape
        c0 = np.clip(np.floor(at[:, 0]), 0, columns - 2).astype(np.int64)
        r0 = np.clip(np.floor(at[:, 1]), 0, rows - 2).astype(np.int64)
        fc = np.clip(at[:, 0] - c0, 0.0, 1.0)
        fr = np.clip(at[:, 1] - r0, 0.0, 1.0)
        grey = (
            (texture[r0, c0] * (1 - fc) + texture[r0, c0 + 1] * fc) * (1 - fr)
            + (texture[r0 + 1, c0] * (1 - fc) + texture[r0 + 1, c0 + 1] * fc) * fr
        ).astype(np.float64)
        (x0, y0), (x1, y1) = self.extent
        inside_squares = (xy[:, 0] >= 0) & (xy[:, 1] >= 0) & (xy * scale < texture.shape[::-1]).all(axis=1)
        on_board = (xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)
        return np.where(on_board, np.where(inside_squares, grey, LIGHT), np.nan)


class BoardRenderer:
    """Images of a planar board seen by one camera, exact to its lens model.

    Parameters
    ----------
    camera : Camera
        Any camera (distortion, skew); its pose is used: boards are posed in the world.
    supersample : int, keyword-only
        Sub-pixels per pixel side (default 3): each pixel averages ``supersample**2`` rays.

    Notes
    -----
    The sub-pixel rays are computed once (the camera model's Newton back-projection) and
    reused for every board pose. Sub-pixels whose ray misses the board see a smooth random
    grey background.
    """

    def __init__(self, camera: Camera, *, supersample: int = 3) -> None:
        if not isinstance(camera, Camera):
            raise InvalidInputError(f"camera must be an elastocap Camera, got {type(camera).__name__}")
        self.camera = camera
        self.supersample = as_count("supersample", supersample)
        directions = subpixel_rays(camera, self.supersample)
        # World frame, one column per axis (float32 halves the memory traffic; hit points
        # then err by ~1e-7 of the distance), NaN where no ray.
        self._directions = [np.ascontiguousarray(directions[:, k], dtype=np.float32) for k in range(3)]

    def render(
        self,
        board: Board,
        R: Any,
        t: Any,
        *,
        noise: float = 2.0,
        rng: np.random.Generator | None = None,
    ) -> NDArray[np.uint8]:
        """The grey image of ``board`` posed at ``X_world = R X_board + t``.

        Parameters
        ----------
        board : Chessboard or CharucoTarget
        R : (3, 3) array_like of float
            Board -> world rotation.
        t : (3,) array_like of float
            Board origin in the world (world units).
        noise : float, keyword-only
            Standard deviation of the added Gaussian sensor noise (grey levels).
        rng : numpy Generator, keyword-only
            For the background and the noise (default: seeded with 0).

        Returns
        -------
        (height, width) uint8
        """
        rng = np.random.default_rng(0) if rng is None else rng
        R_ = np.asarray(R, dtype=np.float64)
        t_ = np.asarray(t, dtype=np.float64).reshape(3)
        origin = R_.T @ (self.camera.center - t_)  # camera centre, board frame
        dx, dy, dz = self._directions
        # Directions in the board frame: R^T d, one axis at a time.
        d = [R_[0, k] * dx + R_[1, k] * dy + R_[2, k] * dz for k in range(3)]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = -origin[2] / d[2]
            s[~(s > 0)] = np.inf
            hit = np.stack([origin[0] + s * d[0], origin[1] + s * d[1]], axis=1).astype(np.float64)
        grey = board.reflectance(hit)
        h, w, n = self.camera.height, self.camera.width, self.supersample
        background = _smooth_background(h * n, w * n, rng).reshape(h, n, w, n).transpose(0, 2, 1, 3).ravel()
        grey = np.where(np.isnan(grey), background, grey).reshape(h, w, n * n).mean(axis=2)
        grey = grey + rng.normal(0.0, noise, grey.shape)
        return np.clip(np.rint(grey), 0, 255).astype(np.uint8)


def subpixel_rays(camera: Camera, supersample: int) -> NDArray[np.float64]:
    """World directions ``(H * W * n * n, 3)`` (not normalised; NaN where the lens model has
    no ray) of the ``n x n`` sub-pixels of every pixel, pixel by pixel in row-major order,
    sub-pixels row-major within a pixel.

    Notes
    -----
    Exact back-projection (:meth:`Camera.rays`, Newton on the distortion) on the lattice of
    pixel corners, bilinearly interpolated at the sub-pixels: the lens map is smooth, so this
    differs from back-projecting every sub-pixel by under 1e-3 px (tests/test_calibration.py
    checks it) at n^2 times less Newton work.
    """
    n = supersample
    local = camera.replace(R=np.eye(3), t=np.zeros(3))
    grid_u, grid_v = np.meshgrid(np.arange(camera.width + 1) - 0.5, np.arange(camera.height + 1) - 0.5)
    _, lattice = local.rays(np.stack([grid_u.ravel(), grid_v.ravel()], axis=1))
    ab = (lattice[:, :2] / lattice[:, 2:]).reshape(camera.height + 1, camera.width + 1, 2)
    offsets = (np.arange(n) + 0.5) / n  # within a pixel, from its top-left corner
    fv = offsets[:, None, None] * np.ones((1, n, 1))  # (n, n, 1): sub-pixel row offset
    fu = offsets[None, :, None] * np.ones((n, 1, 1))  # (n, n, 1): sub-pixel column offset
    top = ab[:-1, :-1, None, None] * (1 - fu) + ab[:-1, 1:, None, None] * fu
    bottom = ab[1:, :-1, None, None] * (1 - fu) + ab[1:, 1:, None, None] * fu
    sub = (top * (1 - fv) + bottom * fv).reshape(-1, 2)
    return np.hstack([sub, np.ones((len(sub), 1))]) @ camera.R


def _smooth_background(height: int, width: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """A cluttered but smooth grey scene: random values on a coarse grid, upsampled."""
    coarse = rng.uniform(60.0, 190.0, (max(2, height // 24), max(2, width // 24))).astype(np.float32)
    return cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC).astype(np.float64)


def random_board_poses(
    cameras: list[Camera],
    board: Board,
    count: int,
    *,
    rng: np.random.Generator,
    distance: tuple[float, float],
    max_tilt: float = 50.0,
    max_roll: float = 30.0,
    border: float = 8.0,
    max_tries: int = 20000,
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Board poses that every camera in ``cameras`` sees whole.

    Parameters
    ----------
    cameras : list of Camera
    board : Chessboard or CharucoTarget
    count : int
        Poses to return.
    rng : numpy Generator, keyword-only
    distance : (float, float), keyword-only
        Range of the board centre's distance from the cameras' mean centre (world units).
    max_tilt : float, keyword-only
        Largest angle between the board normal and the direction to the cameras (degrees).
    max_roll : float, keyword-only
        Largest turn of the board about its normal (degrees), small enough that the
        detector's ordering of a symmetric board stays consistent between cameras.
    border : float, keyword-only
        Pixels the printed board keeps from every image edge.
    max_tries : int, keyword-only

    Returns
    -------
    list of (R (3, 3), t (3,))
        Board -> world poses, ``X_world = R X_board + t``.

    Raises
    ------
    InvalidInputError
        When ``max_tries`` random poses give fewer than ``count`` visible ones.
    """
    centres = np.array([c.center for c in cameras])
    middle = centres.mean(axis=0)
    forward = np.mean([c.R[2] for c in cameras], axis=0)
    forward /= np.linalg.norm(forward)
    (x0, y0), (x1, y1) = board.extent
    outline = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]])
    edges = np.concatenate([outline + f * (np.roll(outline, -1, axis=0) - outline) for f in np.linspace(0, 1, 8)])
    centre_board = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    # A board facing the cameras: its z axis points away from them, its x along their x.
    base = np.mean([c.R for c in cameras], axis=0)
    u, _, vt = np.linalg.svd(base)
    facing = (u @ vt).T  # board -> world rotation of a board parallel to the image planes
    poses: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
    for _ in range(max_tries):
        if len(poses) == count:
            break
        axis = rng.normal(size=2)
        axis = np.array([axis[0], axis[1], 0.0]) / np.linalg.norm(axis)
        tilt = np.radians(rng.uniform(0, max_tilt))
        roll = np.radians(rng.uniform(-max_roll, max_roll))
        R_tilt, _ = cv2.Rodrigues(axis * tilt)
        R_roll, _ = cv2.Rodrigues(np.array([0.0, 0.0, roll]))
        R = facing @ R_tilt @ R_roll
        direction = forward + 0.35 * rng.normal(size=3)
        centre = middle + rng.uniform(*distance) * direction / np.linalg.norm(direction)
        t = centre - R @ centre_board
        points = edges @ R.T + t
        ok = True
        for camera in cameras:
            uv, depth = camera.project(points)
            ok &= bool(
                camera.visible(points).all()
                and (uv.min(axis=0) >= border).all()
                and (uv[:, 0] <= camera.width - 1 - border).all()
                and (uv[:, 1] <= camera.height - 1 - border).all()
            )
        if ok:
            poses.append((R, t))
    if len(poses) < count:
        raise InvalidInputError(
            f"found only {len(poses)} of {count} board poses seen whole by every camera in {max_tries} tries"
        )
    return poses
