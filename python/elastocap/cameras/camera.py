"""The pinhole camera with OpenCV distortion and skew.

A :class:`Camera` maps world points to pixels (``project``) and pixels to rays (``rays``);
:class:`elastocap.cameras.rig.Rig` holds the cameras of a capture.

Conventions (DESIGN.md): world -> camera is ``x_cam = R X + t``; pixel coordinates are
``(u, v)`` = (column, row) with the origin at the centre of the top-left pixel, the OpenCV
convention, so the image covers ``-0.5 <= u < width - 0.5`` and ``-0.5 <= v < height - 0.5``.
"""

from __future__ import annotations

from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_float_array
from elastocap.cameras.checks import (
    as_distortion,
    as_image_size,
    as_intrinsics,
    as_points2,
    as_points3,
    as_rotation,
    read_only,
)
from elastocap.cameras.distortion import distort, fold_radius, padded, undistort

__all__ = ["Camera"]

class Camera:
    """A pinhole camera with OpenCV lens distortion and a full intrinsic matrix (with skew).

    Parameters
    ----------
    name : str
        The camera's name (unique within a :class:`Rig`).
    K : (3, 3) array_like of float
        Intrinsics ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels; the skew ``s`` may
        be non-zero. ``fx`` and ``fy`` must be positive. A last row within 1e-6 of
        ``[0, 0, 1]`` and ``K[1, 0]`` within 1e-6 fy of 0 (printed precision) are set
        exactly.
    dist : (n,) array_like of float or None
        OpenCV distortion coefficients in OpenCV's order, ``k1 k2 p1 p2 [k3 [k4 k5 k6 [s1
        s2 s3 s4 [tauX tauY]]]]`` (n = 4, 5, 8, 12 or 14; fewer than 4 are padded): radial
        k1 k2 k3, rational k4 k5 k6 (denominator), tangential p1 p2, thin prism s1-s4 (see
        :mod:`elastocap.cameras.distortion`). ``None`` means no distortion. ``(1, n)`` and
        ``(n, 1)`` are accepted. Stored as the shortest of 5, 8 or 12 coefficients that
        holds every non-zero one (a 4- or 5-coefficient camera keeps ``(5,)``). Tilted
        sensors (non-zero tauX, tauY) are refused.
    R : (3, 3) array_like of float
        World -> camera rotation. Printed calibrations carry 6-8 digits, so a matrix whose
        ``max |R^T R - I|`` is at most ``ROTATION_TOLERANCE`` (1e-3) is accepted and
        replaced by the nearest rotation (polar decomposition), with a
        :class:`CalibrationWarning` naming the camera and the size of the change when that
        error exceeds 1e-12 (below it R is kept bit for bit). A reflection (det < 0) or a
        matrix farther from any rotation is refused.
    t : (3,) array_like of float
        World -> camera translation (world units): ``x_cam = R X + t``. ``(3, 1)`` is
        accepted.
    width, height : int
        Image size in pixels, positive.

    Raises
    ------
    InvalidInputError
        On a wrong shape, a non-finite entry, an ``R`` far from any rotation or a
        reflection, a ``K`` whose last row is not ``[0, 0, 1]`` or whose focal lengths are
        not positive, or a non-positive or non-integer image size; the message names the
        argument and the camera.

    Notes
    -----
    Read-only: the arrays are not writeable and attributes cannot be reassigned; use
    :meth:`replace` for a modified copy. Derived values (``center``,
    ``projection_matrix``) are computed once and cached. Two cameras are equal when every
    field is exactly equal.
    """

    name: str
    K: NDArray[np.float64]
    dist: NDArray[np.float64]
    R: NDArray[np.float64]
    t: NDArray[np.float64]
    width: int
    height: int

    def __init__(
        self, name: str, K: Any, dist: Any, R: Any, t: Any, width: Any, height: Any
    ) -> None:
        if not isinstance(name, str) or not name:
            raise InvalidInputError(f"name must be a non-empty string, got {name!r}")
        K_ = as_intrinsics(name, K)
        dist_ = as_distortion(dist)
        R_ = as_rotation(name, R)
        t_ = as_float_array("t", t)
        if t_.size != 3 or t_.ndim > 2:
            raise InvalidInputError(f"t must have shape (3,) or (3, 1), got {t_.shape}")
        t_ = t_.reshape(3)
        if not np.isfinite(t_).all():
            raise InvalidInputError(f"t must be finite, got {t_.tolist()}")
        set_ = object.__setattr__
        set_(self, "name", name)
        set_(self, "K", read_only(K_))
        set_(self, "dist", read_only(dist_))
        set_(self, "R", read_only(R_))
        set_(self, "t", read_only(t_))
        set_(self, "width", as_image_size("width", width))
        set_(self, "height", as_image_size("height", height))

    # -- immutability, equality, printing -------------------------------------------------

    def __setattr__(self, key: str, value: Any) -> None:
        raise AttributeError(f"Camera is read-only; use camera.replace({key}=...)")

    def __delattr__(self, key: str) -> None:
        raise AttributeError("Camera is read-only")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        return (
            self.name == other.name
            and self.width == other.width
            and self.height == other.height
            and all(
                np.array_equal(a, b)
                for a, b in (
                    (self.K, other.K),
                    (self.dist, other.dist),
                    (self.R, other.R),
                    (self.t, other.t),
                )
            )
        )

    def __hash__(self) -> int:
        return hash(
            (self.name, self.width, self.height, self.K.tobytes(), self.dist.tobytes(),
             self.R.tobytes(), self.t.tobytes())
        )

    def __reduce__(self) -> tuple[type[Camera], tuple[Any, ...]]:
        # Rebuild through __init__, so that a copy or an unpickled camera is validated and
        # read-only too.
        return (Camera, (self.name, self.K, self.dist, self.R, self.t, self.width, self.height))

    def __repr__(self) -> str:
        fx, s, cx = self.K[0]
        return (
            f"Camera({self.name!r}, {self.width}x{self.height}, fx={fx:.6g}, fy={self.K[1, 1]:.6g}, "
            f"cx={cx:.6g}, cy={self.K[1, 2]:.6g}, skew={s:.3g}, dist={self.dist.tolist()}, "
            f"center={self.center.tolist()})"
        )

    def replace(self, **changes: Any) -> Camera:
        """A copy with some fields changed (``name``, ``K``, ``dist``, ``R``, ``t``,
        ``width``, ``height``), validated like the constructor."""
        fields: dict[str, Any] = {
            "name": self.name, "K": self.K, "dist": self.dist, "R": self.R, "t": self.t,
            "width": self.width, "height": self.height,
        }
        unknown = set(changes) - set(fields)
        if unknown:
            raise TypeError(f"Camera.replace: unknown field(s) {sorted(unknown)}")
        fields.update(changes)
        return Camera(**fields)

    # -- derived values -------------------------------------------------------------------

    @cached_property
    def center(self) -> NDArray[np.float64]:
        """(3,) float64: the camera centre in world coordinates, ``-R^T t``."""
        return read_only(-self.R.T @ self.t)

    @cached_property
    def projection_matrix(self) -> NDArray[np.float64]:
        """(3, 4) float64: ``K [R | t]``, mapping homogeneous world points to homogeneous
        pixels of the undistorted image (distortion is not included)."""
        return read_only(self.K @ np.hstack([self.R, self.t[:, None]]))

    @cached_property
    def _K_inverse(self) -> NDArray[np.float64]:
        fx, s, cx = self.K[0]
        fy, cy = self.K[1, 1], self.K[1, 2]
        return read_only(
            np.array(
                [[1 / fx, -s / (fx * fy), (s * cy - cx * fy) / (fx * fy)],
                 [0.0, 1 / fy, -cy / fy],
                 [0.0, 0.0, 1.0]]
            )
        )

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels, the order OpenCV uses."""
        return (self.width, self.height)

    @cached_property
    def fold_radius(self) -> float:
        """The radius, in normalised image coordinates ``sqrt(a^2 + b^2)``, beyond which the
        radial distortion folds back (``r (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 +
        k5 r^4 + k6 r^6)`` decreases, or its denominator vanishes); ``inf`` when it never
        does.

        Beyond it the lens model is outside its calibrated range: points there project to
        spurious pixels, often inside the image. :meth:`visible` excludes them and
        :meth:`rays` only returns rays inside this radius.
        """
        return fold_radius(self.dist)

    @cached_property
    def full_dist(self) -> NDArray[np.float64]:
        """(12,) float64: :attr:`dist` padded with zeros to all of OpenCV's ``k1 k2 p1 p2
        k3 k4 k5 k6 s1 s2 s3 s4`` (what the Rust kernels take)."""
        return read_only(padded(self.dist))

    @property
    def has_distortion(self) -> bool:
        """Whether any distortion coefficient is non-zero."""
        return bool(np.any(self.dist != 0))

    # -- projection -----------------------------------------------------------------------

    def to_camera(self, points: Any) -> NDArray[np.float64]:
        """World points in camera coordinates.

        Parameters
        ----------
        points : (N, 3) array_like of float
            World coordinates.

        Returns
        -------
        (N, 3) float64
            ``R X + t``, camera coordinates (world units; z along the optical axis).
        """
        X = as_points3("points", points)
        return X @ self.R.T + self.t

    def project(self, points: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Project world points to pixels, with distortion and skew.

        Parameters
        ----------
        points : (N, 3) array_like of float
            World coordinates.

        Returns
        -------
        uv : (N, 2) float64
            Pixel coordinates ``(u, v)`` = (column, row), origin at the centre of the
            top-left pixel. Computed for every point, including those behind the camera
            (``depth < 0``: a meaningless mirror image) and those in the camera's plane
            (``depth == 0``: ``inf`` or NaN); check ``depth > 0`` or use :meth:`visible`.
        depth : (N,) float64
            ``z`` in camera coordinates (world units). Points are visible only where
            ``depth > 0``.

        Notes
        -----
        SPEC section 1: ``x = R X + t``; ``(a, b) = (x/z, y/z)``; with ``r^2 = a^2 + b^2``,
        ``q = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)``,
        ``a' = a q + 2 p1 a b + p2 (r^2 + 2 a^2) + s1 r^2 + s2 r^4`` and
        ``b' = b q + p1 (r^2 + 2 b^2) + 2 p2 a b + s3 r^2 + s4 r^4``;
        ``[u, v, 1] = K [a', b', 1]``, so ``u = fx a' + s b' + cx``, ``v = fy b' + cy``.
        This equals ``cv2.projectPoints`` with the same coefficients when the skew ``s`` is
        0 (OpenCV ignores ``K[0, 1]``).
        """
        x = self.to_camera(points)
        depth = x[:, 2].copy()
        with np.errstate(divide="ignore", invalid="ignore"):
            ab = x[:, :2] / depth[:, None]
        uv = self._distorted_to_pixels(distort(ab, self.dist))
        return uv, depth

    def visible(self, points: Any) -> NDArray[np.bool_]:
        """Which world points project into the image, in front of the camera.

        Parameters
        ----------
        points : (N, 3) array_like of float
            World coordinates.

        Returns
        -------
        (N,) bool
            ``depth > 0``, ``-0.5 <= u < width - 0.5`` and ``-0.5 <= v < height - 0.5``
            (the pixel footprints; pixel centres are at integer ``(u, v)``), and within
            :attr:`fold_radius` of the optical axis (beyond it, distortion maps points to
            spurious pixels).
        """
        x = self.to_camera(points)
        depth = x[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            ab = x[:, :2] / depth[:, None]
            uv = self._distorted_to_pixels(distort(ab, self.dist))
            return np.asarray(
                (depth > 0)
                & (np.hypot(ab[:, 0], ab[:, 1]) < self.fold_radius)
                & (uv[:, 0] >= -0.5) & (uv[:, 0] < self.width - 0.5)
                & (uv[:, 1] >= -0.5) & (uv[:, 1] < self.height - 0.5)
            )

    def rays(self, uv: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Back-project pixels to rays in world coordinates.

        Parameters
        ----------
        uv : (N, 2) array_like of float
            Pixel coordinates ``(u, v)`` = (column, row), origin at the centre of the
            top-left pixel.

        Returns
        -------
        origins : (N, 3) float64
            The camera centre ``-R^T t`` (world), repeated.
        directions : (N, 3) float64
            Unit vectors (world) such that ``origins + s * directions`` with ``s > 0``
            projects to ``uv``. NaN for pixels that no ray within :attr:`fold_radius`
            reaches (possible only for strongly distorting lenses, near the image corners).

        Notes
        -----
        SPEC section 1: ``[a', b', 1] = K^-1 [u, v, 1]`` (with skew:
        ``b' = (v - cy) / fy``, ``a' = (u - cx - s b') / fx``); ``(a, b)`` solves
        ``distort(a, b) = (a', b')``; direction ``R^T [a, b, 1]``, normalised.

        The distortion is inverted by Newton's method with the analytic 2x2 Jacobian,
        started at ``(a', b')``, to rounding level. ``cv2.undistortPoints`` uses a
        fixed-point iteration instead, which converges only linearly and stops after 5
        iterations by default (short of rounding level under moderate to strong
        distortion); both converge to the same point. Newton steps are shortened to stay
        within :attr:`fold_radius`, so that the physical preimage is found and not a
        second one on the folded-back branch of the lens model.
        """
        pixels = as_points2("uv", uv)
        distorted = pixels @ self._K_inverse[:2, :2].T + self._K_inverse[:2, 2]
        ab = undistort(distorted, self.dist, self.fold_radius)
        directions = np.hstack([ab, np.ones((len(ab), 1))]) @ self.R
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        origins = np.broadcast_to(self.center, directions.shape).copy()
        return origins, directions

    def _distorted_to_pixels(self, ab: NDArray[np.float64]) -> NDArray[np.float64]:
        K = self.K
        out = np.empty(ab.shape, np.result_type(ab.dtype, K.dtype))
        out[:, 0] = K[0, 0] * ab[:, 0] + K[0, 1] * ab[:, 1] + K[0, 2]
        out[:, 1] = K[1, 1] * ab[:, 1] + K[1, 2]
        return out
