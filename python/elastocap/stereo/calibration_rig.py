"""Calibration of a rig of cameras from shared views of a board: stereo and multi-camera.

Each camera is first calibrated alone (:func:`~elastocap.stereo.calibration.calibrate_camera`,
which holds fixed what its views do not determine); the cameras' relative poses are then
initialised from the views they share, and everything (intrinsics that were estimated, camera
poses, board poses) is refined together by minimising the reprojection error of every corner
in every camera (a bundle adjustment, scipy's sparse trust-region least squares).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import scipy.optimize
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.cameras import Camera, Rig
from elastocap.stereo.board import Board
from elastocap.stereo.calibration import DISTORTION_NAMES, CameraCalibration, calibrate_camera
from elastocap.stereo.calibration_detect import BoardView

__all__ = ["RigCalibration", "calibrate_rig", "calibrate_stereo"]

Pose = tuple[NDArray[np.float64], NDArray[np.float64]]

# The bundle adjustment stops when the cost changes by less than this, relative: corners are
# known to ~0.01-0.1 px, so 1e-12 is far past anything that moves a parameter visibly.
BUNDLE_TOLERANCE = 1e-12
# Central-difference step, relative to max(1, |parameter|): the truncation error (~step^2)
# and the rounding error (~1e-16 / step) of the derivative then both stay near 1e-10.
FD_STEP = 1e-6
_INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", *DISTORTION_NAMES)


@dataclass(frozen=True)
class RigCalibration:
    """A rig calibrated from views of a board.

    Attributes
    ----------
    rig : Rig
        The cameras, in the order given, world units = the board's.
    rms : dict of str -> float
        Reprojection RMS per camera after the joint refinement, pixels.
    cameras : dict of str -> CameraCalibration
        Each camera's own calibration (what its views determined; :attr:`CameraCalibration.fixed`).
    board_poses : dict of str -> (R (3, 3), t (3,))
        Board -> world pose of every view used.
    world : str
        ``"board:<view>"`` (the board of that view is the world frame) or a camera's name.
    messages : tuple of str
        Everything warned.
    """

    rig: Rig
    rms: dict[str, float]
    cameras: dict[str, CameraCalibration]
    board_poses: dict[str, Pose]
    world: str
    messages: tuple[str, ...] = field(default=())


def _rodrigues(r: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrices ``(N, 3, 3)`` of rotation vectors ``(N, 3)``."""
    theta = np.linalg.norm(r, axis=1)
    small = theta < 1e-12
    k = r / np.where(small, 1.0, theta)[:, None]
    K = np.zeros((len(r), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    R = np.eye(3) + s * K + (1 - c) * (K @ K)
    # Near 0: I + [r]x to first order (the exact formula divides 0 by 0).
    R[small] = np.eye(3) + _skew(r[small])
    return R


def _skew(r: NDArray[np.float64]) -> NDArray[np.float64]:
    S = np.zeros((len(r), 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
    S[:, 1, 0], S[:, 2, 0], S[:, 2, 1] = r[:, 2], -r[:, 1], r[:, 0]
    return S


def _rotation_vector(R: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray(cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0], dtype=np.float64).reshape(3)


def _compose(a: Pose, b: Pose) -> Pose:
    """``a o b``: apply b, then a."""
    return a[0] @ b[0], a[0] @ b[1] + a[1]


def _inverse(a: Pose) -> Pose:
    return a[0].T, -a[0].T @ a[1]


def _mean_pose(poses: list[Pose]) -> Pose:
    """Chordal mean of rotations (nearest rotation to the summed matrices), mean translation."""
    u, _, vt = np.linalg.svd(sum(p[0] for p in poses))
    R = u @ vt
    if np.linalg.det(R) < 0:
        R = u @ np.diag([1.0, 1.0, -1.0]) @ vt
    return R, np.mean([p[1] for p in poses], axis=0)


def _sizes(names: list[str], size: Any) -> dict[str, tuple[int, int]]:
    if isinstance(size, Mapping):
        missing = [n for n in names if n not in size]
        if missing:
            raise InvalidInputError(f"size has no entry for camera(s) {missing}")
        return {n: (int(size[n][0]), int(size[n][1])) for n in names}
    if len(size) != 2:
        raise InvalidInputError(f"size must be (width, height) or a mapping camera -> (width, height), got {size!r}")
    return {n: (int(size[0]), int(size[1])) for n in names}


def calibrate_rig(
    detections: Mapping[str, Mapping[str, BoardView]],
    board: Board,
    size: Any,
    *,
    world: str | None = None,
    K: Mapping[str, Any] | None = None,
    focal_length: float | None = None,
    distortion: Sequence[str] = DISTORTION_NAMES,
) -> RigCalibration:
    """Calibrate several cameras from their views of one board.

    Parameters
    ----------
    detections : mapping of camera name -> mapping of view -> BoardView
        What each camera saw in each view (a view is one placement of the board, seen at
        the same moment by the cameras that list it); rig order = mapping order.
    board : Chessboard or CharucoTarget
        Its ``square_size`` is the unit of length of the result.
    size : (width, height) or mapping of camera name -> (width, height)
        Image sizes, pixels.
    world : str, keyword-only
        A camera's name to put the world frame on that camera; default: the board of the
        first view (the view key that sorts first) is the world frame.
    K : mapping of camera name -> (3, 3), keyword-only
        Known or nominal intrinsics, per camera (see :func:`calibrate_camera`).
    focal_length : float, keyword-only
        Focal length guess, pixels, for cameras whose views do not determine it.
    distortion : sequence of str, keyword-only
        Distortion coefficients to estimate (see :func:`calibrate_camera`).

    Returns
    -------
    RigCalibration

    Warns
    -----
    UnderdeterminedCalibrationWarning
        Per camera, as :func:`calibrate_camera`.

    Raises
    ------
    InvalidInputError
        A camera without usable views, a camera that shares no view (directly or through
        other cameras) with the rest, an unknown ``world`` camera.

    Notes
    -----
    The joint refinement keeps fixed whatever a camera's own calibration held fixed, so a
    camera's focal length is never estimated from views that could not determine it.
    """
    names = list(detections)
    if not names:
        raise InvalidInputError("detections is empty: no camera")
    if world is not None and world not in names:
        raise InvalidInputError(f"world must be one of the cameras {names} or None, got {world!r}")
    sizes = _sizes(names, size)
    singles: dict[str, CameraCalibration] = {}
    for name in names:
        given = None if K is None else K.get(name)
        singles[name] = calibrate_camera(
            detections[name], board, sizes[name], name=name, K=given,
            focal_length=focal_length, distortion=tuple(distortion),
        )
    reference = world if world is not None else max(names, key=lambda n: len(singles[n].views))
    camera_poses = _initial_camera_poses(names, singles, reference)
    view_keys = sorted({v for n in names for v in singles[n].views})
    view_poses: dict[str, Pose] = {}
    for v in view_keys:
        seen_by = [n for n in [reference, *names] if v in singles[n].views]
        n = seen_by[0]
        view_poses[v] = _compose(_inverse(camera_poses[n]), singles[n].views[v])
    problem = _Bundle(names, singles, detections, board, reference, view_keys)
    camera_poses, view_poses, intrinsics = problem.solve(camera_poses, view_poses)
    rms = problem.rms
    world_from_reference: Pose
    if world is None:
        world_key = f"board:{view_keys[0]}"
        world_from_reference = _inverse(view_poses[view_keys[0]])
    else:
        world_key = world
        world_from_reference = camera_poses[world]
    reference_from_world = _inverse(world_from_reference)
    cameras = []
    for name in names:
        R, t = _compose(camera_poses[name], reference_from_world)
        base = singles[name].camera
        cameras.append(Camera(name, intrinsics[name][0], intrinsics[name][1], R, t, base.width, base.height))
    board_poses = {v: _compose(world_from_reference, view_poses[v]) for v in view_keys}
    messages = tuple(m for n in names for m in singles[n].messages)
    return RigCalibration(Rig(cameras), rms, singles, board_poses, world_key, messages)


def calibrate_stereo(
    left: Mapping[str, BoardView],
    right: Mapping[str, BoardView],
    board: Board,
    size: Any,
    *,
    names: tuple[str, str] = ("left", "right"),
    **options: Any,
) -> RigCalibration:
    """:func:`calibrate_rig` for two cameras: ``left`` and ``right`` map view keys (the
    same key for the two images of one board placement) to detections."""
    return calibrate_rig({names[0]: left, names[1]: right}, board, size, **options)


def _initial_camera_poses(names: list[str], singles: dict[str, CameraCalibration], reference: str) -> dict[str, Pose]:
    """Reference -> camera poses from shared views, by breadth-first search from the
    reference camera over cameras that share views."""
    poses: dict[str, Pose] = {reference: (np.eye(3), np.zeros(3))}
    frontier = [reference]
    while frontier:
        known = frontier.pop(0)
        for name in names:
            if name in poses:
                continue
            shared = sorted(set(singles[name].views) & set(singles[known].views))
            if not shared:
                continue
            # camera <- known = (camera <- board) o (known <- board)^-1, averaged over views.
            relative = _mean_pose([_compose(singles[name].views[v], _inverse(singles[known].views[v])) for v in shared])
            poses[name] = _compose(relative, poses[known])
            frontier.append(name)
    lost = [n for n in names if n not in poses]
    if lost:
        raise InvalidInputError(
            f"camera(s) {lost} share no view of the board with camera {reference!r} (nor through other cameras): "
            "their poses cannot be found"
        )
    return poses


class _Bundle:
    """The joint least-squares problem over intrinsics, camera poses and board poses."""

    def __init__(
        self,
        names: list[str],
        singles: dict[str, CameraCalibration],
        detections: Mapping[str, Mapping[str, BoardView]],
        board: Board,
        reference: str,
        view_keys: list[str],
    ) -> None:
        self.names, self.reference, self.view_keys = names, reference, view_keys
        self.singles = singles
        view_index = {v: i for i, v in enumerate(view_keys)}
        cam_idx, view_idx, points, uv = [], [], [], []
        for c, name in enumerate(names):
            for v in singles[name].views:
                det = detections[name][v]
                cam_idx.append(np.full(len(det.ids), c))
                view_idx.append(np.full(len(det.ids), view_index[v]))
                points.append(board.object_points[det.ids])
                uv.append(det.corners)
        self.cam_idx = np.concatenate(cam_idx)
        self.view_idx = np.concatenate(view_idx)
        self.points = np.concatenate(points)
        self.uv = np.concatenate(uv)
        # Free intrinsic parameters: each is a group of positions in a camera's 9-vector
        # (fx and fy move together where the aspect ratio was held).
        self.base = np.array([
            [*(singles[n].camera.K[[0, 1, 0, 1], [0, 1, 2, 2]]), *singles[n].camera.dist] for n in names
        ])
        self.groups: list[tuple[int, list[int]]] = []
        for c, n in enumerate(names):
            fixed = set(singles[n].fixed)
            if "focal" not in fixed:
                self.groups += [(c, [0, 1])] if "aspect" in fixed else [(c, [0]), (c, [1])]
            if "principal_point" not in fixed:
                self.groups += [(c, [2]), (c, [3])]
            self.groups += [(c, [4 + i]) for i, d in enumerate(DISTORTION_NAMES) if d not in fixed]
        self.moving = [n for n in names if n != reference]

    def _unpack(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        intr = self.base.copy()
        g = len(self.groups)
        for (c, positions), value in zip(self.groups, x[:g]):
            # Groups move their positions by the same relative amount (keeps fy/fx fixed).
            intr[c, positions] = self.base[c, positions] * value if len(positions) > 1 else value
        m = len(self.moving)
        cam = x[g : g + 6 * m].reshape(m, 6)
        views = x[g + 6 * m :].reshape(-1, 6)
        Rc = np.repeat(np.eye(3)[None], len(self.names), axis=0)
        tc = np.zeros((len(self.names), 3))
        index = [self.names.index(n) for n in self.moving]
        if m:
            Rc[index] = _rodrigues(cam[:, :3])
            tc[index] = cam[:, 3:]
        return intr, Rc, tc, _rodrigues(views[:, :3]), views[:, 3:]

    def residuals(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        intr, Rc, tc, Rv, tv = self._unpack(x)
        c, v = self.cam_idx, self.view_idx
        in_reference = np.einsum("nij,nj->ni", Rv[v], self.points) + tv[v]
        in_camera = np.einsum("nij,nj->ni", Rc[c], in_reference) + tc[c]
        a = in_camera[:, 0] / in_camera[:, 2]
        b = in_camera[:, 1] / in_camera[:, 2]
        p = intr[c]
        k1, k2, p1, p2, k3 = p[:, 4], p[:, 5], p[:, 6], p[:, 7], p[:, 8]
        r2 = a * a + b * b
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        ad = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
        bd = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
        u = p[:, 0] * ad + p[:, 2]
        w = p[:, 1] * bd + p[:, 3]
        return np.concatenate([u - self.uv[:, 0], w - self.uv[:, 1]])

    def _column_groups(self, n_params: int) -> list[tuple[NDArray[np.int64], NDArray[np.int64]]]:
        """Sets of parameters whose residual rows do not overlap, so that one residual
        evaluation differentiates them all: the k-th intrinsic of every camera, the k-th pose
        parameter of every moving camera, the k-th pose parameter of every view. Each set
        comes with its residual rows per column (as a mask per observation)."""
        groups: list[tuple[NDArray[np.int64], NDArray[np.int64]]] = []
        by_camera: dict[int, list[int]] = {}
        for j, (c, _) in enumerate(self.groups):
            by_camera.setdefault(c, []).append(j)
        for k in range(max((len(v) for v in by_camera.values()), default=0)):
            columns = np.array([cols[k] for cols in by_camera.values() if k < len(cols)], dtype=np.int64)
            groups.append((columns, np.array([self.groups[j][0] for j in columns], dtype=np.int64)))
        g = len(self.groups)
        moving = np.array([self.names.index(n) for n in self.moving], dtype=np.int64)
        for q in range(6 if len(moving) else 0):
            groups.append((g + 6 * np.arange(len(moving), dtype=np.int64) + q, moving))
        base = g + 6 * len(self.moving)
        for q in range(6):
            views = np.arange(len(self.view_keys), dtype=np.int64)
            groups.append((base + 6 * views + q, -1 - views))
        return groups

    def jacobian(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Dense Jacobian of :meth:`residuals` by central differences, one pair of residual
        evaluations per set of :meth:`_column_groups` (about 20 pairs in all)."""
        n_obs = len(self.uv)
        J = np.zeros((2 * n_obs, len(x)))
        for columns, owners in self._groups:
            h = FD_STEP * np.maximum(1.0, np.abs(x[columns]))
            up, down = x.copy(), x.copy()
            up[columns] += h
            down[columns] -= h
            difference = (self.residuals(up) - self.residuals(down)).reshape(2, n_obs)
            # Each observation belongs to exactly one column of the set: its camera's (for
            # intrinsics and camera poses) or its view's (owners < 0 encode views).
            key, owner = (self.cam_idx, owners) if owners[0] >= 0 else (self.view_idx, -1 - owners)
            lookup = np.full(int(max(key.max(), owner.max())) + 1, -1)
            lookup[owner] = np.arange(len(columns))
            which = lookup[key]
            rows = np.flatnonzero(which >= 0)
            column = columns[which[rows]]
            step = 2 * h[which[rows]]
            J[rows, column] = difference[0, rows] / step
            J[rows + n_obs, column] = difference[1, rows] / step
        return J

    def solve(self, camera_poses: dict[str, Pose], view_poses: dict[str, Pose]) -> tuple[dict[str, Pose], dict[str, Pose], dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]]:
        x0 = [1.0 if len(pos) > 1 else self.base[c, pos[0]] for c, pos in self.groups]
        for name in self.moving:
            x0 += [*_rotation_vector(camera_poses[name][0]), *camera_poses[name][1]]
        for v in self.view_keys:
            x0 += [*_rotation_vector(view_poses[v][0]), *view_poses[v][1]]
        x0_ = np.array(x0, dtype=np.float64)
        self._groups = self._column_groups(len(x0_))
        result = scipy.optimize.least_squares(
            self.residuals, x0_, jac=self.jacobian, method="lm", x_scale="jac",
            ftol=BUNDLE_TOLERANCE, xtol=BUNDLE_TOLERANCE, gtol=BUNDLE_TOLERANCE,
        )
        intr, Rc, tc, Rv, tv = self._unpack(result.x)
        r = self.residuals(result.x).reshape(2, -1)
        squared = (r**2).sum(axis=0)
        self.rms = {
            n: float(np.sqrt(squared[self.cam_idx == c].mean())) for c, n in enumerate(self.names)
        }
        cameras = {n: (Rc[c], tc[c]) for c, n in enumerate(self.names)}
        views = {v: (Rv[i], tv[i]) for i, v in enumerate(self.view_keys)}
        intrinsics = {
            n: (
                np.array([[intr[c, 0], 0.0, intr[c, 2]], [0.0, intr[c, 1], intr[c, 3]], [0.0, 0.0, 1.0]]),
                intr[c, 4:].copy(),
            )
            for c, n in enumerate(self.names)
        }
        return cameras, views, intrinsics
