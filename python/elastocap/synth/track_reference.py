"""The true surface point of each track on the textured synthetic capture: the reference that
:func:`elastocap.tracking.accuracy.track_accuracy` measures tracks against (``reference=``).

A track is seeded on a pixel of one camera (:func:`elastocap.tracking.seeding.seed_candidates`
puts seeds on pixel centres; the other views are sub-pixel matches). That pixel, back-projected
with the camera's ground-truth depth at the seeding frame, is the surface point whose texture
the track follows; it is carried through the sequence by its body part's rigid motion, as the
truth's own surface points are (:func:`~elastocap.synth.textured_render.material_points`), so
the reference is exact wherever the truth is. The tracker's own seeded position (its
triangulation, a median 1 px-equivalent off the surface) plays no part in it.

Seeds whose depth cannot be read (the neighbourhood straddles the silhouette or a depth
jump, an occluding limb's edge) or whose point leaves its texture (the blend of two parts
at a joint slides the surface under it) get no reference and are counted by reason.
"""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.synth.textured import TexturedTruth
from elastocap.synth.textured_render import material_mask, material_points
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.tracks import Tracks

__all__ = ["DEPTH_JUMP", "NoReference", "SurfaceReference", "surface_reference"]

# Largest second difference of the depth (pixel equivalents per pixel squared) within the
# 4 x 4 pixels around a seed for its depth to be read as one surface. A limb's curvature
# gives z/(f r cos^3) (0.06 at its middle for r = 5 cm at 3 m, 2.2 at a cosine of 0.3 to
# the camera), an occluding edge tens: seeds lie 9 px inside the silhouette, where the
# surface faces the camera.
DEPTH_JUMP = 3.0


class NoReference(IntEnum):
    """Why a track has no true surface point (:attr:`SurfaceReference.reason`)."""

    NONE = 0  #: it has one
    NOT_TRACKED = 1  #: never tracked
    NO_SEED_VIEW = 2  #: no view on a pixel centre at its seeding frame
    SILHOUETTE = 3  #: a pixel around the seed is off the figure
    DEPTH_JUMP = 4  #: the depth around the seed jumps (another surface's edge)
    NOT_MATERIAL = 5  #: the point leaves its texture on a later frame (a joint's blend)


class SurfaceReference(NamedTuple):
    """``positions`` (F, N, 3) world: each track's true surface point on every frame from
    its seeding on (NaN before, and for tracks without one); ``camera`` (N,) the camera it
    was seeded in (-1: none found); ``reason`` (N,) :class:`NoReference` codes; ``offset``
    (N,) the tracker's seeded position's distance from it at seeding, pixel equivalents."""

    positions: NDArray[np.float64]
    camera: NDArray[np.int64]
    reason: NDArray[np.uint8]
    offset: NDArray[np.float64]


def _seed_cameras(views: NDArray[np.float64]) -> NDArray[np.int64]:
    """(N,) the camera whose view (N, C, 2) lies on a pixel centre (-1: none)."""
    on_centre = np.asarray(np.isfinite(views).all(axis=2) & (np.abs(views - np.round(views)) < 1e-9).all(axis=2))
    # Two views on pixel centres would need a sub-pixel match to land on one exactly.
    return np.where(on_centre.any(axis=1), np.argmax(on_centre, axis=1), -1)


def _read_depth(depth: NDArray[np.float32], uv: NDArray[np.float64], footprint_f: float,
                jump: float) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """Bilinear depth (M,) at ``uv`` (M, 2) and the reason it cannot be read (M,)."""
    h, w = depth.shape
    u0 = np.floor(uv[:, 0]).astype(np.int64)
    v0 = np.floor(uv[:, 1]).astype(np.int64)
    du, dv = uv[:, 0] - u0, uv[:, 1] - v0
    # The 4 x 4 block around the bilinear cell: the cell's four corners and a ring, so the
    # second differences at the corners exist.
    offs = np.arange(-1, 3)
    rows = np.clip(v0[:, None, None] + offs[None, :, None], 0, h - 1)
    cols = np.clip(u0[:, None, None] + offs[None, None, :], 0, w - 1)
    block = depth[rows, cols].astype(np.float64)  # (M, 4, 4)
    inside = (u0 >= 1) & (v0 >= 1) & (u0 + 2 < w) & (v0 + 2 < h)
    reason = np.zeros(len(uv), np.uint8)
    reason[~(inside & np.isfinite(block).all(axis=(1, 2)))] = NoReference.SILHOUETTE
    z = ((1 - dv) * ((1 - du) * block[:, 1, 1] + du * block[:, 1, 2])
         + dv * ((1 - du) * block[:, 2, 1] + du * block[:, 2, 2]))
    with np.errstate(invalid="ignore"):
        second = np.maximum(np.abs(np.diff(block, 2, axis=1)).max(axis=(1, 2)),
                            np.abs(np.diff(block, 2, axis=2)).max(axis=(1, 2)))
        jumps = second / (z / footprint_f) > jump
    reason[(reason == 0) & jumps] = NoReference.DEPTH_JUMP
    return np.where(reason == 0, z, np.nan), reason


def surface_reference(tracks: Tracks, truth: TexturedTruth, *, jump: float = DEPTH_JUMP) -> SurfaceReference:
    """The true surface point of every track (module docstring).

    Parameters
    ----------
    tracks : Tracks
        With ``views`` (the seed's pixel is read from them).
    truth : TexturedTruth
        Of the capture the tracks were made on; ``tracks.frames`` are its frame numbers.
    jump : float, default :data:`DEPTH_JUMP`, keyword-only
        Largest second difference of the depth around a seed, pixel equivalents per
        pixel squared.

    Returns
    -------
    SurfaceReference

    Raises
    ------
    InvalidInputError
        Tracks without views, with a camera count other than the truth's, or frames the
        truth does not have.
    """
    if tracks.views is None:
        raise InvalidInputError("tracks must carry their views (Tracks.views) to find the pixel each was seeded on")
    f, n = tracks.flags.shape
    cameras = truth.rig.cameras
    if tracks.views.shape[2] != len(cameras):
        raise InvalidInputError(f"tracks have views in {tracks.views.shape[2]} cameras, the truth's rig {len(cameras)}")
    missing = sorted(set(int(x) for x in tracks.frames) - set(int(x) for x in truth.frames))
    if missing:
        raise InvalidInputError(f"frames {missing[:5]} are not in the truth (it has {len(truth.frames)} frames)")
    if not np.isfinite(jump) or jump <= 0:
        raise InvalidInputError(f"jump must be a positive number, got {jump!r}")
    tracked = tracks.flags == TrackFlag.TRACKED
    first = np.where(tracked.any(axis=0), np.argmax(tracked, axis=0), -1)
    reason = np.where(first >= 0, NoReference.NONE, NoReference.NOT_TRACKED).astype(np.uint8)
    rows = np.flatnonzero(first >= 0)
    seed_views = tracks.views[first[rows], rows]
    camera = np.full(n, -1, np.int64)
    camera[rows] = _seed_cameras(seed_views)
    reason[rows[camera[rows] < 0]] = NoReference.NO_SEED_VIEW
    x0 = np.full((n, 3), np.nan)
    frame_of = tracks.frames
    for s in np.unique(first[rows]):
        for k, cam in enumerate(cameras):
            sel = rows[(first[rows] == s) & (camera[rows] == k)]
            if sel.size == 0:
                continue
            uv = tracks.views[s, sel, k]
            z, why = _read_depth(truth.depth(cam.name, int(frame_of[s])), uv, float(cam.K[0, 0]), jump)
            reason[sel] = np.where(why > 0, why, reason[sel])
            origin, direction = cam.rays(uv)
            # Depth is z in the camera frame: the ray's length to it is z over the cosine of
            # the ray with the optical axis.
            x0[sel] = origin + direction * (z / (direction @ cam.R[2]))[:, None]

    positions = np.full((f, n, 3), np.nan)
    offset = np.full(n, np.nan)
    figure = truth.figure
    good = np.flatnonzero(reason == NoReference.NONE)
    for s in np.unique(first[good]):
        sel = good[first[good] == s]
        fs = int(frame_of[s])
        # The texture is fixed to the nearest capsule's frame (the renderer's choice); the
        # depth map's point is on the mesh, a fraction of a millimetre off the field's zero
        # level, where the truth's points live: put it there, as the truth's frame 0 does.
        part = np.argmin(figure.part_distances(x0[sel], fs), axis=1).astype(np.int64)
        pose = figure.capsules(fs)
        local = np.einsum("nji,nj->ni", pose.frames[part], x0[sel] - pose.starts[part])
        on = material_points(figure, fs, part, local)
        local = np.einsum("nji,nj->ni", pose.frames[part], on - pose.starts[part])
        material = np.ones(sel.size, bool)
        for t in range(s, f):
            x = material_points(figure, int(frame_of[t]), part, local)
            material &= material_mask(figure, int(frame_of[t]), part, local, x)
            positions[t, sel] = x
        reason[sel[~material]] = NoReference.NOT_MATERIAL
        positions[:, sel[~material]] = np.nan
        k = camera[sel]
        depth = np.array([cameras[j].to_camera(on[i : i + 1])[0, 2] / cameras[j].K[0, 0] for i, j in enumerate(k)])
        offset[sel] = np.linalg.norm(tracks.positions[s, sel] - on, axis=1) / depth
    return SurfaceReference(positions=positions, camera=camera, reason=reason, offset=offset)
