"""Single-camera calibration from views of a board, and the checks that say what the views
determine.

Zhang's method (OpenCV's ``calibrateCameraExtended``) recovers the focal length only from
perspective (the convergence of a board's lines, strong for boards tilted and near), and the
principal point only from boards in several orientations. Views that lack these leave a family
of calibrations that fit equally well, and OpenCV then returns one of them, sometimes with
standard deviations that look fine (on the shared chessboard pairs: 29 px for a 320 px wide
camera). :func:`calibrate_camera` therefore measures the perspective in each view and the
spread of the board orientations, holds fixed what they cannot determine, checks the standard
deviations of what it did estimate, and says what it held fixed with an
:class:`UnderdeterminedCalibrationWarning`.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.cameras import Camera
from elastocap.stereo.board import Board
from elastocap.stereo.calibration_detect import BoardView

__all__ = ["CameraCalibration", "UnderdeterminedCalibrationWarning", "calibrate_camera"]

# Horizontal field of view assumed for the focal length when the views cannot determine it
# and none is given (degrees): a common webcam / machine-vision lens.
NOMINAL_FIELD_OF_VIEW = 60.0
# The focal length comes from perspective: how far a board's image departs from the best
# affine image of it (the convergence of its lines). A board far away or facing the camera
# looks affine, and then focal length and distance trade off exactly (weak perspective). The
# largest departure over the views must be this many times the reprojection error of the full
# model (noise plus whatever the model does not explain), so that an error of that size moves
# the focal length by a few percent at most; the error is floored at MIN_CORNER_SCATTER px.
MIN_PERSPECTIVE_RATIO = 20.0
MIN_CORNER_SCATTER = 0.05
# The principal point needs boards in at least two clearly different orientations (degrees).
MIN_SPREAD = 10.0
# Estimated parameters must be known to these standard deviations (calibrateCameraExtended's,
# from the Jacobian and the residual): focal lengths relative to their value, principal point
# relative to the image width, and each distortion coefficient as the pixel shift it makes at
# the farthest corner seen.
MAX_FOCAL_RELATIVE_STD = 0.01
MAX_PRINCIPAL_POINT_STD = 0.02
MAX_DISTORTION_SHIFT_STD = 0.5
DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3")
# The order in which distortion terms are dropped when undetermined: highest order first.
DISTORTION_DROP_ORDER = ("k3", "k2", "p1", "p2", "k1")
_DISTORTION_FLAGS = {
    "k1": cv2.CALIB_FIX_K1, "k2": cv2.CALIB_FIX_K2, "k3": cv2.CALIB_FIX_K3,
    "p1": cv2.CALIB_ZERO_TANGENT_DIST, "p2": cv2.CALIB_ZERO_TANGENT_DIST,
}
_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)


class UnderdeterminedCalibrationWarning(UserWarning):
    """The views do not determine some of the parameters asked for; they were held fixed."""


@dataclass(frozen=True)
class CameraCalibration:
    """One camera calibrated from its views of a board.

    Attributes
    ----------
    camera : Camera
        Intrinsics and distortion; pose at the identity (the camera's own frame).
    rms : float
        Root mean square reprojection error over all corners, pixels
        (``sqrt(sum |residual|^2 / corners)``, OpenCV's definition).
    views : dict of str -> (R (3, 3), t (3,))
        Board -> camera pose per view used, ``x_cam = R X_board + t``.
    view_rms : dict of str -> float
        Reprojection RMS per view, pixels.
    std : dict of str -> float
        Standard deviation of each estimated parameter (``fx fy cx cy k1 k2 p1 p2 k3``;
        pixels or unitless), from ``calibrateCameraExtended``; fixed ones are absent.
    fixed : tuple of str
        Parameters held fixed (``"focal"``, ``"principal_point"``, ``"aspect"``, or
        distortion names).
    perspective : float
        The largest departure of a view's corners from an affine image of the board, pixels
        (see :func:`perspective_signal`).
    scatter : float
        The reprojection RMS of the full model (floored at :data:`MIN_CORNER_SCATTER`),
        pixels: the error that no parameter explains, which the perspective must exceed.
    spread : float
        Largest angle between two views' board normals, degrees (poses through ``K`` or the
        nominal camera).
    messages : tuple of str
        What the views did not determine, as warned.
    """

    camera: Camera
    rms: float
    views: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]
    view_rms: dict[str, float]
    std: dict[str, float]
    fixed: tuple[str, ...]
    perspective: float
    scatter: float
    spread: float
    messages: tuple[str, ...] = field(default=())

    @property
    def determined(self) -> bool:
        """Whether every parameter asked for was estimated (nothing had to be held fixed)."""
        return not self.messages


def _validate_views(views: Mapping[str, BoardView], board: Board, name: str) -> list[str]:
    keys = [key for key, view in views.items() if view is not None and len(view.ids) >= 4]
    if not keys:
        raise InvalidInputError(f"camera {name!r}: no view with at least 4 board corners")
    n = len(board.object_points)
    for key in keys:
        ids = views[key].ids
        if ids.min() < 0 or ids.max() >= n:
            raise InvalidInputError(f"camera {name!r}, view {key!r}: corner ids must lie in [0, {n}), got {ids.min()}..{ids.max()}")
    return keys


def nominal_K(size: tuple[int, int], focal: float | None = None) -> NDArray[np.float64]:
    """``K`` with the principal point at the image centre and ``focal`` (default: the
    :data:`NOMINAL_FIELD_OF_VIEW` guess) as both focal lengths."""
    width, height = size
    if focal is None:
        focal = (width / 2) / np.tan(np.radians(NOMINAL_FIELD_OF_VIEW / 2))
    return np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])


def perspective_signal(view: BoardView, board: Board) -> float:
    """The largest distance, in pixels, between a view's corners mapped by their homography
    and by their best affine map: how much perspective the view shows.

    Notes
    -----
    Independent of the camera model: an affine image (no perspective) is what a camera of
    any focal length gives of a distant board, so only the departure carries the focal
    length.
    """
    xy = board.object_points[view.ids][:, :2]
    H, _ = cv2.findHomography(xy, view.corners, 0)
    if H is None:
        return 0.0
    homogeneous = np.hstack([xy, np.ones((len(xy), 1))])
    mapped = homogeneous @ np.asarray(H, dtype=np.float64).T
    projected = mapped[:, :2] / mapped[:, 2:]
    affine, *_ = np.linalg.lstsq(homogeneous, view.corners, rcond=None)
    return float(np.linalg.norm(projected - homogeneous @ affine, axis=1).max())


def board_spread(views: Mapping[str, BoardView], board: Board, K: NDArray[np.float64], keys: list[str]) -> float:
    """The largest angle between two views' board normals, degrees, with poses from
    ``solvePnP`` through ``K`` (distortion ignored)."""
    normals = []
    for key in keys:
        view = views[key]
        ok, rvec, _ = cv2.solvePnP(board.object_points[view.ids], view.corners, K, None, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            ok, rvec, _ = cv2.solvePnP(board.object_points[view.ids], view.corners, K, None)
        normals.append(cv2.Rodrigues(rvec)[0][:, 2])
    n = np.array(normals)
    cosines = np.clip(np.abs(n @ n.T), 0, 1)
    return float(np.degrees(np.arccos(cosines.min())))


def calibrate_camera(
    views: Mapping[str, BoardView],
    board: Board,
    size: tuple[int, int],
    *,
    name: str = "camera",
    K: Any = None,
    focal_length: float | None = None,
    distortion: tuple[str, ...] = DISTORTION_NAMES,
    min_perspective_ratio: float = MIN_PERSPECTIVE_RATIO,
    min_spread: float = MIN_SPREAD,
) -> CameraCalibration:
    """Intrinsics and distortion of one camera from its views of a board.

    Parameters
    ----------
    views : mapping of str -> BoardView
        Detections per view (views with fewer than 4 corners are skipped).
    board : Chessboard or CharucoTarget
        Its ``object_points`` set the unit of length.
    size : (width, height)
        Image size, pixels.
    name : str, keyword-only
        The camera's name (in messages and in the returned camera).
    K : (3, 3) array_like, keyword-only
        Known or nominal intrinsics: the starting point, and the values held fixed where the
        views do not determine them.
    focal_length : float, keyword-only
        A focal length guess (pixels) to hold fixed if the views do not determine it and no
        ``K`` is given; default from a 60-degree horizontal field of view.
    distortion : tuple of str, keyword-only
        The distortion coefficients to estimate, a subset of ``("k1", "k2", "p1", "p2",
        "k3")``; the others stay 0.
    min_perspective_ratio, min_spread : float, keyword-only
        See :data:`MIN_PERSPECTIVE_RATIO` and :data:`MIN_SPREAD` (degrees).

    Returns
    -------
    CameraCalibration

    Warns
    -----
    UnderdeterminedCalibrationWarning
        When the views do not determine the focal length (no view shows enough perspective),
        the principal point (orientations within ``min_spread``) or a distortion coefficient
        (its standard deviation moves the image corners by more than half a pixel): those
        are held fixed, at ``K`` / the guess / 0, and the message says so.

    Raises
    ------
    InvalidInputError
        No usable view, bad ``size``, ``K`` or ``distortion``.

    Notes
    -----
    Zhang (2000) via ``cv2.calibrateCameraExtended`` (skew 0). The checks run on the first,
    full fit (each view's perspective, which needs no camera model, against the full model's residual;
    the spread of board orientations, seen through ``K`` or the nominal camera) and on every
    fit (standard deviations, which alone
    are not enough: on views without perspective OpenCV converges to a wrong focal length
    with a small standard deviation); a failed check drops to the next simpler model: full ->
    principal point fixed (one focal length) -> focal length fixed too.
    """
    keys = _validate_views(views, board, name)
    width, height = (int(size[0]), int(size[1]))
    if width <= 0 or height <= 0:
        raise InvalidInputError(f"size must be (width, height) in pixels, got {size!r}")
    unknown = set(distortion) - set(DISTORTION_NAMES)
    if unknown:
        raise InvalidInputError(f"distortion must name coefficients among {DISTORTION_NAMES}, got {sorted(unknown)}")
    if K is not None:
        K0 = np.asarray(K, dtype=np.float64)
        if K0.shape != (3, 3) or not np.isfinite(K0).all():
            raise InvalidInputError(f"K must be a finite (3, 3) matrix, got shape {K0.shape}")
        focal_source = "the given K"
    else:
        K0 = nominal_K((width, height), focal_length)
        focal_source = (
            "the given focal_length" if focal_length is not None
            else f"a guess: {NOMINAL_FIELD_OF_VIEW:g}-degree horizontal field of view; pass K or focal_length"
        )
    perspective = max(perspective_signal(views[k], board) for k in keys)
    spread = board_spread(views, board, K0, keys)
    messages: list[str] = []
    level = 0  # 0: full; 1: principal point and aspect fixed; 2: focal length fixed too
    free = [d for d in DISTORTION_NAMES if d in distortion]
    if ("p1" in free) != ("p2" in free):  # OpenCV fixes the tangential pair together
        raise InvalidInputError("distortion must name both p1 and p2 or neither")
    object_points = [board.object_points[views[k].ids].astype(np.float32) for k in keys]
    image_points = [views[k].corners.astype(np.float32).reshape(-1, 1, 2) for k in keys]
    radius = _farthest_corner_radius(image_points, K0)
    scatter = float("nan")
    while True:
        flags = cv2.CALIB_USE_INTRINSIC_GUESS
        if level >= 1:
            flags |= cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_ASPECT_RATIO
        if level >= 2:
            flags |= cv2.CALIB_FIX_FOCAL_LENGTH
        for d in DISTORTION_NAMES:
            if d not in free:
                flags |= _DISTORTION_FLAGS[d]
        K_start = K0.copy()
        K_start[0, 1] = 0.0
        if level >= 1:
            K_start[1, 1] = K_start[0, 0]
        rms, K_fit, dist, rvecs, tvecs, std_i, _, per_view = cv2.calibrateCameraExtended(
            object_points, image_points, (width, height), K_start, np.zeros(5), flags=flags, criteria=_CRITERIA
        )
        std_all = dict(zip(("fx", "fy", "cx", "cy", *DISTORTION_NAMES), std_i.ravel()[:9]))
        focal_rstd = max(std_all["fx"] / K_fit[0, 0], std_all["fy"] / K_fit[1, 1])
        pp_std = max(std_all["cx"], std_all["cy"]) / width
        if np.isnan(scatter):  # the first, full fit: what remains unexplained by any model
            scatter = max(float(rms), MIN_CORNER_SCATTER)
            if perspective < min_perspective_ratio * scatter:
                level = 2
                messages.append(
                    f"camera {name!r}: its {len(keys)} views show the board within {spread:.1f} degrees of one "
                    f"orientation and with at most {perspective:.2f} px of perspective (departure from an affine "
                    f"image), {perspective / scatter:.1f} times the {scatter:.2f} px reprojection error "
                    f"({min_perspective_ratio:g} needed): the views do not determine the focal length"
                )
                if K is None:
                    # The focal length is then a guess, and distortion fitted around a wrong
                    # focal length only absorbs the error.
                    if free:
                        messages.append(f"camera {name!r}: nor the distortion, with the focal length guessed")
                    free = []
                continue
            if spread < min_spread:
                level = 1
                messages.append(
                    f"camera {name!r}: its {len(keys)} views show the board within {spread:.1f} degrees of one "
                    f"orientation ({min_spread:g} needed): they do not determine the principal point"
                )
                continue
        if level == 0 and (pp_std > MAX_PRINCIPAL_POINT_STD or focal_rstd > MAX_FOCAL_RELATIVE_STD):
            level = 1
            messages.append(
                f"camera {name!r}: the principal point is known only to {pp_std * width:.1f} px and the focal lengths "
                f"to {100 * focal_rstd:.1f}% (standard deviations): the views do not determine them"
            )
            continue
        if level == 1 and focal_rstd > MAX_FOCAL_RELATIVE_STD:
            level = 2
            messages.append(
                f"camera {name!r}: the focal length is known only to {100 * focal_rstd:.1f}% (standard deviation): "
                f"the views do not determine it"
            )
            continue
        shift = {d: std_all[d] * _distortion_gain(d, radius) * K_fit[0, 0] for d in free}
        loose = [d for d in DISTORTION_DROP_ORDER if d in free and shift[d] > MAX_DISTORTION_SHIFT_STD]
        if loose:
            drop = loose[0]
            dropped = ("p1", "p2") if drop in ("p1", "p2") else (drop,)
            free = [d for d in free if d not in dropped]
            messages.append(
                f"camera {name!r}: distortion {'/'.join(dropped)} moves the farthest corner seen by "
                f"{shift[drop]:.2f} px per standard deviation ({MAX_DISTORTION_SHIFT_STD} allowed)"
            )
            continue
        break
    fixed: list[str] = []
    held: list[str] = []
    if level >= 2:
        fixed.append("focal")
        held.append(
            f"the focal length at {K_start[0, 0]:.1f} px ({focal_source}; distances along the optical axis "
            f"scale with it)"
        )
    if level >= 1:
        fixed += ["principal_point", "aspect"]
        where = "from the given K" if K is not None else "the image centre"
        held.append(f"the principal point at ({K_start[0, 2]:.1f}, {K_start[1, 2]:.1f}) px ({where}) and fx = fy")
    zeroed = [d for d in distortion if d not in free]
    fixed += [d for d in DISTORTION_NAMES if d not in free]
    if zeroed:
        held.append(f"distortion {' '.join(zeroed)} at 0")
    if messages:
        summary = "; ".join(messages) + ". Held " + ", ".join(held) + "."
        warnings.warn(summary, UnderdeterminedCalibrationWarning, stacklevel=2)
        messages = [summary]
    camera = Camera(name, K_fit, dist.ravel()[:5], np.eye(3), np.zeros(3), width, height)
    estimated = {"fx", "fy"} if level < 2 else set()
    if level == 0:
        estimated |= {"cx", "cy"}
    std = {k: float(v) for k, v in std_all.items() if k in estimated or k in free}
    poses = {
        k: (np.asarray(cv2.Rodrigues(r)[0], dtype=np.float64), np.asarray(t, dtype=np.float64).reshape(3))
        for k, r, t in zip(keys, rvecs, tvecs)
    }
    return CameraCalibration(
        camera=camera,
        rms=float(rms),
        views=poses,
        view_rms={k: float(e) for k, e in zip(keys, per_view.ravel())},
        std=std,
        fixed=tuple(fixed),
        perspective=perspective,
        scatter=scatter,
        spread=spread,
        messages=tuple(messages),
    )


def _farthest_corner_radius(image_points: list[NDArray[np.float32]], K: NDArray[np.float64]) -> float:
    """Largest normalised radius ``|K^-1 uv|`` of the corners seen (distortion's reach)."""
    uv = np.concatenate([p.reshape(-1, 2) for p in image_points]).astype(np.float64)
    ab = (uv - K[:2, 2]) / np.array([K[0, 0], K[1, 1]])
    return float(np.hypot(ab[:, 0], ab[:, 1]).max())


def _distortion_gain(name: str, r: float) -> float:
    """``d(shift)/d(coefficient)`` at normalised radius ``r`` (normalised units; times fx
    for pixels): ``r^3``, ``r^5``, ``r^7`` for k1 k2 k3, ``3 r^2`` for p1 p2 (at most)."""
    return {"k1": r**3, "k2": r**5, "k3": r**7, "p1": 3 * r**2, "p2": 3 * r**2}[name]
