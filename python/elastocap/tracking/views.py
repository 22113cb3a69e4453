"""Across cameras: spatial least-squares matching of a point's patch from one camera into
others at the projection of its 3-D position (confirmation of new views and re-acquisition
of lost ones), and the forward intersection of the tracked views with blunder rejection.

Every step is vectorised over points; Python loops run over camera pairs only."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap import _core
from elastocap.cameras import Camera
from elastocap.stereo import intersect
from elastocap.stereo.matching import MatchStatus, match_checked_pairs
from elastocap.tracking.frame_images import checked as checked_images
from elastocap.tracking.frame_images import checked_weights_of

__all__ = ["confirm_views", "facing_normals", "intersect_views", "plane_affine", "plane_affine_from", "plane_offset_points",
           "plane_warped_tiles", "project_all", "spatial_match", "spatial_search"]


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
        uv, depth = cam.project(x)
        inside = (depth > 0) & (uv[:, 0] >= margin) & (uv[:, 1] >= margin) & (uv[:, 0] <= cam.width - 1 - margin) & (uv[:, 1] <= cam.height - 1 - margin)
        block = np.where(inside[:, None], uv, np.nan)
        out[np.flatnonzero(ok), k] = block
    return out


def plane_affine(cameras: Sequence[Camera], r: int, k: int, uv: NDArray[np.float64], points: NDArray[np.float64],
                 normals: NDArray[np.float64]) -> NDArray[np.float64]:
    """(M, 2, 3) affine start maps from camera ``r``'s patch around ``uv`` (M, 2) into
    camera ``k``: the derivative of the homography the plane through ``points`` with
    ``normals`` induces (one-pixel central differences), centred on the projection."""
    return plane_affine_from(cameras[k], plane_offset_points(cameras[r], uv, points, normals), points)


def plane_offset_points(camera: Camera, uv: NDArray[np.float64], points: NDArray[np.float64],
                        normals: NDArray[np.float64]) -> NDArray[np.float64]:
    """(M, 4, 3) where the rays of ``camera`` through ``uv`` (M, 2) shifted by +u, -u, +v,
    -v one pixel meet the planes through ``points`` with ``normals``: what
    :func:`plane_affine` differences, the same for every target camera (computed once per
    reference camera, not once per camera pair: the rays' undistortion is most of it)."""
    m = len(uv)
    shifts = ((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0))
    shifted = []
    for e, sign in shifts:
        shift = np.zeros(2)
        shift[e] = sign
        shifted.append(uv + shift)
    if m < 2:
        # One ray a call: numpy multiplies a single row by the camera's matrices through
        # BLAS's matrix-vector product, whose rounding differs from the matrix-matrix
        # product of the batch below (tests/test_track_plane_starts.py); kept per shift.
        out = np.empty((m, 4, 3))
        for j, pixels in enumerate(shifted):
            o, d = camera.rays(pixels)
            t = np.einsum("ij,ij->i", points - o, normals) / np.einsum("ij,ij->i", d, normals)
            out[:, j] = o + t[:, None] * d
        return out
    # The four shifts' rays in one call (row by row the same numbers as four calls: the
    # undistortion is elementwise and the matrix products round each row alike from two rows on).
    o, d = camera.rays(np.concatenate(shifted))
    points4, normals4 = np.concatenate([points] * 4), np.concatenate([normals] * 4)
    t = np.einsum("ij,ij->i", points4 - o, normals4) / np.einsum("ij,ij->i", d, normals4)
    return np.ascontiguousarray((o + t[:, None] * d).reshape(4, m, 3).transpose(1, 0, 2))


def plane_affine_from(camera: Camera, ends: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """(M, 2, 3) :func:`plane_affine` into ``camera`` from the plane's offset points
    ``ends`` (M, 4, 3; :func:`plane_offset_points`) and the points (M, 3)."""
    m = len(points)
    out = np.zeros((m, 2, 3))
    projected = camera.project(ends.reshape(-1, 3))[0].reshape(m, 4, 2)
    out[:, :, 0] = 0.5 * (projected[:, 0] - projected[:, 1])
    out[:, :, 1] = 0.5 * (projected[:, 2] - projected[:, 3])
    out[:, :, 2] = camera.project(points)[0]
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
    gathered = good[near]  # (N, neighbours, 3), gathered once
    local = gathered - gathered.mean(axis=1, keepdims=True)
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
    wanted = np.all(np.isfinite(targets), axis=2)
    tol = np.broadcast_to(np.asarray(tolerance, float).reshape(-1), (n,))
    # Each image (and mask) checked once here, not once per camera pair.
    references = np.unique(reference[wanted.any(axis=1)])
    checked = {int(k): checked_images(images, int(k)) for k in np.union1d(np.flatnonzero(wanted.any(axis=0)), references)}
    checked_w = {} if weights is None else {int(r): checked_weights_of(weights, int(r), checked[int(r)].shape) for r in references}
    plane = cameras is not None and points is not None and normals is not None
    # Every camera pair's patches gathered, then matched in one parallel core call: ~80-100
    # pairs of a few dozen patches a frame.
    gathered_rows, gathered_pairs = [], []
    # The plane's points under the template's one-pixel offsets, once per reference camera
    # for every target camera (a point has one reference camera: one array serves them all).
    ends = np.full((n, 4, 3), np.nan) if plane else None
    for r in range(c):
        mine = (reference == r) & wanted.any(axis=1)
        if not mine.any():
            continue
        if ends is not None:
            assert cameras is not None and points is not None and normals is not None
            ends[mine] = plane_offset_points(cameras[r], template_uv[mine], points[mine], normals[mine])
        # The pairs (r, k), k != r, in the order of k, each pair's rows in order.
        asked = mine[:, None] & wanted
        asked[:, r] = False
        into, rows = np.nonzero(asked.T)
        if rows.size:
            gathered_rows.append(rows)
            gathered_pairs.append(np.column_stack([np.full(rows.size, r), into]))
    if not gathered_rows:
        return uv, cov
    rows = np.concatenate(gathered_rows)
    pairs = np.concatenate(gathered_pairs)
    target = pairs[:, 1]
    starts = np.zeros((rows.size, 2, 3))
    starts[:, 0, 0] = starts[:, 1, 1] = 1.0
    if ends is not None:
        assert cameras is not None
        # The start maps of every pair into a target camera from one projection of their
        # plane points (plane_affine_from's linear part; its centre, the points' projection,
        # is replaced by the target): 8 projections, not two per camera pair.
        for k in np.unique(target):
            into = np.flatnonzero(target == k)
            projected = cameras[k].project(ends[rows[into]].reshape(-1, 3))[0].reshape(-1, 4, 2)
            starts[into, :, 0] = 0.5 * (projected[:, 0] - projected[:, 1])
            starts[into, :, 1] = 0.5 * (projected[:, 2] - projected[:, 3])
        starts[:, :, 2] = targets[rows, target]
        det = starts[:, 0, 0] * starts[:, 1, 1] - starts[:, 0, 1] * starts[:, 1, 0]
        bad = ~(np.isfinite(starts).all(axis=(1, 2)) & (det > 0))
        starts[bad, :, :2] = np.eye(2)
    starts[:, :, 2] = targets[rows, target]
    m = match_checked_pairs([checked.get(k) for k in range(c)], pairs, template_uv[rows], starts,
                            size=size, min_texture=min_texture, max_iterations=20,
                            weights=None if weights is None else [checked_w.get(k) for k in range(c)])
    pos = m.positions[:, 0]
    good = ((m.status[:, 0] == MatchStatus.CONVERGED) & (m.correlation[:, 0] >= min_correlation)
            & (np.linalg.norm(pos - targets[rows, target], axis=1) <= tol[rows]))
    uv[rows[good], target[good]] = pos[good]
    cov[rows[good], target[good]] = m.position_covariance()[good]
    return uv, cov


def plane_warped_tiles(image: NDArray[np.float32], uv: NDArray[np.float64], affine: NDArray[np.float64],
                       side: int) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
    """The patches of ``image`` around ``uv`` (M, 2) as another camera would see them:
    tile ``i`` samples ``image`` at ``uv[i] + L_i^-1 q`` for the tile's offsets ``q`` from
    its centre, ``L_i`` the linear part of ``affine[i]`` (M, 2, 3; :func:`plane_affine`).
    Returns a mosaic of ``side x side`` tiles (bilinear, border replicated) and the tiles'
    centres (M, 2) in it."""
    m = len(uv)
    per_row = max(1, int(np.ceil(np.sqrt(m))))
    half = side // 2
    q = np.arange(side, dtype=float) - half
    qu, qv = np.meshgrid(q, q)  # (side, side): column offset, row offset
    inverse = np.linalg.inv(affine[:, :, :2])
    ref_u = uv[:, 0, None, None] + inverse[:, 0, 0, None, None] * qu + inverse[:, 0, 1, None, None] * qv
    ref_v = uv[:, 1, None, None] + inverse[:, 1, 0, None, None] * qu + inverse[:, 1, 1, None, None] * qv
    maps = np.zeros((2, per_row * per_row, side, side), np.float32)
    maps[0, :m], maps[1, :m] = ref_u, ref_v

    def tiled(a: NDArray[np.float32]) -> NDArray[np.float32]:
        return np.ascontiguousarray(a.reshape(per_row, per_row, side, side).transpose(0, 2, 1, 3)
                                    .reshape(per_row * side, per_row * side))

    mosaic = cv2.remap(image, tiled(maps[0]), tiled(maps[1]), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    index = np.arange(m)
    centres = np.column_stack([(index % per_row) * side + half, (index // per_row) * side + half]).astype(float)
    return np.ascontiguousarray(mosaic, dtype=np.float32), centres


def spatial_search(
    images: Sequence[NDArray[np.float32]],
    reference: NDArray[np.int64],
    template_uv: NDArray[np.float64],
    targets: NDArray[np.float64],
    *,
    cameras: Sequence[Camera],
    points: NDArray[np.float64],
    normals: NDArray[np.float64],
    size: int,
    radius: int,
    min_correlation: float,
    box_correlation: float,
    forward_backward: float,
    tolerance: float | NDArray[np.float64],
    min_texture: float,
    max_iterations: int,
    weights: Sequence[NDArray[np.float32]] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`spatial_match` with a search: each point's patch in its reference camera is
    first warped into the target camera's view by the plane through ``points`` with
    ``normals`` (:func:`plane_warped_tiles`), then found there by the tracker's step (NCC
    box search of ``radius`` pixels around the target, least-squares match, forward-
    backward check) -- a point held by one stereo pair projects pixels off in a camera
    45-90 degrees away, and a match started there without a search diverges (track5: 76%
    of the tries into cameras that see the point). Kept when the correlation reaches
    ``min_correlation`` and the match lies within ``tolerance`` pixels of the target.
    Returns positions (N, C, 2) and covariances (N, C, 2, 2), NaN where not found."""
    n, c = targets.shape[:2]
    uv = np.full((n, c, 2), np.nan)
    cov = np.full((n, c, 2, 2), np.nan)
    wanted = np.all(np.isfinite(targets), axis=2)
    tol = np.broadcast_to(np.asarray(tolerance, float).reshape(-1), (n,))
    side = size + 6
    for r in range(c):
        for k in range(c):
            rows = np.flatnonzero((reference == r) & wanted[:, k])
            if k == r or rows.size == 0:
                continue
            affine = plane_affine(cameras, r, k, template_uv[rows], points[rows], normals[rows])
            det = affine[:, 0, 0] * affine[:, 1, 1] - affine[:, 0, 1] * affine[:, 1, 0]
            # A plane seen edge-on (or a failed ray) gives no warp: the identity then.
            bad = ~(np.isfinite(affine).all(axis=(1, 2)) & (det > 0.05))
            affine[bad] = np.array([[1.0, 0, 0], [0, 1.0, 0]])
            mosaic, centres = plane_warped_tiles(images[r], template_uv[rows], affine, side)
            step_weights = None
            if weights is not None:
                weighs, _ = plane_warped_tiles(np.ascontiguousarray(weights[r], dtype=np.float32), template_uv[rows],
                                               affine, side)
                step_weights = ([weighs], [np.ones_like(images[k])])
            # The step predicts 2 last - before: a prediction at the target.
            before = 2 * centres - targets[rows, k]
            pos, flags, pcov, corr = _core.track_step(
                [mosaic], [images[k]], centres[None], before[None], size=size, radius=radius,
                min_correlation=box_correlation, forward_backward=forward_backward, min_texture=min_texture,
                max_iterations=max_iterations, weights=step_weights)
            found = pos[0]
            good = ((flags[0] == 0) & (corr[0] >= min_correlation)
                    & (np.linalg.norm(found - targets[rows, k], axis=1) <= tol[rows]))
            uv[rows[good], k] = found[good]
            cov[rows[good], k] = pcov[0, good]
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
    observed = np.all(np.isfinite(uv), axis=2) & np.all(np.isfinite(cov), axis=(2, 3))
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


def confirm_views(
    cameras: Sequence[Camera],
    uv: NDArray[np.float64],
    cov: NDArray[np.float64],
    new_uv: NDArray[np.float64],
    new_cov: NDArray[np.float64],
    *,
    max_residual: float,
    floor: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """New views ``new_uv`` (N, C, 2; NaN where none, covariances ``new_cov``) of points
    held in ``uv`` (N, C, 2, with ``cov``), checked by intersecting each point's held and new
    views together (:func:`intersect_views`): a point's new views are kept when every one
    of them is used and the intersection holds (one wrong view would otherwise fail the
    point's intersection on the next frame and end its track), refused (NaN) otherwise.
    Returns the kept new views and their covariances, and the points intersected with them
    (N, 3) and their covariances (N, 3, 3), NaN for points without a kept new view."""
    n = len(uv)
    new = np.isfinite(new_uv[..., 0]) & ~np.isfinite(uv[..., 0])
    out_uv = np.where(new[..., None], new_uv, np.nan)
    out_cov = np.where(new[..., None, None], new_cov, np.nan)
    points = np.full((n, 3), np.nan)
    covariance = np.full((n, 3, 3), np.nan)
    rows = np.flatnonzero(new.any(axis=1))
    if rows.size == 0:
        return out_uv, out_cov, points, covariance
    both_uv = np.where(new[rows, :, None], new_uv[rows], uv[rows])
    both_cov = np.where(new[rows, :, None, None], new_cov[rows], cov[rows])
    x, xcov, used, _ = intersect_views(cameras, both_uv, both_cov, max_residual=max_residual, floor=floor)
    ok = np.isfinite(x).all(axis=1) & (used | ~new[rows]).all(axis=1)
    out_uv[rows[~ok]] = np.nan
    out_cov[rows[~ok]] = np.nan
    points[rows[ok]], covariance[rows[ok]] = x[ok], xcov[ok]
    return out_uv, out_cov, points, covariance
