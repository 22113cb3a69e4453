"""Trajectory filters (SPEC 7): velocity and acceleration thresholds, and local uniformity
(a point's velocity against the median velocity of its neighbouring trajectories), all in
pixel equivalents (world units divided by the pixel footprint at the point's depth) so that
one setting fits any rig scale."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from elastocap.cameras import Camera
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.rigidity import nanmedian_rows

__all__ = ["pixel_size", "trajectory_flags"]

# Neighbouring trajectories count within this distance, pixel equivalents.
_REACH = 40.0


def pixel_size(cameras: Sequence[Camera], points: NDArray[np.float64], used: NDArray[np.bool_]) -> NDArray[np.float64]:
    """(N,) world size of a pixel at each point: depth / focal length, the mean over the
    cameras that see it (NaN without any)."""
    total = np.zeros(len(points))
    count = np.zeros(len(points))
    x = np.nan_to_num(points)
    for k, cam in enumerate(cameras):
        size = cam.to_camera(x)[:, 2] / cam.K[0, 0]
        total += np.where(used[:, k], size, 0.0)
        count += used[:, k]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan)


def trajectory_flags(
    current: NDArray[np.float64],
    last: NDArray[np.float64],
    before: NDArray[np.float64],
    pixel: NDArray[np.float64],
    *,
    max_velocity: float,
    max_acceleration: float,
    uniformity: float,
    neighbours: int,
) -> NDArray[np.uint8]:
    """(N,) flags of the trajectory filters for points at ``current`` (N, 3; NaN where not
    tracked), ``last`` and ``before`` (their positions one and two frames earlier, NaN where
    unknown). ``pixel`` (N,) converts world units to pixel equivalents. Thresholds in pixel
    equivalents per frame (velocity, and its deviation from the neighbours' median) and per
    frame squared (acceleration)."""
    n = len(current)
    flags = np.zeros(n, np.uint8)
    velocity = current - last
    with np.errstate(invalid="ignore"):
        speed = np.linalg.norm(velocity, axis=1) / pixel
        accel = np.linalg.norm(current - 2 * last + before, axis=1) / pixel
    flags[speed > max_velocity] = TrackFlag.VELOCITY
    flags[(flags == 0) & (accel > max_acceleration)] = TrackFlag.ACCELERATION
    moving = np.flatnonzero(np.isfinite(velocity).all(axis=1) & np.isfinite(pixel))
    k = min(neighbours, moving.size - 1)
    if k >= 3:
        tree = cKDTree(current[moving])
        distance, near = tree.query(current[moving], k=k + 1)
        # Neighbours only within a reach of the point (another limb nearby moves otherwise),
        # and the threshold widened by how much the neighbours disagree among themselves
        # (a turning or deforming surface has a velocity gradient).
        reach = _REACH * pixel[moving]
        close = distance[:, 1:] <= reach[:, None]
        v = velocity[moving][near[:, 1:]]
        v = np.where(close[..., None], v, np.nan)
        with np.errstate(all="ignore"):
            # np.nanmedian's medians to the bit, without its masked sort (~5 ms a frame):
            # each velocity component's over the neighbours, then the spread's.
            m = len(moving)
            local = nanmedian_rows(v.transpose(0, 2, 1).reshape(3 * m, k)).reshape(m, 3)
            spread = nanmedian_rows(np.linalg.norm(v - local[:, None], axis=2)) / pixel[moving]
            deviation = np.linalg.norm(velocity[moving] - local, axis=1) / pixel[moving]
        enough = close.sum(axis=1) >= 3
        odd = moving[enough & (deviation > uniformity + 3.0 * np.nan_to_num(spread))]
        flags[odd[flags[odd] == 0]] = TrackFlag.NONUNIFORM
    return flags
