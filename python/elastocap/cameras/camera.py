"""Pinhole cameras with OpenCV distortion and skew, and rigs of named cameras.

A :class:`Camera` maps world points to pixels (``project``) and pixels to rays (``rays``);
a :class:`Rig` holds the cameras of a capture in order and reads and writes the calibration
files real data sets use: EasyMocap / ZJU-MoCap ``intri.yml`` + ``extri.yml`` (OpenCV
FileStorage YAML), elastocap's ``rig.json``, and Middlebury multi-view ``*_par.txt``.

Conventions (DESIGN.md): world -> camera is ``x_cam = R X + t``; pixel coordinates are
``(u, v)`` = (column, row) with the origin at the centre of the top-left pixel, the OpenCV
convention, so the image covers ``-0.5 <= u < width - 0.5`` and ``-0.5 <= v < height - 0.5``.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from functools import cached_property
from pathlib import Path
from typing import Any

import warnings

import numpy as np
from numpy.typing import NDArray

from elastocap.cameras import formats as _calibration_files
from elastocap._core import InvalidInputError
from elastocap._validate import as_float_array
from elastocap.geometry.polar import polar_rotation

__all__ = ["CalibrationWarning", "Camera", "Rig"]

# A rotation is kept exactly as given when R^T R = I holds to this, entry-wise (a Rodrigues
# vector or a matrix printed with 15 or more digits), so that files round-trip bit for bit.
ROTATION_EXACT_ATOL = 1e-12
# Calibration files print rotations with 6 to 17 significant digits, so a printed rotation is
# orthonormal only to about 1e-6. Up to this error R is projected onto the nearest rotation
# (polar decomposition) with a CalibrationWarning naming the camera and the size of the
# change; beyond it (a scaled or sheared matrix, a typo) R is refused.
ROTATION_TOLERANCE = 1e-3
# K's last row must be [0, 0, 1] and K[1, 0] zero to this (relative to fy); within it they
# are set exactly (a printed 1.0000001 or -1e-17), beyond it K is refused.
INTRINSICS_TOLERANCE = 1e-6

# Newton's method on the distortion map stops when the step is below this (normalised image
# coordinates, i.e. about 1e-15 focal lengths: rounding level) ...
UNDISTORT_STEP_TOL = 1e-15
# ... or after this many iterations; a point whose distortion residual is then still above
# UNDISTORT_RESIDUAL_TOL lies where the distortion map folds over and has no unique ray.
UNDISTORT_MAX_ITERATIONS = 50
UNDISTORT_RESIDUAL_TOL = 1e-10


# ------------------------------------------------------------------------------------------
# Camera
# ------------------------------------------------------------------------------------------


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
    dist : (<= 5,) array_like of float or None
        OpenCV distortion ``k1 k2 p1 p2 k3`` (radial k1 k2 k3, tangential p1 p2); shorter
        input is padded with zeros, ``None`` means no distortion. Any shape with at most 5
        entries (``(1, 5)``, ``(5, 1)``, ...) is accepted.
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
        K_ = _intrinsics(name, K)
        dist_ = _distortion(dist)
        R_ = _rotation(name, R)
        t_ = as_float_array("t", t)
        if t_.size != 3 or t_.ndim > 2:
            raise InvalidInputError(f"t must have shape (3,) or (3, 1), got {t_.shape}")
        t_ = t_.reshape(3)
        if not np.isfinite(t_).all():
            raise InvalidInputError(f"t must be finite, got {t_.tolist()}")
        set_ = object.__setattr__
        set_(self, "name", name)
        set_(self, "K", _read_only(K_))
        set_(self, "dist", _read_only(dist_))
        set_(self, "R", _read_only(R_))
        set_(self, "t", _read_only(t_))
        set_(self, "width", _image_size("width", width))
        set_(self, "height", _image_size("height", height))

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
        return _read_only(-self.R.T @ self.t)

    @cached_property
    def projection_matrix(self) -> NDArray[np.float64]:
        """(3, 4) float64: ``K [R | t]``, mapping homogeneous world points to homogeneous
        pixels of the undistorted image (distortion is not included)."""
        return _read_only(self.K @ np.hstack([self.R, self.t[:, None]]))

    @cached_property
    def _K_inverse(self) -> NDArray[np.float64]:
        fx, s, cx = self.K[0]
        fy, cy = self.K[1, 1], self.K[1, 2]
        return _read_only(
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
        radial distortion folds back (``r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` decreases);
        ``inf`` when it never does.

        Beyond it the lens model is outside its calibrated range: points there project to
        spurious pixels, often inside the image. :meth:`visible` excludes them and
        :meth:`rays` only returns rays inside this radius.
        """
        return _fold_radius(self.dist)

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
        X = _points3("points", points)
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
        ``a' = a (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 a b + p2 (r^2 + 2 a^2)`` and
        ``b' = b (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 b^2) + 2 p2 a b``;
        ``[u, v, 1] = K [a', b', 1]``, so ``u = fx a' + s b' + cx``, ``v = fy b' + cy``.
        This equals ``cv2.projectPoints`` when the skew ``s`` is 0 (OpenCV ignores
        ``K[0, 1]``).
        """
        x = self.to_camera(points)
        depth = x[:, 2].copy()
        with np.errstate(divide="ignore", invalid="ignore"):
            ab = x[:, :2] / depth[:, None]
        uv = self._distorted_to_pixels(_distort(ab, self.dist))
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
            uv = self._distorted_to_pixels(_distort(ab, self.dist))
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
        pixels = _points2("uv", uv)
        distorted = pixels @ self._K_inverse[:2, :2].T + self._K_inverse[:2, 2]
        ab = _undistort(distorted, self.dist, self.fold_radius)
        directions = np.hstack([ab, np.ones((len(ab), 1))]) @ self.R
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        origins = np.broadcast_to(self.center, directions.shape).copy()
        return origins, directions

    def _distorted_to_pixels(self, ab: NDArray[np.float64]) -> NDArray[np.float64]:
        K = self.K
        u = K[0, 0] * ab[:, 0] + K[0, 1] * ab[:, 1] + K[0, 2]
        v = K[1, 1] * ab[:, 1] + K[1, 2]
        return np.stack([u, v], axis=1)


def _distort(ab: NDArray[np.float64], dist: NDArray[np.float64]) -> NDArray[np.float64]:
    """OpenCV's distortion of normalised image coordinates ``(N, 2)``."""
    k1, k2, p1, p2, k3 = dist
    a, b = ab[:, 0], ab[:, 1]
    with np.errstate(invalid="ignore", over="ignore"):
        r2 = a * a + b * b
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        a2 = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
        b2 = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
    return np.stack([a2, b2], axis=1)


def _fold_radius(dist: NDArray[np.float64]) -> float:
    """The smallest normalised radius where the radial distortion ``r (1 + k1 r^2 + k2 r^4 +
    k3 r^6)`` stops increasing, or inf when it never does."""
    k1, k2, _, _, k3 = dist
    # d/dr [r (1 + k1 s + k2 s^2 + k3 s^3)] = 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3, s = r^2.
    coefficients = np.trim_zeros(np.array([7 * k3, 5 * k2, 3 * k1, 1.0]), "f")
    roots = np.roots(coefficients) if len(coefficients) > 1 else np.array([])
    real = roots[np.abs(roots.imag) <= 1e-12 * np.maximum(1.0, np.abs(roots))].real
    positive = real[real > 0]
    return float(np.sqrt(positive.min())) if positive.size else float("inf")


def _undistort(
    target: NDArray[np.float64], dist: NDArray[np.float64], fold: float
) -> NDArray[np.float64]:
    """Solve ``_distort(ab) = target`` for ``ab`` ``(N, 2)`` inside the fold radius, by
    Newton's method with steps shortened to stay inside; NaN rows where there is no such
    solution (or the iteration does not find it)."""
    if not np.any(dist != 0):
        return target.copy()
    k1, k2, p1, p2, k3 = dist
    limit = 0.999 * fold
    ab = target.copy()
    radius = np.hypot(ab[:, 0], ab[:, 1])
    outside = radius >= limit
    ab[outside] *= (0.5 * limit / radius[outside])[:, None]
    active: NDArray[np.bool_] = np.asarray(np.isfinite(ab).all(axis=1))
    for _ in range(UNDISTORT_MAX_ITERATIONS):
        index = np.flatnonzero(active)
        if index.size == 0:
            break
        a, b = ab[index, 0], ab[index, 1]
        r2 = a * a + b * b
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d radial / d r2
        fa = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a) - target[index, 0]
        fb = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b - target[index, 1]
        # Jacobian of the distortion map (symmetric), with d r2/da = 2a, d r2/db = 2b.
        jaa = radial + 2 * a * a * dradial + 2 * p1 * b + 6 * p2 * a
        jab = 2 * a * b * dradial + 2 * p1 * a + 2 * p2 * b
        jbb = radial + 2 * b * b * dradial + 6 * p1 * b + 2 * p2 * a
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            det = jaa * jbb - jab * jab
            da = (jbb * fa - jab * fb) / det
            db = (jaa * fb - jab * fa) / det
        # Halve steps that would leave the fold radius, where a second, unphysical
        # preimage may lie.
        scale = np.ones_like(da)
        for _ in range(60):
            beyond = np.hypot(a - scale * da, b - scale * db) >= limit
            if not beyond.any():
                break
            scale[beyond] *= 0.5
        ab[index, 0] = a - scale * da
        ab[index, 1] = b - scale * db
        step = scale * np.maximum(np.abs(da), np.abs(db))
        with np.errstate(invalid="ignore"):
            done = step <= UNDISTORT_STEP_TOL * np.maximum(1.0, np.abs(ab[index]).max(axis=1))
        active[index[done | ~np.isfinite(step)]] = False
    residual = np.abs(_distort(ab, dist) - target).max(axis=1)
    with np.errstate(invalid="ignore"):
        failed = ~(residual <= UNDISTORT_RESIDUAL_TOL * np.maximum(1.0, np.abs(target).max(axis=1)))
    ab[failed] = np.nan
    return ab


# ------------------------------------------------------------------------------------------
# Rig
# ------------------------------------------------------------------------------------------


class Rig(Mapping[str, Camera]):
    """The cameras of a capture, by name, in a fixed order.

    Parameters
    ----------
    cameras : iterable of Camera
        In rig order; names must be unique.

    Notes
    -----
    A read-only mapping: ``rig["cam0"]``, ``len(rig)``, ``for name in rig`` (in order),
    ``rig.names``, ``rig.cameras``. Load and save with :meth:`load` and :meth:`save`.
    """

    def __init__(self, cameras: Iterable[Camera]) -> None:
        ordered: dict[str, Camera] = {}
        for camera in cameras:
            if not isinstance(camera, Camera):
                raise InvalidInputError(f"cameras must hold Camera objects, got {type(camera).__name__}")
            if camera.name in ordered:
                raise InvalidInputError(f"cameras: the name {camera.name!r} appears twice")
            ordered[camera.name] = camera
        if not ordered:
            raise InvalidInputError("cameras is empty: a rig needs at least one camera")
        self._cameras = ordered

    def __getitem__(self, name: str) -> Camera:
        try:
            return self._cameras[name]
        except KeyError:
            raise KeyError(f"no camera named {name!r} in the rig (cameras: {self.names})") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._cameras)

    def __len__(self) -> int:
        return len(self._cameras)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Rig):
            return NotImplemented
        return list(self._cameras.items()) == list(other._cameras.items())

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"Rig({len(self)} cameras: {', '.join(self.names)})"

    @property
    def names(self) -> list[str]:
        """The camera names, in rig order."""
        return list(self._cameras)

    @property
    def cameras(self) -> list[Camera]:
        """The cameras, in rig order."""
        return list(self._cameras.values())

    # -- loading --------------------------------------------------------------------------

    @classmethod
    def load(cls, path: str | Path, *, size: tuple[int, int] | None = None) -> Rig:
        """Read a rig from a capture folder or a calibration file.

        Parameters
        ----------
        path : str or Path
            One of

            - a capture folder with ``intri.yml`` + ``extri.yml`` (preferred when present)
              or ``rig.json``, or a single ``*_par.txt``;
            - ``intri.yml`` or ``extri.yml`` itself (the pair is read from its folder);
            - a ``.json`` file in the ``rig.json`` format;
            - a Middlebury ``*_par.txt`` file.
        size : (width, height), optional, keyword-only
            Image size for cameras whose file does not give it. Where a size is also found
            in the files or images, the two must agree.

        Returns
        -------
        Rig

        Raises
        ------
        FileNotFoundError
            The path or a calibration file does not exist, or a folder holds no
            calibration.
        InvalidInputError
            A malformed file, a camera listed in ``names`` without its matrices, a
            non-finite or invalid calibration, or no way to tell an image size; the
            message names the file and the camera.

        Notes
        -----
        ``intri.yml``: ``names`` (sequence of strings), ``K_<name>`` (3x3),
        ``dist_<name>`` (1x5 or shorter; missing means none), optional ``H_<name>``,
        ``W_<name>`` (image height and width). ``extri.yml``: ``Rot_<name>`` (3x3,
        preferred) or ``R_<name>`` (3x1 Rodrigues), ``T_<name>`` (3x1); when both
        rotations are present they must agree to the precision the file prints them with
        (a few units in the last digit of each) and the matrix wins. Rotations printed with
        few digits are projected onto the nearest rotation with a
        :class:`CalibrationWarning` (see :class:`Camera`). Without ``H_``/``W_``, the size
        comes from the camera's first image, mask, background or video in the folder
        (see :class:`elastocap.Capture`), else from ``size``; with them, images are not
        opened (:class:`elastocap.Capture` checks each image's size when reading it).

        Middlebury ``*_par.txt``: a count, then one line per image ``name.png k11 .. k33
        r11 .. r33 t1 t2 t3`` (P = K [R | t]); camera names are the image names' stems;
        the size is read from the image beside the file if it exists.
        """
        records = _calibration_files.read(Path(path), size)
        return cls(_camera(record) for record in records)

    # -- saving ---------------------------------------------------------------------------

    def save(self, path: str | Path) -> None:
        """Write the rig.

        Parameters
        ----------
        path : str or Path
            A path ending in ``.json``: the ``rig.json`` format. Anything else is a folder
            (created if needed) that receives ``intri.yml`` and ``extri.yml`` in the
            EasyMocap layout, with both ``R_<name>`` (Rodrigues) and ``Rot_<name>`` (3x3)
            and the image size as ``H_<name>`` / ``W_<name>``; existing files are
            overwritten.

        Notes
        -----
        Both formats store doubles exactly (OpenCV prints 17 significant digits, JSON the
        shortest exact form), so :meth:`load` gives back exactly the same cameras.
        """
        path = Path(path)
        if path.suffix.lower() == ".json":
            _calibration_files.write_json(path, self.cameras)
        else:
            _calibration_files.write_yaml(path, self.cameras)

# ------------------------------------------------------------------------------------------
# helpers: validation
# ------------------------------------------------------------------------------------------


class CalibrationWarning(UserWarning):
    """A calibration was accepted after a correction (a printed rotation projected onto the
    nearest rotation, printed intrinsics rounded to their exact form) or looks implausible.
    The message names the camera and the size of the correction."""


def _rotation(camera: str, value: Any) -> NDArray[np.float64]:
    """``value`` as a rotation matrix: kept when orthonormal to rounding, projected onto the
    nearest rotation (with a warning) when within ROTATION_TOLERANCE, refused otherwise."""
    R = _matrix("R", value, (3, 3))
    orthonormality = float(np.abs(R.T @ R - np.eye(3)).max())
    determinant = float(np.linalg.det(R))
    if determinant <= 0.0:
        raise InvalidInputError(
            f"camera {camera!r}: R must be a rotation, got a reflection or a singular matrix "
            f"(det R = {determinant:.9g})"
        )
    if orthonormality > ROTATION_TOLERANCE:
        raise InvalidInputError(
            f"camera {camera!r}: R must be a rotation: max |R^T R - I| = {orthonormality:.3g} "
            f"exceeds the {ROTATION_TOLERANCE:g} that printed precision explains "
            f"(det R = {determinant:.9g}); is it scaled or a different matrix?"
        )
    if orthonormality <= ROTATION_EXACT_ATOL:
        return R
    nearest = polar_rotation(R[None])[0]
    warnings.warn(
        f"camera {camera!r}: R is orthonormal only to {orthonormality:.3g} (printed "
        f"precision); replaced by the nearest rotation, entries changed by at most "
        f"{np.abs(nearest - R).max():.3g}",
        CalibrationWarning,
        stacklevel=3,
    )
    return np.ascontiguousarray(nearest)


def _intrinsics(camera: str, value: Any) -> NDArray[np.float64]:
    """``value`` as an intrinsic matrix: last row [0, 0, 1] and K[1, 0] = 0 to printed
    precision (set exactly), positive focal lengths."""
    K = _matrix("K", value, (3, 3))
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InvalidInputError(
            f"camera {camera!r}: K must have positive focal lengths, got fx = {K[0, 0]}, "
            f"fy = {K[1, 1]}"
        )
    if np.abs(K[2] - [0.0, 0.0, 1.0]).max() > INTRINSICS_TOLERANCE:
        raise InvalidInputError(f"camera {camera!r}: K must have last row [0, 0, 1], got {K[2].tolist()}")
    if abs(K[1, 0]) > INTRINSICS_TOLERANCE * K[1, 1]:
        raise InvalidInputError(f"camera {camera!r}: K[1, 0] must be 0, got {K[1, 0]}")
    K = K.copy()
    K[2] = [0.0, 0.0, 1.0]
    K[1, 0] = 0.0
    return K


def _read_only(array: NDArray[np.float64]) -> NDArray[np.float64]:
    array = np.array(array, dtype=np.float64, order="C")
    array.flags.writeable = False
    return array


def _matrix(name: str, value: Any, shape: tuple[int, int]) -> NDArray[np.float64]:
    matrix = as_float_array(name, value)
    if matrix.shape != shape:
        raise InvalidInputError(f"{name} must have shape {shape}, got {matrix.shape}")
    if not np.isfinite(matrix).all():
        raise InvalidInputError(f"{name} must be finite, got {matrix.tolist()}")
    return matrix


def _distortion(value: Any) -> NDArray[np.float64]:
    if value is None:
        return np.zeros(5)
    dist = as_float_array("dist", value)
    if dist.size > 5 or (dist.ndim == 2 and 1 not in dist.shape) or dist.ndim > 2:
        raise InvalidInputError(
            f"dist must hold at most 5 coefficients (k1 k2 p1 p2 k3) as (5,), (1, 5) or (5, 1), "
            f"got shape {dist.shape}"
        )
    dist = dist.ravel()
    if not np.isfinite(dist).all():
        raise InvalidInputError(f"dist must be finite, got {dist.tolist()}")
    return np.concatenate([dist, np.zeros(5 - dist.size)])


def _image_size(name: str, value: Any) -> int:
    if isinstance(value, (float, np.floating)) and float(value).is_integer():
        value = int(value)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value <= 0:
        raise InvalidInputError(f"{name} must be a positive integer (pixels), got {value!r}")
    return int(value)


def _points3(name: str, value: Any) -> NDArray[np.float64]:
    points = as_float_array(name, value)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InvalidInputError(f"{name} must have shape (N, 3), got {points.shape}")
    return points


def _points2(name: str, value: Any) -> NDArray[np.float64]:
    points = as_float_array(name, value)
    if points.ndim != 2 or points.shape[1] != 2:
        raise InvalidInputError(f"{name} must have shape (N, 2), got {points.shape}")
    return points


def _camera(record: _calibration_files.CameraRecord) -> Camera:
    """A Camera from a file's record, with construction errors prefixed by the file and
    camera they come from."""
    try:
        return Camera(record.name, record.K, record.dist, record.R, record.t, record.width, record.height)
    except InvalidInputError as error:
        raise InvalidInputError(f"{record.where}: camera {record.name!r}: {error}") from None
