"""Which cameras can see a tracked point, without ground truth (issue 15): a camera sees a
surface point when the point projects inside its silhouette, the surface there faces the
camera (the normal from the plane of the neighbouring tracked points, turned towards the
cameras that hold the point) and no other tracked point lies in front of it along the same
line of sight (a z-buffer of the tracked points: an arm passing in front of the body).

The re-acquisition and the revival leave the other cameras alone instead of matching a
patch they cannot show: on the textured capture 88% of the re-acquisition's tries went
into such cameras (benches/README.md, track5). Measured on the truth of seed 0 (half the
material points as the cloud, 3 mm noise, frames 0-50 by 10; branch track6): 90% of the
visible (point, camera) pairs inside a silhouette kept, 97% of the invisible ones
refused. A visual hull's line-of-sight test kept only 47-65% of the visible pairs (the
hull of four directions is fat between the limbs) and cost 50 times more."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from elastocap._core import track_occluded
from elastocap.cameras import Camera

__all__ = ["predicted_visible"]

# Points of the z-buffer compared with each point (the nearest projections within the radius).
_OCCLUDERS = 12


def predicted_visible(cameras: Sequence[Camera], masks: Sequence[NDArray[np.bool_]], points: NDArray[np.float64],
                      normals: NDArray[np.float64], cloud: NDArray[np.float64], where: NDArray[np.bool_], *,
                      facing: float = 0.0, radius: float = 6.0, gap: float = 12.0) -> NDArray[np.bool_]:
    """(N, C) whether camera ``k`` is predicted to see ``points[p]``, asked where
    ``where[p, k]`` (False elsewhere and where the point is not finite).

    Parameters
    ----------
    cameras : sequence of Camera
    masks : sequence of (H, W) bool
        The frame's silhouettes, one per camera.
    points : (N, 3) float64
        World positions of the points asked about.
    normals : (N, 3) float64
        Unit surface normals at ``points`` (outwards: towards the cameras that see them).
    cloud : (M, 3) float64
        The tracked points of the frame (NaN rows ignored): the occluders.
    where : (N, C) bool
        The (point, camera) pairs asked about.
    facing : float, default 0
        Least cosine between the normal and the direction to the camera.
    radius : float, default 6
        Pixels: cloud points projecting this near to a point's projection are on its line of sight...
    gap : float, default 12
        ... and hide it when nearer to the camera by more than this many pixel
        equivalents (the depth of one pixel at the point): a limb in front, not the
        surface around the point.
    """
    n, c = where.shape
    out = np.zeros((n, c), bool)
    where = where & np.all(np.isfinite(points), axis=1)[:, None] & np.all(np.isfinite(normals), axis=1)[:, None]
    occluders = cloud[np.isfinite(cloud).all(axis=1)]
    for k, (cam, mask) in enumerate(zip(cameras, masks)):
        rows = np.flatnonzero(where[:, k])
        if rows.size == 0:
            continue
        x = points[rows]
        # The projection's depth is the camera frame's z (one transform, not two). The
        # points and the occluders in one projection where each part has two rows or more
        # (a single row's matrix product rounds otherwise: views.plane_offset_points).
        together = rows.size >= 2 and len(occluders) >= 2
        if together:
            both_uv, both_depth = cam.project(np.concatenate([x, occluders]))
            uv, depth = both_uv[: rows.size], both_depth[: rows.size]
        else:
            uv, depth = cam.project(x)
        iu, iv = np.round(uv[:, 0]), np.round(uv[:, 1])
        ok = (depth > 0) & (iu >= 0) & (iv >= 0) & (iu <= mask.shape[1] - 1) & (iv <= mask.shape[0] - 1)
        ok[ok] = mask[iv[ok].astype(np.intp), iu[ok].astype(np.intp)]
        view = cam.center - x
        view /= np.linalg.norm(view, axis=1, keepdims=True)
        ok &= np.einsum("ij,ij->i", view, normals[rows]) > facing
        if len(occluders) and ok.any():
            ouv, odepth = (both_uv[rows.size :], both_depth[rows.size :]) if together else cam.project(occluders)
            front = odepth > 0
            ouv, odepth = ouv[front], odepth[front]
            if len(odepth):
                # One pixel at the point's depth, in world units: depth / focal length.
                pixel = depth[ok] / float(cam.K[0, 0])
                # The core's grid, by the rule of cKDTree(ouv).query(uv[ok], k=_OCCLUDERS,
                # distance_upper_bound=radius) (the tree cost ~0.01 CPU s a frame).
                hidden = track_occluded(np.ascontiguousarray(ouv), np.ascontiguousarray(odepth),
                                        np.ascontiguousarray(uv[ok]), depth[ok] - gap * pixel,
                                        radius=float(radius), nearest=_OCCLUDERS)
                ok[np.flatnonzero(ok)[hidden]] = False
        out[rows[ok], k] = True
    return out
