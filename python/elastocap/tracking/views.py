"""Across cameras: spatial least-squares matching of a point's patch from one camera into
others at the projection of its 3-D position (confirmation of new views and re-acquisition
of lost ones), and the forward intersection of the tracked views with blunder rejection.

Every step is vectorised over points; Python loops run over camera pairs only."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from elastocap.cameras import Camera
from elastocap.stereo import intersect, match_patches
from elastocap.stereo.matching import MatchStatus

__all__ = ["facing_normals", "intersect_views", "plane_affine", "project_all", "spatial_match"]


def project_all(cameras: Sequence[Camera], points: NDArray[np.float64], margin: float) -> NDArray[np.float64]:
    """(N, C, 2) projections; NaN for non-finite points, behind a camera or closer than
    ``margin`` pixels to the image border."""
    n, c = len(points), len(cameras)
    out = np.full((n, c, 2), np.nan)
    ok = np.isfinite(points).all(axis=1)
    if not ok.any():
        return out
    x = points[ok]
    for k, cam in enumerate(cameras):
        uv, _ = cam.project(x)
        depth = cam.to_camera(x)[:, 2]
        inside = (depth > 0) & (uv[:, 0] >= margin) & (uv[:, 1] >= margin) & (uv[:, 0] <= cam.width - 1 - margin) & (uv[:, 1] <= cam.height - 1 - margin)
        block = np.where(inside[:, None], uv, np.nan)
        out[np.flatnonzero(ok), k] = block
    return out


def plane_affine(cameras: Sequence[Camera], r: int, k: int, uv: NDArray[np.float64], points: NDArray[np.float64],
                 normals: NDArray[np.float64]) -> NDArray[np.float64]:
    """(M, 2, 3) affine start maps from camera ``r``'s patch around ``uv`` (M, 2) into
    camera ``k``: the derivative of the homography the plane through ``points`` with
    ``normals`` induces (one-pixel central differences), centred on the projection."""
    out = np.zeros((len(uv), 2, 3))
    columns = []
    for e in (np.array([1.0, 0.0]), np.array([0.0, 1.0])):
        ends = []
        for sign in (1.0, -1.0):
            o, d = cameras[r].rays(uv + sign * e)
            t = np.einsum("ij,ij->i", points - o, normals) / np.einsum("ij,ij->i", d, normals)
            ends.append(cameras[k].project(o + t[:, None] * d)[0])
        columns.append(0.5 * (ends[0] - ends[1]))
    out[:, :, 0], out[:, :, 1] = columns
    out[:, :, 2] = cameras[k].project(points)[0]
    return out


def facing_normals(cameras: Sequence[Camera], points: NDArray[np.float64], used: NDArray[np.bool_]) -> NDArray[np.float64]:
    """(N, 3) a guess of the surface normal: the mean direction from the point to the
    centres of the cameras that see it (the surface faces them)."""
    total = np.zeros_like(points)
    for k, cam in enumerate(cameras):
        d = cam.center - points
        total += np.where(used[:, k, None], d / np.linalg.norm(d, axis=1, keepdims=True), 0.0)
    norm = np.linalg.norm(total, axis=1, keepdims=True)
    return total / np.where(norm > 0, norm, 1.0)


def surface_normals(points: NDArray[np.float64], cloud: NDArray[np.float64], towards: NDArray[np.float64], *,
                    neighbours: int = 10) -> NDArray[np.float64]:
    """(N, 3) unit normals at ``points`` from the plane of their ``neighbours`` nearest
    points of ``cloud`` (M, 3; the tracked points, NaN rows ignored), turned to face
    ``towards`` (N, 3; e.g. :func:`facing_normals`); ``towards`` itself where the cloud
    is too small or the neighbours do not span a plane (a line of points)."""
    from scipy.spatial import cKDTree

    good = cloud[np.isfinite(cloud).all(axis=1)]
    out = towards.copy()
    ok = np.isfinite(points).all(axis=1)
    if len(good) < neighbours or not ok.any():
        return out
    _, near = cKDTree(good).query(points[ok], k=neighbours)
    local = good[near] - good[near].mean(axis=1, keepdims=True)
    values, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", local, local))
    normal = vectors[:, :, 0]
    # A plane: two directions of spread, the third well below them.
    flat = (values[:, 0] < 0.25 * values[:, 1]) & (values[:, 1] > 0.05 * values[:, 2])
    normal *= np.where(np.einsum("ni,ni->n", normal, towards[ok]) < 0, -1.0, 1.0)[:, None]
    out[np.flatnonzero(ok)[flat]] = normal[flat]
    return out


def spatial_match(
    images: Sequence[NDArray[np.float32]],
    reference: NDArray[np.int64],
    template_uv: NDArray[np.float64],
    targets: NDArray[np.float64],
    *,
    cameras: Sequence[Camera] | None = None,
    points: NDArray[np.float64] | None = None,
    normals: NDArray[np.float64] | None = None,
    size: int,
    min_correlation: float,
    tolerance: float | NDArray[np.float64],
    min_texture: float,
    weights: Sequence[NDArray[np.float32]] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Match each point's patch in its reference camera into the cameras where ``targets``
    (N, C, 2) is finite, started there (identity shape). A match counts when it converged,
    its correlation reaches ``min_correlation`` and it lies within ``tolerance`` pixels of
    its target. With ``cameras``, ``points`` and ``normals`` the start's shape is the
    plane's (:func:`plane_affine`): wide baselines foreshorten and turn the patch. With
    ``weights`` (per camera, its mask) the reference patch is weighed by its camera's. Returns the matched positions (N, C, 2; NaN elsewhere) and their per-view
    covariance (N, C, 2, 2)."""
    n, c = targets.shape[:2]
    uv = np.full((n, c, 2), np.nan)
    cov = np.full((n, c, 2, 2), np.nan)
    wanted = np.isfinite(targets).all(axis=2)
    tol = np.broadcast_to(np.asarray(tolerance, float).reshape(-1), (n,))
    for r in range(c):
        for k in range(c):
            rows = np.flatnonzero((reference == r) & wanted[:, k])
            if k == r or rows.size == 0:
                continue
            initial: NDArray[np.float64] = targets[rows, k][:, None, :]
            if cameras is not None and points is not None and normals is not None:
                affine = plane_affine(cameras, r, k, template_uv[rows], points[rows], normals[rows])
                affine[:, :, 2] = targets[rows, k]
                det = affine[:, 0, 0] * affine[:, 1, 1] - affine[:, 0, 1] * affine[:, 1, 0]
                if not (np.isfinite(affine).all() and (det > 0).all()):
                    affine[~(np.isfinite(affine).all(axis=(1, 2)) & (det > 0))] = np.array([[1.0, 0, 0], [0, 1.0, 0]])
                    affine[:, :, 2] = targets[rows, k]
                initial = affine[:, None]
            m = match_patches(images[r], template_uv[rows], [images[k]], initial=initial,
                              size=size, min_texture=min_texture, max_iterations=20,
                              weights=None if weights is None else weights[r])
            pos = m.positions[:, 0]
            good = ((m.status[:, 0] == MatchStatus.CONVERGED) & (m.correlation[:, 0] >= min_correlation)
                    & (np.linalg.norm(pos - targets[rows, k], axis=1) <= tol[rows]))
            uv[rows[good], k] = pos[good]
            cov[rows[good], k] = m.position_covariance()[good]
    return uv, cov


def intersect_views(
    cameras: Sequence[Camera],
    uv: NDArray[np.float64],
    cov: NDArray[np.float64],
    *,
    max_residual: float,
    floor: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]:
    """Forward intersection of the tracked views (N, C, 2) with their covariances (N, C, 2,
    2; a floor of ``floor`` pixels added to each standard deviation: the matcher's covariance
    leaves out the template's drift), rejecting blunders by normalised residuals and views
    whose residual exceeds ``max_residual`` pixels. Returns points (N, 3), covariances
    (N, 3, 3), the used views (N, C) and the views rejected as inconsistent (N, C)."""
    n, c = uv.shape[:2]
    observed = np.isfinite(uv).all(axis=2) & np.isfinite(cov).all(axis=(2, 3))
    sigma = np.where(observed[..., None, None], np.nan_to_num(cov) + floor**2 * np.eye(2), np.nan)
    obs = np.where(observed[..., None], uv, np.nan)
    points = np.full((n, 3), np.nan)
    covariance = np.full((n, 3, 3), np.nan)
    used = np.zeros((n, c), bool)
    rejected = np.zeros((n, c), bool)
    rows = np.flatnonzero(observed.sum(axis=1) >= 2)
    if rows.size:
        result = intersect(cameras, obs[rows], covariance=sigma[rows])
        residual = np.linalg.norm(np.nan_to_num(result.residuals), axis=2)
        bad = result.used & (residual > max_residual)
        keep = result.valid & ~bad.any(axis=1)
        points[rows[keep]] = result.points[keep]
        covariance[rows[keep]] = result.covariance[keep]
        used[rows[keep]] = result.used[keep]
        rejected[rows] = (observed[rows] & ~result.used & result.valid[:, None]) | bad
    return points, covariance, used, rejected
