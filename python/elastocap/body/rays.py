"""Rays of a silhouette, the body fit's 2-D evidence (SPEC 6): :func:`silhouette_rays`
through the outline and :func:`silhouette_samples`, which adds one-sided rays inside and
outside the mask."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_count
from elastocap.cameras.camera import Camera

__all__ = ["silhouette_rays", "silhouette_samples"]


def silhouette_rays(mask: Any, camera: Camera, *, max_rays: int | None = None, seed: int = 0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rays grazing a silhouette: through the midpoint of every pair of neighbouring pixels
    (horizontal and vertical) of which one is inside the mask and one outside.

    The midpoint is the unbiased sub-pixel estimate of the outline (a boundary pixel centre
    would sit half a pixel inside it on average).

    Parameters
    ----------
    mask : (height, width) array_like
        Non-zero = body.
    camera : Camera
    max_rays : int, optional, keyword-only
        Keep a random subset of at most this many rays.
    seed : int, keyword-only
        Seed of that subset.

    Returns
    -------
    origins, directions : (R, 3) float64
    """
    m = np.asarray(mask) != 0
    if m.shape != (camera.height, camera.width):
        raise InvalidInputError(f"mask must have shape ({camera.height}, {camera.width}) like its camera, got {m.shape}")
    rows, cols = np.nonzero(m[:, 1:] != m[:, :-1])
    horizontal = np.stack([cols + 0.5, rows], axis=1)
    rows, cols = np.nonzero(m[1:, :] != m[:-1, :])
    vertical = np.stack([cols, rows + 0.5], axis=1)
    uv = np.concatenate([horizontal, vertical]).astype(float)
    if max_rays is not None and len(uv) > as_count("max_rays", max_rays):
        uv = uv[np.random.default_rng(seed).choice(len(uv), max_rays, replace=False)]
    if len(uv) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    origins, directions = camera.rays(uv)
    ok = np.isfinite(directions).all(axis=1)
    return np.ascontiguousarray(origins[ok]), np.ascontiguousarray(directions[ok])


def silhouette_samples(
    mask: Any, camera: Camera, *, outline: int = 300, inside: int = 100, outside: int = 100, margin: float = 2.5, seed: int = 0
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int8]]:
    """Rays of one silhouette for :func:`fit_body`: outline rays (:func:`silhouette_rays`)
    and sparse one-sided rays through pixels inside the mask and outside it (at least
    ``margin`` pixels from the outline, so that outline quantisation does not contradict
    them); the outside pixels are drawn from the mask's bounding box grown by half its size.

    Parameters
    ----------
    mask : (height, width) array_like
        Non-zero = body.
    camera : Camera
    outline, inside, outside : int, keyword-only
        How many of each to draw (fewer when the mask has fewer pixels).
    margin : float, keyword-only
        Pixels.
    seed : int, keyword-only

    Returns
    -------
    origins, directions : (R, 3) float64
    side : (R,) int8
        0 outline, +1 inside, -1 outside (``BodyObservations.ray_side``).
    """
    import cv2

    m = np.asarray(mask) != 0
    o, d = silhouette_rays(m, camera, max_rays=outline if outline > 0 else None, seed=seed)
    if outline == 0:
        o, d = o[:0], d[:0]
    parts = [(o, d, np.zeros(len(o), dtype=np.int8))]
    rng = np.random.default_rng([seed, 0x51DE])
    if m.any():
        inner = cv2.distanceTransform(m.astype(np.uint8), cv2.DIST_L2, 3)
        outer = cv2.distanceTransform((~m).astype(np.uint8), cv2.DIST_L2, 3)
        rows, cols = np.nonzero(m)
        r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
        grow_r, grow_c = (r1 - r0) // 2, (c1 - c0) // 2
        box = np.zeros_like(m)
        box[max(r0 - grow_r, 0) : r1 + grow_r, max(c0 - grow_c, 0) : c1 + grow_c] = True
        for count, candidates, side in ((inside, inner > margin, 1), (outside, (outer > margin) & box, -1)):
            v, u = np.nonzero(candidates)
            if count <= 0 or len(v) == 0:
                continue
            pick = rng.choice(len(v), min(count, len(v)), replace=False)
            uv = np.stack([u[pick], v[pick]], axis=1).astype(float)
            origins, directions = camera.rays(uv)
            ok = np.isfinite(directions).all(axis=1)
            parts.append((origins[ok], directions[ok], np.full(int(ok.sum()), side, dtype=np.int8)))
    return (
        np.ascontiguousarray(np.concatenate([p[0] for p in parts])),
        np.ascontiguousarray(np.concatenate([p[1] for p in parts])),
        np.concatenate([p[2] for p in parts]),
    )
