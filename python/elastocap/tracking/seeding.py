"""Seeding (issue 15 item 2): points at a fixed density over the textured mask area of each
camera (one per ``spacing x spacing`` pixel cell, and at least one per mask region so that
thin limbs get points), where no tracked point already lies; each seed's depth found by
normalised cross-correlation along its ray inside the visual hull in a partner camera,
refined by least-squares matching on the epipolar line, then confirmed by spatial matching
into every other camera and forward intersection."""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap import _core
from elastocap.cameras import Camera
from elastocap.cameras.distortion import padded
from elastocap.stereo.matching import MatchStatus, checked_image, match_checked
from elastocap.tracking import settings
from elastocap.tracking.seed_check import rematch_depth
from elastocap.tracking.views import facing_normals, intersect_views, project_all, spatial_match

__all__ = ["CandidateMaps", "candidate_maps", "seed_candidates", "seed_points"]

# Depth samples along a seed's ray: enough that neighbouring samples project within about a
# pixel of each other in a partner camera across the hull's depth.
_DEPTHS = 96
# Local maxima within this many samples of the best belong to its peak; the best must beat
# every other local maximum by this much correlation.
_PEAK_WIDTH = 3
_UNIQUENESS = 0.1
_COARSE = 120


class CandidateMaps(NamedTuple):
    """The part of one camera's seed candidates that does not depend on the tracked points
    (:func:`candidate_maps`): computed for every camera at once, off the seed loop's thread.

    ``inner`` (H, W) bool: the mask eroded by the patch's reach and off the image's border;
    ``vs``, ``us`` (G, W') int: the cell centres' rows and columns (pixels); ``textured``
    (G, W') bool: which centres lie in ``inner`` with a texture of at least ``min_texture``;
    ``labels`` (H, W) int32: ``inner``'s 8-connected regions (0 outside it), ``regions`` of
    them with the background; ``distance`` (H, W) float32: ``inner``'s L2 distance
    transform (pixels), or None until a region needs it."""

    inner: NDArray[np.bool_]
    vs: NDArray[np.intp]
    us: NDArray[np.intp]
    textured: NDArray[np.bool_]
    regions: int
    labels: NDArray[np.int32]
    distance: NDArray[np.float32] | None


def candidate_maps(mask: NDArray[np.bool_], grey: NDArray[np.float32], *, spacing: int, size: int, min_texture: float,
                   margin: int | None = None, distance: bool = False) -> CandidateMaps:
    """:class:`CandidateMaps` of one camera's ``mask`` (H, W) and ``grey`` (H, W): the erosion,
    texture, regions (and with ``distance`` the distance transform) :func:`seed_candidates`
    reads. OpenCV's calls in it release the GIL, so :func:`seed_points` runs them in a
    thread beside its loop (benches/README.md, "seedpar1")."""
    h, w = mask.shape
    reach = size // 2 + 2 if margin is None else margin
    kernel = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    inner = cv2.erode(mask.astype(np.uint8), kernel) > 0
    inner[:reach], inner[-reach:], inner[:, :reach], inner[:, -reach:] = False, False, False, False
    texture = _texture(grey, inner, size)
    vs, us = np.mgrid[spacing // 2:h:spacing, spacing // 2:w:spacing]
    textured = inner[vs, us] & (texture[vs, us] >= min_texture)
    inner8 = inner.astype(np.uint8)
    count, labels = cv2.connectedComponents(inner8)
    return CandidateMaps(inner, vs, us, textured, int(count), np.asarray(labels, np.int32),
                         _distance(inner8) if distance else None)


def _distance(inner: NDArray[np.uint8]) -> NDArray[np.float32]:
    """(H, W) float32: each pixel's L2 distance (pixels, OpenCV's 3x3 approximation) to the
    nearest pixel outside ``inner`` (H, W; nonzero inside)."""
    return np.asarray(cv2.distanceTransform(inner, cv2.DIST_L2, 3), np.float32)


def seed_candidates(mask: NDArray[np.bool_], grey: NDArray[np.float32], covered: NDArray[np.float64], *,
                    spacing: int, size: int, min_texture: float, bare: int = 0,
                    margin: int | None = None, maps: CandidateMaps | None = None) -> NDArray[np.float64]:
    """(M, 2) seed pixels of one camera: cell centres inside the mask eroded by the patch,
    textured, in cells holding none of ``covered`` (K, 2); plus the most interior pixel of
    every mask region that got no seed.

    ``bare`` > 0 keeps only the cells with none of ``covered`` within ``bare`` cells (the
    areas the tracks left bare, such as a fast limb whose points were all lost, not the odd
    cell between tracked points): the cheap seeding of the frames between full seedings.
    ``maps``: :func:`candidate_maps` of ``mask`` and ``grey`` at the same ``spacing``,
    ``size``, ``min_texture`` and ``margin`` if already made."""
    if maps is None:
        maps = candidate_maps(mask, grey, spacing=spacing, size=size, min_texture=min_texture, margin=margin)
    h, w = mask.shape
    vs, us, labels = maps.vs, maps.us, maps.labels
    cells = np.zeros(((h + spacing - 1) // spacing, (w + spacing - 1) // spacing), bool)
    ok = np.isfinite(covered).all(axis=1)
    if ok.any():
        cu = np.clip((covered[ok, 0] // spacing).astype(int), 0, cells.shape[1] - 1)
        cv = np.clip((covered[ok, 1] // spacing).astype(int), 0, cells.shape[0] - 1)
        cells[cv, cu] = True
    if bare > 0:
        cells = cv2.dilate(cells.astype(np.uint8), np.ones((2 * bare + 1, 2 * bare + 1), np.uint8)) > 0
    pick = maps.textured & ~cells[vs // spacing, us // spacing]
    seeds = [np.column_stack([us[pick], vs[pick]]).astype(float)]
    have = np.zeros(maps.regions, bool)
    have[labels[vs[pick], us[pick]]] = True
    if ok.any():
        cu = np.clip(np.round(covered[ok, 0]).astype(int), 0, w - 1)
        cv = np.clip(np.round(covered[ok, 1]).astype(int), 0, h - 1)
        have[labels[cv, cu]] = True
    if (~have[1:]).any():
        distance = _distance(maps.inner.astype(np.uint8)) if maps.distance is None else maps.distance
        for region in np.flatnonzero(~have[1:]) + 1:
            where = np.flatnonzero((labels == region).ravel())
            best = where[np.argmax(distance.ravel()[where])]
            seeds.append(np.array([[best % w, best // w]], float))
    return np.concatenate(seeds)


def _texture(grey: NDArray[np.float32], inner: NDArray[np.bool_], size: int) -> NDArray[np.float32]:
    """(H, W) float32 texture (the square root of the smallest eigenvalue of the
    ``size x size`` structure tensor, grey levels per pixel) where ``inner`` (H, W) holds
    (and on the box around it); 0 outside the box.

    Computed on ``inner``'s bounding box widened by the window's reach (the box filter's
    half side and the 3x3 Sobel's pixel, with a margin): a subject's masks cover ~10% of
    an image, the whole image cost ~15 ms a camera, and the values inside the box equal the
    whole image's bit for bit (their windows see the same pixels; benches/README.md,
    "seedframe1")."""
    texture = np.zeros(grey.shape, np.float32)
    # The box from the rows and columns that hold any of ``inner`` (np.nonzero's extremes,
    # without its (N,) index arrays).
    vs, us = np.flatnonzero(inner.any(axis=1)), np.flatnonzero(inner.any(axis=0))
    if vs.size == 0:
        return texture
    pad = size + 4
    v0, v1 = max(0, int(vs[0]) - pad), min(grey.shape[0], int(vs[-1]) + pad + 1)
    u0, u1 = max(0, int(us[0]) - pad), min(grey.shape[1], int(us[-1]) + pad + 1)
    box = np.ascontiguousarray(grey[v0:v1, u0:u1])
    texture[v0:v1, u0:u1] = np.sqrt(np.maximum(cv2.cornerMinEigenVal(box, size, ksize=3), 0)) * 8  # Sobel scale -> grey/px
    return texture


def _partners(cameras: Sequence[Camera]) -> NDArray[np.int64]:
    """(C, C-1): the other cameras by angle between optical axes, nearest first."""
    axes = np.array([cam.R[2] for cam in cameras])
    cosine = axes @ axes.T
    np.fill_diagonal(cosine, -np.inf)
    return np.argsort(-cosine, axis=1)[:, :-1]


_Poses = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]


def _hull_cameras(cam: Camera, cameras: Sequence[Camera],
                  masks: Sequence[NDArray[np.bool_]]) -> tuple[_Poses, list[NDArray[np.bool_]], int]:
    """The other cameras' poses and lenses as the core's hull kernels take them (``r`` (C, 3,
    3), ``t`` (C, 3), ``k`` (C, 3, 3), ``dist`` (C, 12)), their masks (H, W) (checked
    against their images), and how many must see a point: half of them."""
    others = [(other, mask) for other, mask in zip(cameras, masks) if other is not cam]
    for other, mask in others:
        if mask.shape != (other.height, other.width):
            raise ValueError(f"a mask of shape {mask.shape} for a {other.width} x {other.height} camera")
    poses = (np.array([other.R for other, _ in others], dtype=float).reshape(-1, 3, 3),
             np.array([other.t for other, _ in others], dtype=float).reshape(-1, 3),
             np.array([other.K for other, _ in others], dtype=float).reshape(-1, 3, 3),
             np.array([padded(other.dist) for other, _ in others], dtype=float).reshape(-1, 12))
    return poses, [np.ascontiguousarray(mask, dtype=bool) for _, mask in others], max(2, (len(cameras) - 1) // 2)


def _inside_hull(flat: NDArray[np.float64], cam: Camera, cameras: Sequence[Camera],
                 masks: Sequence[NDArray[np.bool_]]) -> NDArray[np.bool_]:
    """(N,) bool: whether the world points ``flat`` (N, 3) are finite, lie inside every
    other camera's mask (H, W) where they project into its image, and are seen by at least
    half of them (the visual hull; space that few cameras see is not bounded by it: right in
    front of a camera of a ring, the cameras across see the space behind the subject and
    count it inside).

    In the core, one sample at a time through the cameras, stopping at the first mask that
    does not hold it: the rotation, the pixel (``_seen_pixels``' operations), the footprint
    test and the mask read at the rounded pixel, all of numpy's numbers to the bit
    (benches/README.md, "seednear1", "seedfast1"). The test :func:`_hull_depths` makes."""
    (r, t, k, dist), held, min_seen = _hull_cameras(cam, cameras, masks)
    inside: NDArray[np.bool_] = _core.seed_hull_inside(np.ascontiguousarray(flat, dtype=float), r, t, k, dist, held,
                                                       min_seen=min_seen)
    return inside


def _seen_pixels(camera: Camera, points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """``camera.project(points)`` (N, 3) finite world points -> pixels (N, 2), and whether
    each is seen (N,): in front (depth > 0) and inside the image's pixel footprints.

    In the core, with the hull test's arithmetic (``seed_pixels``; benches/README.md,
    "seedfast1"): the same floating-point operations as :meth:`Camera.project` (its pixels
    equal, bit for bit, wherever they are finite) without the lens terms whose coefficient is
    zero (each adds an exact zero to a finite value) and without its input checks; the seed
    loop projects every candidate's 96 depth samples into its partners."""
    uv, seen = _core.seed_pixels(np.ascontiguousarray(points, dtype=float), np.ascontiguousarray(camera.R, dtype=float),
                                 np.ascontiguousarray(camera.t, dtype=float), np.ascontiguousarray(camera.K, dtype=float),
                                 np.ascontiguousarray(padded(camera.dist), dtype=float), width=camera.width,
                                 height=camera.height)
    return uv, seen


def _line_pixels(camera: Camera, points: NDArray[np.float64], inside: NDArray[np.bool_],
                 rows: NDArray[np.int64]) -> NDArray[np.float64]:
    """(T, K, 2) pixels in ``camera`` of the ray samples ``points[rows]`` ((M, K, 3) world
    points; ``rows`` (T,)): :func:`_seen_pixels` of their ``np.nan_to_num``, and -1e6 (outside
    any image: no score) where a sample is not ``inside`` (M, K) the hull.

    In the core (``seed_line_pixels``), in parallel: numpy's gather, clean-up and masking
    around ``seed_pixels`` ran on one core while the other waited (benches/README.md,
    "seedpar1"); the numbers are the same to the bit."""
    uv: NDArray[np.float64] = _core.seed_line_pixels(
        np.ascontiguousarray(points, dtype=float), np.ascontiguousarray(inside, dtype=bool),
        np.ascontiguousarray(rows, dtype=np.int64), np.ascontiguousarray(camera.R, dtype=float),
        np.ascontiguousarray(camera.t, dtype=float), np.ascontiguousarray(camera.K, dtype=float),
        np.ascontiguousarray(padded(camera.dist), dtype=float), width=camera.width, height=camera.height)
    return uv


def _hull_depths(cam: Camera, seeds: NDArray[np.float64], cameras: Sequence[Camera],
                 masks: Sequence[NDArray[np.bool_]]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Ray samples (M, K, 3) from ``cam`` through ``seeds`` (M, 2) over the ray's first run
    inside the visual hull (where the front surface lies): found on a coarse grid across the
    rig's depth range, then sampled finely; and which of them lie inside the hull (M, K;
    none where the ray never enters it).

    In the core (``seed_hull_depths``, the test of :func:`_inside_hull`), ray by ray: it
    tests the coarse grid only until the first run ends and a ray that misses the hull gets
    no fine test; the samples and answers are those of the numpy search it replaced
    (benches/README.md, "seedfast1")."""
    origins, dirs = cam.rays(seeds)
    dirs = np.nan_to_num(dirs)
    centres = np.array([c.center for c in cameras])
    reach = np.linalg.norm(centres - cam.center, axis=1).max()
    coarse = np.linspace(0.05 * reach, 1.2 * reach, _COARSE)
    (r, t, k, dist), held, min_seen = _hull_cameras(cam, cameras, masks)
    fine, inside = _core.seed_hull_depths(np.ascontiguousarray(origins, dtype=float), np.ascontiguousarray(dirs, dtype=float),
                                          coarse, np.linspace(0, 1, _DEPTHS), float(coarse[1] - coarse[0]), r, t, k, dist,
                                          held, min_seen=min_seen)
    return fine, inside


def _unique_peaks(scores: NDArray[np.float64], uv: NDArray[np.float64],
                  min_correlation: float) -> tuple[NDArray[np.bool_], NDArray[np.int64]]:
    """Seeding's test on the correlation along each candidate's line: whether it holds (M,)
    and the best sample (M,), from the scores (M, K; NaN or -inf where none) at the
    samples' pixels ``uv`` (M, K, 2) in the partner. Holds where the best score reaches
    ``min_correlation`` and beats every local maximum away from it by ``_UNIQUENESS``;
    the scores ``track_ncc_at(decide=...)`` leaves at -inf cannot change either answer.

    A repeated texture along the line makes a false match as likely as the true one: the
    best peak must stand out from every local maximum away from it (more than
    ``_PEAK_WIDTH`` samples, or ``settings.SEED_PEAK_PIXELS`` pixels in the partner's image:
    the samples' spacing there varies from ~0.1 px (a short baseline) to a few pixels). The
    peaks are found in the core, in parallel (benches/README.md, "seedpar1")."""
    best, peak, second = _core.seed_line_peaks(np.ascontiguousarray(scores, dtype=float), width=_PEAK_WIDTH,
                                               uv=uv if settings.SEED_PEAK_PIXELS is not None else None,
                                               pixels=settings.SEED_PEAK_PIXELS)
    # A point with no score anywhere has peak = second = -inf (NaN margin, not good).
    with np.errstate(invalid="ignore"):
        good = (peak >= min_correlation) & (peak - second >= _UNIQUENESS)
    return good, best


def seed_points(images: Sequence[NDArray[np.float32]], masks: Sequence[NDArray[np.bool_]], cameras: Sequence[Camera],
                covered: NDArray[np.float64], *, spacing: int, size: int, min_correlation: float, min_views: int,
                min_texture: float, tolerance: float, max_residual: float, floor: float,
                bare: int = 0, margin: int | None = None) -> NDArray[np.float64]:
    """New points: their views (M, C, 2; NaN where not matched; at least ``min_views``).

    ``covered`` (N, C, 2) holds the tracked points' views; seeds go where no point lies, one
    camera after the other (so a point seeded from one camera covers its cells in the
    others); with ``bare`` > 0 only where none lies within ``bare`` cells
    (:func:`seed_candidates`).

    The cameras' :func:`candidate_maps` (which do not depend on the points) are made in a
    thread beside the loop, in camera order: on two cores the loop's own numpy and Python
    work leaves one idle, and OpenCV's calls release the GIL (benches/README.md,
    "seedpar1"). The loop takes them in order, so the seeds are those of one thread."""
    c = len(cameras)
    partners = _partners(cameras)
    views: list[NDArray[np.float64]] = []
    cover = [covered[:, k] for k in range(c)]
    def maps_of(k: int, distance: bool) -> CandidateMaps:
        return candidate_maps(masks[k], images[k], spacing=spacing, size=size, min_texture=min_texture, margin=margin,
                              distance=distance)

    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="seed_maps")
    try:
        # The images checked for the matches once (not in each of the 2 x C calls), then
        # camera 0's maps on this thread (nothing to overlap them with yet) and the others'
        # in the pool, with the distance transform a region left without seeds needs.
        checks = [pool.submit(checked_image, image) for image in images]
        later = [pool.submit(maps_of, k, True) for k in range(1, c)]
        checked: list[NDArray[np.float32]] = []
        for k in range(c):
            maps = later[k - 1].result() if k else maps_of(k, False)
            if k == 0:
                checked = [check.result() for check in checks]
            seeds = seed_candidates(masks[k], images[k], cover[k], spacing=spacing, size=size, min_texture=min_texture,
                                    bare=bare, margin=margin, maps=maps)
            if len(seeds) == 0:
                continue
            new = _camera_seeds(images, checked, masks, cameras, k, seeds, partners[k][:2], size=size,
                                min_correlation=min_correlation, min_views=min_views, min_texture=min_texture,
                                tolerance=tolerance, max_residual=max_residual, floor=floor)
            if new is None:
                continue
            views.append(new)
            for j in range(c):
                cover[j] = np.concatenate([cover[j], new[:, j]])
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    return np.concatenate(views) if views else np.zeros((0, c, 2))


def _camera_seeds(images: Sequence[NDArray[np.float32]], checked: Sequence[NDArray[np.float32]],
                  masks: Sequence[NDArray[np.bool_]], cameras: Sequence[Camera], k: int, seeds: NDArray[np.float64],
                  partners: NDArray[np.int64], *, size: int, min_correlation: float, min_views: int, min_texture: float,
                  tolerance: float, max_residual: float, floor: float) -> NDArray[np.float64] | None:
    """The new points of camera ``k``'s ``seeds`` (S, 2 pixels): their views (M, C, 2; NaN
    where not matched), or None where no seed found a partner. Each seed's depth along its
    ray inside the hull by NCC and then least squares in the ``partners`` (up to 2 camera
    indices, nearest first; the second only for the seeds the first did not match),
    confirmed by spatial matching into the other cameras (:func:`seed_points`' steps).
    ``checked``: ``images`` as :func:`checked_image` returns them."""
    c = len(cameras)
    cam = cameras[k]
    points, hull = _hull_depths(cam, seeds, cameras, masks)
    found = np.full((len(seeds), 2), np.nan)
    partner_of = np.full(len(seeds), -1)
    for p in partners:
        todo = np.flatnonzero(np.isnan(found[:, 0]) & hull.any(axis=1))
        if todo.size == 0:
            break
        other = cameras[p]
        uv = _line_pixels(other, points, hull, todo)
        # Only the scores that can decide the test are exact (the others -inf: a row whose
        # best is below min_correlation keeps nothing, and a score below the best minus
        # _UNIQUENESS is neither the peak nor a rival that refuses it, and leaves its
        # neighbours' local maxima as they are); benches/README.md, "seedfloor1".
        scores = _core.track_ncc_at(images[k], seeds[todo], images[p], np.ascontiguousarray(uv), size=size,
                                    decide=(min_correlation, _UNIQUENESS))
        good, best = _unique_peaks(scores, uv, min_correlation)
        rows, best = todo[good], best[good]
        if rows.size == 0:
            continue
        lo = np.clip(best - 1, 0, _DEPTHS - 1)
        hi = np.clip(best + 1, 0, _DEPTHS - 1)
        a, _ = other.project(points[rows, lo])
        b, _ = other.project(points[rows, hi])
        line = np.column_stack([a[:, 1] - b[:, 1], b[:, 0] - a[:, 0], a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]])
        m = match_checked(checked[k], seeds[rows], [checked[p]], initial=uv[good, best][:, None, :],
                          epipolar=line[:, None, :], size=size, min_texture=min_texture, max_iterations=20)
        ok = (m.status[:, 0] == MatchStatus.CONVERGED) & (m.correlation[:, 0] >= min_correlation)
        found[rows[ok]] = m.positions[ok, 0]
        partner_of[rows[ok]] = p
    rows = np.flatnonzero(partner_of >= 0)
    if rows.size == 0:
        return None
    uv = np.full((rows.size, c, 2), np.nan)
    uv[:, k] = seeds[rows]
    uv[np.arange(rows.size), partner_of[rows]] = found[rows]
    cov = np.where(np.isfinite(uv)[..., None], np.eye(2) * 0.01, np.nan)
    x, _, pair, _ = intersect_views(cameras, uv, cov, max_residual=max_residual, floor=floor)
    # Confirm in every other camera by spatial matching from the seed camera.
    targets = project_all(cameras, x, margin=size)
    targets[:, k] = np.nan
    matched, mcov = spatial_match(images, np.full(rows.size, k), seeds[rows], targets, size=size,
                                  min_correlation=min_correlation, tolerance=tolerance, min_texture=min_texture,
                                  cameras=cameras, points=x, normals=facing_normals(cameras, x, pair))
    matched[:, k] = seeds[rows]
    mcov[:, k] = np.eye(2) * 1e-4
    x, _, used, _ = intersect_views(cameras, matched, mcov, max_residual=max_residual, floor=floor)
    keep = used.sum(axis=1) >= min_views
    new = np.where(used[keep][..., None], matched[keep], np.nan)
    if settings.SEED_DEPTH_SIZE:
        # The partner's depth with a small window (seed_check: a large one lies behind a limb).
        new = rematch_depth(images, cameras, k, new, size=settings.SEED_DEPTH_SIZE,
                            min_correlation=min_correlation, min_texture=min_texture)
    return new
