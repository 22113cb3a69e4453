"""Rectification of a camera pair through elastocap's own camera model (skew and distortion).

OpenCV's ``stereoRectify`` and ``initUndistortRectifyMap`` ignore ``K[0, 1]`` (the skew), so
a skewed camera rectified by them keeps a vertical disparity that grows with the column. Here
the rectifying rotation is built from the camera centres and optical axes (Fusiello, Trucco
and Verri 2000), and the remap tables come from projecting each rectified pixel's ray through
the original camera with :meth:`elastocap.Camera.project`, which applies distortion and skew.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.cameras import Camera
from elastocap.hull.grid import Grid

__all__ = ["RectifiedPair", "rectify_pair", "volume_corners"]

# Samples per image edge when tracing where an original image lands in the rectified frame.
BORDER_SAMPLES = 64
# Map entries for rectified pixels whose ray does not reach the original image (behind the
# camera or beyond the lens model's fold): far outside, so remap fills them with the border.
OUTSIDE = -1.0e6


def volume_corners(volume: Any) -> NDArray[np.float64]:
    """The 8 corners ``(8, 3)`` of a :class:`~elastocap.Grid`'s box or of ``(2, 3)`` bounds
    (lower, upper), world units."""
    if isinstance(volume, Grid):
        bounds = volume.bounds
    else:
        bounds = np.asarray(volume, dtype=np.float64)
        if bounds.shape != (2, 3) or not np.isfinite(bounds).all() or not (bounds[1] > bounds[0]).all():
            raise InvalidInputError(f"volume must be a Grid or finite (2, 3) bounds with lower < upper, got {volume!r}")
    index = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    return np.stack([bounds[index[:, a], a] for a in range(3)], axis=1)


@dataclass(frozen=True, eq=False)
class RectifiedPair:
    """Two cameras and their rectified versions: same rotation, same focal length, same
    ``cy``, the right camera displaced along the rectified x axis only.

    Attributes
    ----------
    left, right : Camera
        The original cameras; ``left`` is the one at smaller rectified x (a world point is
        at column ``u`` in the left rectified image and ``u - d`` in the right one, with
        disparity ``d`` decreasing with depth).
    left_rectified, right_rectified : Camera
        Pinhole cameras (no distortion, no skew) with the original centres and the common
        rotation; they differ in ``cx`` only.
    swapped : bool
        Whether ``left`` is the second camera given to :func:`rectify_pair`.

    Notes
    -----
    Disparity ``d = u_left - u_right`` of a point at depth ``Z`` (rectified frame) is
    ``f B / Z + (cx_left - cx_right)``: see :attr:`disparity_offset`.
    """

    left: Camera
    right: Camera
    left_rectified: Camera
    right_rectified: Camera
    swapped: bool = field(default=False)

    @property
    def name(self) -> str:
        """``"<left>-<right>"``, the pair's folder name under ``OUT/disparity``."""
        return f"{self.left.name}-{self.right.name}"

    @property
    def rotation(self) -> NDArray[np.float64]:
        """(3, 3): world -> rectified frame (x along the baseline)."""
        return self.left_rectified.R

    @property
    def focal(self) -> float:
        """Focal length of the rectified cameras, pixels."""
        return float(self.left_rectified.K[0, 0])

    @property
    def baseline(self) -> float:
        """Distance between the camera centres, world units."""
        return float(np.linalg.norm(self.right.center - self.left.center))

    @property
    def disparity_offset(self) -> float:
        """``cx_left - cx_right`` of the rectified cameras: the disparity of points at
        infinity, pixels."""
        return float(self.left_rectified.K[0, 2] - self.right_rectified.K[0, 2])

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` of the rectified images."""
        return self.left_rectified.size

    def _maps(self, original: Camera, rectified: Camera) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        width, height = rectified.size
        v, u = np.mgrid[0:height, 0:width].astype(np.float64)
        K = rectified.K
        rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1).reshape(-1, 3)
        world = rays @ rectified.R + rectified.center  # R^T ray + centre
        uv, _ = original.project(world)
        in_camera = original.to_camera(world)
        with np.errstate(divide="ignore", invalid="ignore"):
            radius = np.hypot(in_camera[:, 0], in_camera[:, 1]) / in_camera[:, 2]
        reachable = (in_camera[:, 2] > 0) & (radius < original.fold_radius)
        uv[~reachable] = OUTSIDE
        maps = uv.astype(np.float32).reshape(height, width, 2)
        return np.ascontiguousarray(maps[..., 0]), np.ascontiguousarray(maps[..., 1])

    @cached_property
    def maps(self) -> tuple[tuple[NDArray[np.float32], NDArray[np.float32]], tuple[NDArray[np.float32], NDArray[np.float32]]]:
        """``((left_x, left_y), (right_x, right_y))``: for each rectified pixel, the original
        pixel it samples, float32 ``(height, width)`` tables for ``cv2.remap``."""
        return self._maps(self.left, self.left_rectified), self._maps(self.right, self.right_rectified)

    def rectify(
        self, left_image: Any, right_image: Any, *, interpolation: int = cv2.INTER_LINEAR
    ) -> tuple[NDArray[Any], NDArray[Any]]:
        """The two images resampled into the rectified cameras.

        Parameters
        ----------
        left_image, right_image : (H, W) or (H, W, C) arrays
            Images of :attr:`left` and :attr:`right` (sizes must match those cameras).
        interpolation : int, keyword-only
            ``cv2.INTER_LINEAR`` (default) or another ``cv2.remap`` interpolation; masks
            want ``cv2.INTER_NEAREST``.

        Returns
        -------
        (left, right) : arrays of the rectified size, same dtype; 0 where the rectified
        pixel sees nothing of the original image.

        Notes
        -----
        ``cv2.remap`` quantises the sample positions to 1/32 px, so a rectified image is
        exact to about 0.016 px in position.
        """
        out = []
        for image, camera, (mx, my), label in (
            (left_image, self.left, self.maps[0], "left_image"),
            (right_image, self.right, self.maps[1], "right_image"),
        ):
            array = np.asarray(image)
            if array.ndim not in (2, 3) or array.shape[:2] != (camera.height, camera.width):
                raise InvalidInputError(
                    f"{label} must be a ({camera.height}, {camera.width}[, C]) image of camera {camera.name!r}, "
                    f"got shape {array.shape}"
                )
            out.append(cv2.remap(np.ascontiguousarray(array), mx, my, interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0))
        return out[0], out[1]

    def to_rectified(self, side: str, uv: Any) -> NDArray[np.float64]:
        """Original pixels of the ``side`` (``"left"`` / ``"right"``) camera -> rectified
        pixels ``(N, 2)``; NaN where the camera model has no ray."""
        original, rectified = self._side(side)
        _, directions = original.rays(uv)
        rect = directions @ rectified.R.T
        with np.errstate(divide="ignore", invalid="ignore"):
            ab = rect[:, :2] / rect[:, 2:]
        K = rectified.K
        return np.stack([K[0, 0] * ab[:, 0] + K[0, 2], K[1, 1] * ab[:, 1] + K[1, 2]], axis=1)

    def _side(self, side: str) -> tuple[Camera, Camera]:
        if side == "left":
            return self.left, self.left_rectified
        if side == "right":
            return self.right, self.right_rectified
        raise InvalidInputError(f"side must be 'left' or 'right', got {side!r}")

    @cached_property
    def left_inverse_maps(self) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """For each pixel of the original left image, its rectified position: float32
        ``(height, width)`` tables for ``cv2.remap`` from rectified back to original."""
        v, u = np.mgrid[0 : self.left.height, 0 : self.left.width]
        rectified = self.to_rectified("left", np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64))
        table = np.where(np.isfinite(rectified), rectified, OUTSIDE).astype(np.float32).reshape(self.left.height, self.left.width, 2)
        return np.ascontiguousarray(table[..., 0]), np.ascontiguousarray(table[..., 1])

    def to_left_original(self, image: Any, *, interpolation: int = cv2.INTER_NEAREST) -> NDArray[Any]:
        """A rectified-left image (e.g. a mask) resampled into the original left camera."""
        mx, my = self.left_inverse_maps
        return cv2.remap(np.ascontiguousarray(image), mx, my, interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def _footprint(camera: Camera, rotation: NDArray[np.float64]) -> NDArray[np.float64]:
    """Normalised rectified coordinates ``(N, 2)`` of the camera's image border, for rays
    in front of the rectified frame."""
    w, h = camera.width, camera.height
    s = np.linspace(0, 1, BORDER_SAMPLES)
    border = np.concatenate([
        np.stack([s * (w - 1), np.zeros_like(s)], 1), np.stack([s * (w - 1), np.full_like(s, h - 1)], 1),
        np.stack([np.zeros_like(s), s * (h - 1)], 1), np.stack([np.full_like(s, w - 1), s * (h - 1)], 1),
    ])
    _, directions = camera.rays(border)
    rect = directions @ rotation.T
    keep = np.isfinite(rect).all(axis=1) & (rect[:, 2] > 1e-6)
    return rect[keep, :2] / rect[keep, 2:]


def rectify_pair(
    first: Camera,
    second: Camera,
    *,
    size: tuple[int, int] | None = None,
    focal: float | None = None,
    volume: Any = None,
) -> RectifiedPair:
    """Rectify two cameras: a common rotation with x along the baseline.

    Parameters
    ----------
    first, second : Camera
        Any two cameras with distinct centres (distortion and skew are handled).
    size : (width, height), keyword-only
        Rectified image size; default: the left camera's.
    focal : float, keyword-only
        Rectified focal length, pixels; default: the mean of the four original focal lengths.
    volume : Grid or (2, 3) bounds, keyword-only
        The capture volume: when given, each rectified image is centred on it (so the
        pixels are spent where the subject is); otherwise on the original image's footprint.

    Returns
    -------
    RectifiedPair
        ``left`` is whichever camera lies on the left, looking along the cameras' mean
        optical axis, so the rectified images are upright.

    Raises
    ------
    InvalidInputError
        Coincident centres; cameras that look in opposite directions or whose fields of
        view share no direction (no overlap); a bad ``size`` or ``focal``.

    Notes
    -----
    Fusiello, Trucco and Verri (2000): new x axis = the baseline; new y = (mean optical axis)
    x (new x); new z = x x y. The rectified cameras keep their centres, so depths and 3-D
    points from the rectified pair are in the world frame of the rig.
    """
    for label, camera in (("first", first), ("second", second)):
        if not isinstance(camera, Camera):
            raise InvalidInputError(f"{label} must be an elastocap Camera, got {type(camera).__name__}")
    baseline = second.center - first.center
    length = float(np.linalg.norm(baseline))
    if length <= 1e-12 * max(1.0, float(np.linalg.norm(first.center))):
        raise InvalidInputError(f"cameras {first.name!r} and {second.name!r} have the same centre: no baseline")
    swapped = float(baseline @ (first.R[0] + second.R[0])) < 0
    left, right = (second, first) if swapped else (first, second)
    x = (right.center - left.center) / length
    axis = left.R[2] + right.R[2]
    if np.linalg.norm(axis) < 1e-6:
        raise InvalidInputError(f"cameras {first.name!r} and {second.name!r} look in opposite directions: no overlap")
    y = np.cross(axis, x)
    if np.linalg.norm(y) < 1e-6:
        raise InvalidInputError(
            f"cameras {first.name!r} and {second.name!r} look along their baseline: they cannot be rectified"
        )
    y /= np.linalg.norm(y)
    rotation = np.stack([x, y, np.cross(x, y)])
    width, height = size if size is not None else left.size
    if int(width) <= 0 or int(height) <= 0:
        raise InvalidInputError(f"size must be positive (width, height), got {size!r}")
    width, height = int(width), int(height)
    f = float(np.mean([left.K[0, 0], left.K[1, 1], right.K[0, 0], right.K[1, 1]])) if focal is None else float(focal)
    if not (np.isfinite(f) and f > 0):
        raise InvalidInputError(f"focal must be a positive number, got {focal!r}")
    feet = [_footprint(c, rotation) for c in (left, right)]
    for camera, foot in zip((left, right), feet):
        if len(foot) == 0:
            raise InvalidInputError(f"camera {camera.name!r} sees nothing in front of the rectified pair: no overlap")
    low = max(feet[0][:, 1].min(), feet[1][:, 1].min())
    high = min(feet[0][:, 1].max(), feet[1][:, 1].max())
    if low >= high:
        raise InvalidInputError(f"cameras {first.name!r} and {second.name!r} share no image rows: no overlap")
    if volume is not None:
        corners = volume_corners(volume)
        centres = []
        for camera in (left, right):
            rect = (corners - camera.center) @ rotation.T
            if (rect[:, 2] <= 0).all():
                raise InvalidInputError(f"the volume is behind camera {camera.name!r}")
            rect = rect[rect[:, 2] > 0]
            ab = rect[:, :2] / rect[:, 2:]
            centres.append((ab.min(axis=0) + ab.max(axis=0)) / 2)
        centre_v = (centres[0][1] + centres[1][1]) / 2
        centre_u = [centres[0][0], centres[1][0]]
    else:
        centre_v = (low + high) / 2
        centre_u = [(foot[:, 0].min() + foot[:, 0].max()) / 2 for foot in feet]
    cy = (height - 1) / 2 - f * centre_v
    rectified = []
    for camera, cu in zip((left, right), centre_u):
        K = np.array([[f, 0.0, (width - 1) / 2 - f * cu], [0.0, f, cy], [0.0, 0.0, 1.0]])
        rectified.append(Camera(camera.name, K, None, rotation, -rotation @ camera.center, width, height))
    return RectifiedPair(left, right, rectified[0], rectified[1], swapped)
