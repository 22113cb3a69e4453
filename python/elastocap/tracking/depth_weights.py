"""The frame-to-frame match's template weights cut at depth edges (issue 15).

A point on a fast limb is lost on its first steps mostly because its patch straddles the
limb's edge onto the surface behind it (the torso, the other limb), which moves otherwise:
both lie inside the silhouette, so the mask weights keep them (benches/README.md, branch
track13: of the lost views with another part's visible point within 8 px, 17% are found
even from the true motion, against 42% of the others). The tracked points say where those
edges are: each camera's pixels take the depth of the nearest point whose view it held on
the previous frame (a Voronoi labelling of the views, :func:`depth_images`), and a view
whose template holds pixels more than a tolerance nearer or farther than its own point is
matched with those pixels weighed zero. The Rust step takes one weight image per camera,
not one per point, so such views are grouped by their depth (bins of ``width``) and each
group is matched with its own weight images (:func:`track_step_by_depth`); views with no
depth edge in their patch are matched as before, in one call."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from scipy.spatial import cKDTree

from elastocap import _core
from elastocap.cameras import Camera

__all__ = ["DepthEdges", "depth_edges", "depth_images", "edge_band", "rust_step", "straddling", "track_step_by_depth"]

StepResult = tuple[NDArray[np.float64], NDArray[np.uint8], NDArray[np.float64], NDArray[np.float64]]


def rust_step(previous: list[NDArray[np.float32]], current: list[NDArray[np.float32]]) -> Callable[..., StepResult]:
    """The Rust step (:func:`elastocap._core.track_step`) between two frames' images in the
    tracker's layout: ``step(last, before, *, weights, **options)`` with ``last``, ``before``
    (N, C, 2) returns positions (N, C, 2), flags (N, C), covariances (N, C, 2, 2) and
    correlations (N, C)."""

    def step(last: NDArray[np.float64], before: NDArray[np.float64], *, weights: Any, **options: Any) -> StepResult:
        pos, f2d, cv2d, cr = _core.track_step(previous, current, np.ascontiguousarray(last.transpose(1, 0, 2)),
                                              np.ascontiguousarray(before.transpose(1, 0, 2)), weights=weights, **options)
        return pos.transpose(1, 0, 2), f2d.T.copy(), cv2d.transpose(1, 0, 2, 3), cr.T

    return step


def _occluded(uv: NDArray[np.float64], z: NDArray[np.float64], radius: float, tolerance: float) -> NDArray[np.bool_]:
    """(M,) views ``uv`` (M, 2) with another view within ``radius`` pixels nearer to the
    camera (depth ``z`` (M,)) by more than ``tolerance``: a surface passing behind another."""
    if len(uv) < 2 or radius <= 0:
        return np.zeros(len(uv), bool)
    k = min(9, len(uv))
    distance, near = cKDTree(uv).query(uv, k=k, distance_upper_bound=radius)
    found = np.isfinite(distance)
    zn = np.where(found, z[np.minimum(near, len(uv) - 1)], np.inf)
    return np.any(zn < z[:, None] - tolerance, axis=1)


def depth_images(cameras: Sequence[Camera], uv: NDArray[np.float64], x: NDArray[np.float64],
                 masks: Sequence[NDArray[np.bool_]], reach: float,
                 occlusion: tuple[float, NDArray[np.float64]] | None = None) -> list[NDArray[np.float32]]:
    """Per camera an (H, W) image of depths: each pixel inside its mask takes the depth
    (world units along the camera's axis) of the point ``x`` (N, 3) whose view ``uv``
    (N, C, 2; NaN where the camera holds none) is nearest, within ``reach`` pixels; NaN
    elsewhere (no view near: nothing is known there). With ``occlusion`` (radius, pixels;
    tolerance (C,), world units) views with a nearer one within the radius are left out
    (views moved on by a prediction: the surface they lie on has passed behind another)."""
    out = []
    for k, (cam, mask) in enumerate(zip(cameras, masks)):
        h, w = mask.shape
        depth = np.full((h, w), np.nan, np.float32)
        held = np.isfinite(uv[:, k]).all(axis=1) & np.isfinite(x).all(axis=1)
        pix = np.rint(uv[held, k]).astype(np.int64)
        inside = (pix[:, 0] >= 0) & (pix[:, 0] < w) & (pix[:, 1] >= 0) & (pix[:, 1] < h)
        z = cam.to_camera(x[held][inside])[:, 2] if inside.any() else np.zeros(0)
        if occlusion is not None and inside.any() and np.isfinite(occlusion[1][k]):
            seen = ~_occluded(uv[held, k][inside], z, occlusion[0], float(occlusion[1][k]))
            inside[np.flatnonzero(inside)[~seen]] = False
            z = z[seen]
        if inside.any():
            pix = pix[inside]
            seeds = np.full((h, w), 255, np.uint8)
            seeds[pix[:, 1], pix[:, 0]] = 0
            # Nearest seed pixel by label (each zero pixel its own label, scan order).
            dist, labels = cv2.distanceTransformWithLabels(seeds, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
            lut = np.full(int(labels.max()) + 1, np.nan, np.float32)
            lut[labels[pix[:, 1], pix[:, 0]]] = z
            depth = lut[labels]
            depth[(dist > reach) | ~mask] = np.nan
        out.append(depth)
    return out


def _patch_values(image: NDArray[np.float32], centres: NDArray[np.float64], half: int) -> NDArray[np.float32]:
    """(M, (2 half + 1)^2) values of ``image`` around the rounded ``centres`` (M, 2), NaN
    outside the image."""
    h, w = image.shape
    off = np.arange(-half, half + 1)
    du, dv = np.meshgrid(off, off)
    c = np.rint(centres).astype(np.int64)
    u = c[:, 0, None] + du.ravel()[None]
    v = c[:, 1, None] + dv.ravel()[None]
    ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    vals = np.full(u.shape, np.nan, np.float32)
    vals[ok] = image[v[ok], u[ok]]
    return vals


def straddling(depth: NDArray[np.float32], uv: NDArray[np.float64], z: NDArray[np.float64], half: int,
               tolerance: float) -> NDArray[np.bool_]:
    """(M,) whether the template of half-side ``half`` pixels around each view ``uv`` (M, 2)
    holds a pixel of ``depth`` farther than ``tolerance`` from the view's own depth ``z``
    (M,); False where ``uv`` or ``z`` is NaN."""
    ok = np.isfinite(uv).all(axis=1) & np.isfinite(z)
    out = np.zeros(len(uv), bool)
    if ok.any():
        vals = _patch_values(depth, uv[ok], half)
        with np.errstate(invalid="ignore"):
            out[ok] = (np.abs(vals - z[ok, None]) > tolerance).any(axis=1)
    return out


def edge_band(depth: NDArray[np.float32], tolerance: float, band: int) -> NDArray[np.bool_]:
    """(H, W) the pixels within ``band`` pixels of a depth edge of ``depth`` (two
    neighbouring pixels, both known, differing by more than ``tolerance``): the labelling
    puts the edge half-way between two views, so where the surfaces really part is known
    only to within the views' spacing (``band`` 0: no pixel)."""
    edge = np.zeros(depth.shape, bool)
    if band <= 0:
        return edge
    with np.errstate(invalid="ignore"):
        across = np.abs(np.diff(depth, axis=1)) > tolerance
        down = np.abs(np.diff(depth, axis=0)) > tolerance
    edge[:, :-1] |= across
    edge[:, 1:] |= across
    edge[:-1] |= down
    edge[1:] |= down
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band - 1, 2 * band - 1))
    return cv2.dilate(edge.astype(np.uint8), kernel) > 0


class DepthEdges:
    """One frame pair's depth images and its views' depths: ``previous`` and ``current``
    (C lists of (H, W) float32, see :func:`depth_images`), ``z`` (N, C) each point's depth
    in each camera on the previous frame (NaN where the camera held no view of it),
    ``tolerance`` (C,) the depth difference, world units, beyond which a pixel is another
    surface, and ``band_previous``, ``band_current`` (C lists of (H, W) bool, or None) the
    pixels near a depth edge (:func:`edge_band`), weighed zero for every view near one."""

    def __init__(self, previous: list[NDArray[np.float32]], current: list[NDArray[np.float32]] | None, z: NDArray[np.float64],
                 tolerance: NDArray[np.float64], band_previous: list[NDArray[np.bool_]] | None = None,
                 band_current: list[NDArray[np.bool_]] | None = None) -> None:
        self.previous, self.current, self.z, self.tolerance = previous, current, z, tolerance
        self.band_previous, self.band_current = band_previous, band_current


def depth_edges(cameras: Sequence[Camera], uv: NDArray[np.float64], x_last: NDArray[np.float64],
                x_before: NDArray[np.float64], masks_previous: Sequence[NDArray[np.bool_]],
                masks_current: Sequence[NDArray[np.bool_]], *, reach: float, tolerance: float,
                band: int = 0, current: bool = True) -> DepthEdges:
    """The depth edges of a frame step from the views ``uv`` (N, C, 2) held on the previous
    frame and their points ``x_last`` (N, 3): the previous frame's depth images from them,
    the current frame's from the points moved on linearly (``2 x_last - x_before``, or
    ``x_last`` without a ``x_before``) and projected, the same views held. ``tolerance`` is
    in pixel equivalents (times the median footprint of a pixel at the camera's held points);
    ``band`` the half-width, pixels, of the band along the edges weighed zero (0: none);
    ``current`` False: no current frame's images (the forward-backward check weighed by
    the masks alone)."""
    n, c = uv.shape[:2]
    moved = np.where(np.isfinite(x_before).all(axis=1, keepdims=True), 2 * x_last - x_before, x_last)
    held = np.all(np.isfinite(uv), axis=2) & np.all(np.isfinite(x_last), axis=1)[:, None]
    z = np.full((n, c), np.nan)
    tol = np.full(c, np.nan)
    ahead = np.full_like(uv, np.nan)
    for k, cam in enumerate(cameras):
        rows = np.flatnonzero(held[:, k])
        if rows.size:
            z[rows, k] = cam.to_camera(x_last[rows])[:, 2]
            tol[k] = tolerance * float(np.median(z[rows, k])) / cam.K[0, 0]
            ahead[rows, k] = cam.project(moved[rows])[0]
    previous = depth_images(cameras, uv, x_last, masks_previous, reach)
    now = depth_images(cameras, ahead, moved, masks_current, reach, occlusion=(0.5 * reach, tol)) if current else None
    if band <= 0:
        return DepthEdges(previous, now, z, tol)
    t = np.nan_to_num(tol, nan=np.inf)
    return DepthEdges(previous, now, z, tol, [edge_band(d, t[k], band) for k, d in enumerate(previous)],
                      None if now is None else [edge_band(d, t[k], band) for k, d in enumerate(now)])


def track_step_by_depth(step: Callable[..., StepResult], last: NDArray[np.float64], before: NDArray[np.float64],
                        weights: tuple[list[NDArray[np.float32]], list[NDArray[np.float32]]] | None,
                        edges: DepthEdges, *, half: int, width: float, **options: Any) -> StepResult:
    """``step(last, before, weights=..., **options)`` (the Rust step in the (N, C) layout:
    :func:`elastocap._core.track_step` transposed) with the views whose template straddles
    a depth edge (:func:`straddling` on the previous frame's depth image, half-side ``half``)
    matched apart, grouped by their own depth in bins of ``width`` times the camera's
    tolerance, each group with its weights (``weights``, or ones) times 0 where the depth
    images differ from the bin's centre by more than the tolerance plus half a bin (the
    previous frame's for the template, the current frame's for the forward-backward check).
    The others are matched in one call with ``weights`` as given. Returns the step's
    (positions (N, C, 2), flags (N, C), covariances (N, C, 2, 2), correlations (N, C))."""
    n, c = last.shape[:2]
    apart = np.zeros((n, c), bool)
    for k in range(c):
        if np.isfinite(edges.tolerance[k]):
            depth = edges.previous[k]
            if edges.band_previous is not None:
                # A band pixel counts as another surface (infinitely far).
                depth = np.where(edges.band_previous[k], np.inf, depth).astype(np.float32)
            apart[:, k] = straddling(depth, last[:, k], edges.z[:, k], half, edges.tolerance[k])
    plain = np.where(apart[..., None], np.nan, last)
    pos, flags, cov, corr = step(plain, before, weights=weights, **options)
    pos, flags, cov, corr = pos.copy(), flags.copy(), cov.copy(), corr.copy()
    if not apart.any():
        return pos, flags, cov, corr
    step_k = width * edges.tolerance
    bins = np.where(apart, np.floor(edges.z / np.where(np.isfinite(step_k), step_k, 1.0)[None]), np.nan)
    per_camera = [np.unique(bins[apart[:, k], k]) for k in range(c)]
    rounds = max(len(b) for b in per_camera)
    shape = [d.shape for d in edges.previous]
    ahead = np.where(np.isfinite(before), 2 * last - before, last)
    # Only the pixels a group's matches can read are cut (the rest of each image keeps
    # ``weights``): the box around the views and their predictions, widened by the
    # template's half-side and the search box.
    margin = half + int(options.get("radius", 0)) + 2
    for r in range(rounds):
        rows = np.zeros((n, c), bool)
        wp, wc = [], []
        for k in range(c):
            base_p = weights[0][k] if weights is not None else np.ones(shape[k], np.float32)
            base_c = weights[1][k] if weights is not None else np.ones(shape[k], np.float32)
            if r >= len(per_camera[k]):
                wp.append(base_p)
                wc.append(base_c)
                continue
            b = per_camera[k][r]
            rows[:, k] = apart[:, k] & (bins[:, k] == b)
            centre = (b + 0.5) * step_k[k]
            reach = edges.tolerance[k] + 0.5 * step_k[k]
            at = np.concatenate([last[rows[:, k], k], ahead[rows[:, k], k]])
            at = at[np.isfinite(at).all(axis=1)]
            h, w = shape[k]
            x0, y0 = np.clip(np.floor(at.min(axis=0)).astype(int) - margin, 0, [w, h])
            x1, y1 = np.clip(np.ceil(at.max(axis=0)).astype(int) + margin + 1, 0, [w, h])
            box = (slice(y0, y1), slice(x0, x1))
            with np.errstate(invalid="ignore"):
                # NaN depths (no view near) are kept: nothing says they are another surface.
                keep_p = ~(np.abs(edges.previous[k][box] - centre) > reach)
                keep_c = ~(np.abs(edges.current[k][box] - centre) > reach) if edges.current is not None else None
            if edges.band_previous is not None:
                keep_p &= ~edges.band_previous[k][box]
            if edges.band_current is not None and keep_c is not None:
                keep_c &= ~edges.band_current[k][box]
            cut_p = np.array(base_p, dtype=np.float32, copy=True)
            cut_p[box] *= keep_p
            wp.append(cut_p)
            if keep_c is None:
                wc.append(base_c)
            else:
                cut_c = np.array(base_c, dtype=np.float32, copy=True)
                cut_c[box] *= keep_c
                wc.append(cut_c)
        these = np.where(rows[..., None], last, np.nan)
        p, f, cv, cr = step(these, before, weights=(wp, wc), **options)
        pos[rows], flags[rows], cov[rows], corr[rows] = p[rows], f[rows], cv[rows], cr[rows]
    return pos, flags, cov, corr
