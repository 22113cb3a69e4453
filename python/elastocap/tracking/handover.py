"""Hand-over of a tracked point to another stereo pair while its own pair still holds it
(issue 15, branch track10).

Most points are held by one narrow stereo pair. When the limb turns, that pair loses the
point while another pair sees it (on the textured capture 80-90 degrees away); the
re-acquisition's cross-camera match from the held patch into those cameras fails on
nearly every try (the patch foreshortens and turns across the wide baseline;
benches/README.md, branches track5, track6 and track10), so the point ends although two cameras see it: on the
textured capture (seed 0) 132 of the 287 first losses of the points without a visibility
gap. The hand-over never matches across the wide baseline: the point's position is
projected into a camera of the other pair that is predicted to see it, the patch there is
taken as the new view, and it is matched into that camera's partner across their narrow
baseline, as seeding matches. Both new views are kept when they intersect with the held
ones within the residual threshold (:func:`elastocap.tracking.views.confirm_views`), so
the point then has four views and survives its first pair's loss under its id. The
held pair's depth is off by a pixel equivalent or more (a narrow baseline), which the new
cameras, far from the held pair's direction, see as an image error; so the new views are
looked for where the ray of the first held view meets the surface the other pair sees (a
few iterations of match, intersect, move along the ray), and only for points whose pair is losing them (a
held view's surface turned below ``settings.HANDOVER_WHEN``).

Measured on the textured capture (benches/README.md, branch track10): seed 0 through
32.8 -> 34.3%, kept 3-D beyond 5 px-eq 3.31 -> 2.86%, but the median RMS image error
0.360 -> 0.385 px and through with RMS <= 0.5 px 16.9 -> 15.3%; held out (seeds 2, 3)
through +1.1 / +1.7 points, kept 3-D -0.85 / +0.23 points. Off by default
(``settings.HANDOVER``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from elastocap.tracking import settings
from elastocap.tracking.seeding import _partners
from elastocap.tracking.views import confirm_views, intersect_views, project_all, spatial_match
from elastocap.tracking.visibility import predicted_visible

if TYPE_CHECKING:
    from elastocap.tracking.step import FrameTracker

__all__ = ["handover_pairs", "hand_over"]


def handover_pairs(held: NDArray[np.bool_], visible: NDArray[np.bool_], partner: NDArray[np.int64],
                   facing: NDArray[np.float64]) -> NDArray[np.int64]:
    """(N, C) per point and camera ``k``: the camera its patch is taken in (``k`` or its
    ``partner[k]``, whichever faces the point more by ``facing`` (N, C), the cosine between
    the normal and the direction to the camera), -1 where the pair of ``k`` and its partner
    is not a candidate: both must be ``visible`` (N, C) and neither ``held`` (N, C). Each
    pair is listed once, at the camera the patch is taken in."""
    c = held.shape[1]
    out = np.full(held.shape, -1, np.int64)
    free = visible & ~held
    for k in range(c):
        p = int(partner[k])
        both = free[:, k] & free[:, p]
        # The template camera is the one facing the point more (ties: the lower index).
        mine = both & ((facing[:, k] > facing[:, p]) | ((facing[:, k] == facing[:, p]) & (k < p)))
        out[mine, k] = k
    return out


def hand_over(tracker: FrameTracker, grey: list[NDArray[np.float32]], masks: list[NDArray[np.bool_]],
              weights: list[NDArray[np.float32]] | None, uv: NDArray[np.float64], cov2d: NDArray[np.float64],
              x: NDArray[np.float64], xcov: NDArray[np.float64], tracked: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """New views of the points ``tracked`` at ``x`` (N, 3) in the other stereo pairs that
    are predicted to see them: updates ``uv``, ``cov2d``, ``x`` and ``xcov`` in place and
    returns the views added (N, C)."""
    n, c = uv.shape[:2]
    added = np.zeros((n, c), bool)
    held = np.isfinite(uv[..., 0])
    rows = np.flatnonzero(tracked & np.isfinite(x).all(axis=1) & (held.sum(axis=1) >= 2) & (held.sum(axis=1) < c))
    if rows.size == 0 or c < 3:
        return added
    cameras = tracker.cameras
    proj = project_all(cameras, x[rows], margin=tracker.size)
    asked = np.isfinite(proj[..., 0]) & ~held[rows]
    for k in range(c):
        iu = np.clip(np.round(np.nan_to_num(proj[:, k, 0])).astype(int), 0, masks[k].shape[1] - 1)
        iv = np.clip(np.round(np.nan_to_num(proj[:, k, 1])).astype(int), 0, masks[k].shape[0] - 1)
        asked[:, k] &= masks[k][iv, iu]
    if not asked.any():
        return added
    normals = tracker.normals(x[rows], x, held[rows])
    visible = predicted_visible(cameras, masks, x[rows], normals, x, asked, facing=settings.HANDOVER_FACING)
    facing = np.zeros((rows.size, c))
    for k, cam in enumerate(cameras):
        d = cam.center - x[rows]
        facing[:, k] = np.einsum("ij,ij->i", d / np.linalg.norm(d, axis=1, keepdims=True), normals)
    partner = _partners(cameras)[:, 0]
    # Only points whose own pair is losing them (a held view's surface turning away): a
    # hand-over shows the held pair's depth error in the new cameras as an image error.
    losing = np.where(held[rows], facing, np.inf).min(axis=1) < settings.HANDOVER_WHEN
    template = handover_pairs(held[rows], visible & losing[:, None], partner, facing)
    new_uv = np.full((rows.size, c, 2), np.nan)
    new_cov = np.full((rows.size, c, 2, 2), np.nan)
    # The held pair's image positions are right to a few tenths of a pixel but its depth
    # is not (a narrow baseline): the point is looked for along the ray of its first held
    # view, where that ray meets the surface the other pair sees.
    first = np.argmax(held[rows], axis=1)
    origin = np.zeros((rows.size, 3))
    direction = np.zeros((rows.size, 3))
    for r in range(c):
        sel = np.flatnonzero(first == r)
        if sel.size:
            origin[sel], direction[sel] = cameras[r].rays(uv[rows[sel], r])
    for k in range(c):
        sub = np.flatnonzero(template[:, k] == k)
        if sub.size == 0:
            continue
        p = int(partner[k])
        point = x[rows[sub]].copy()
        start = point.copy()
        o, d, nrm = origin[sub], direction[sub], normals[sub]
        alive = np.ones(sub.size, bool)
        pair_uv = np.full((sub.size, c, 2), np.nan)
        pair_cov = np.full((sub.size, c, 2, 2), np.nan)
        for _ in range(settings.HANDOVER_ITERATIONS):
            at_k = cameras[k].project(point)[0]
            targets = np.full((sub.size, c, 2), np.nan)
            targets[alive, p] = cameras[p].project(point[alive])[0]
            matched, mcov = spatial_match(grey, np.full(sub.size, k), at_k, targets, size=tracker.size,
                                          min_correlation=tracker.min_correlation, tolerance=settings.HANDOVER_TOLERANCE,
                                          min_texture=float(min(tracker.texture)), cameras=cameras, points=point,
                                          normals=nrm, weights=weights)
            alive &= np.isfinite(matched[:, p, 0])
            pair_uv[:] = np.nan
            pair_uv[:, k], pair_uv[:, p] = at_k, matched[:, p]
            pair_cov[:, k], pair_cov[:, p] = mcov[:, p], mcov[:, p]
            surface, _, _, _ = intersect_views(cameras, np.where(alive[:, None, None], pair_uv, np.nan), pair_cov,
                                               max_residual=tracker.o["max_residual"], floor=settings.FLOOR)
            alive &= np.isfinite(surface).all(axis=1)
            with np.errstate(invalid="ignore", divide="ignore"):
                cosine = np.einsum("ij,ij->i", d, nrm)
                t = np.einsum("ij,ij->i", surface - o, nrm) / cosine
            alive &= np.abs(cosine) > 0.2
            point = np.where(alive[:, None], o + t[:, None] * d, point)
        # The ray's move from the held position: the held pair's depth error, which a
        # point on another surface (an arm in front, seen by the other pair) exceeds.
        pixel = cameras[k].to_camera(start)[:, 2] / float(cameras[k].K[0, 0])
        alive &= np.linalg.norm(point - start, axis=1) <= settings.HANDOVER_REACH * pixel
        # A point with two free pairs keeps the first that matched.
        alive &= ~np.isfinite(new_uv[sub, :, 0]).any(axis=1)
        got = sub[alive]
        new_uv[got, k], new_uv[got, p] = pair_uv[alive, k], pair_uv[alive, p]
        new_cov[got, k], new_cov[got, p] = pair_cov[alive, k], pair_cov[alive, p]
    found = np.flatnonzero(np.isfinite(new_uv[..., 0]).any(axis=1))
    if found.size == 0:
        return added
    pts = rows[found]
    kept_uv, kept_cov, cx, ccov = confirm_views(cameras, uv[pts], cov2d[pts], new_uv[found], new_cov[found],
                                                max_residual=tracker.o["max_residual"], floor=settings.FLOOR)
    ok = np.isfinite(cx).all(axis=1)
    pts, kept_uv, kept_cov, cx, ccov = pts[ok], kept_uv[ok], kept_cov[ok], cx[ok], ccov[ok]
    new = np.isfinite(kept_uv[..., 0])
    uv[pts] = np.where(new[..., None], kept_uv, uv[pts])
    cov2d[pts] = np.where(new[..., None, None], kept_cov, cov2d[pts])
    x[pts], xcov[pts] = cx, ccov
    added[pts] = new
    return added
