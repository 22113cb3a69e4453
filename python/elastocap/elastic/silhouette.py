"""The silhouette term's input (issue 17, item 2): per camera, the mask's signed distance in
pixels, computed once per frame with the exact Euclidean distance transform of
:func:`elastocap.hull.sdf.signed_distance` (float64), and the camera's parameters, as
:meth:`elastocap._core.FitCore.fit_frame` takes them.

Not OpenCV's ``distanceTransform``: its float32 result differs by a rounding (3.8e-6 px at
30-60 px) between its IPP path (taken on small images only) and its own, and which one ran
changed from call to call in one process; the term amplified that to fits 2-4 m apart on a
coarse capture, so two runs of ``elastocap fit`` did not agree (benches/README.md, branch
limbs3). The exact distances are rounded as OpenCV's own path rounds them, so that every
fit OpenCV gave reproducibly is unchanged."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.hull.sdf import signed_distance

__all__ = ["signed_mask_distance", "silhouette_views"]


def signed_mask_distance(mask: NDArray[Any]) -> NDArray[np.float64]:
    """The signed distance of a mask's outline, in pixels.

    Parameters
    ----------
    mask : (H, W) array, bool or 0/1
        True on the silhouette.

    Returns
    -------
    (H, W) float64
        Distance (exact, rounded to float32 before the half pixel is taken off: OpenCV's
        ``distanceTransform(DIST_MASK_PRECISE)`` on its own code path) from each pixel centre to the outline (the boundary between mask and
        background pixels, half a pixel from the centres on either side): positive outside
        the mask, negative inside. An empty mask is everywhere as far as the image's
        diagonal outside.
    """
    inside = np.asarray(mask).astype(bool)
    if inside.ndim != 2:
        raise InvalidInputError(f"a mask must have shape (H, W), got {inside.shape}")
    if not inside.any():
        return np.full(inside.shape, float(np.hypot(*inside.shape)))
    if inside.all():
        return np.full(inside.shape, -float(np.hypot(*inside.shape)))
    # Distance to the nearest pixel centre of the other kind, minus half a pixel: the
    # outline. Exact, then rounded to float32 as OpenCV's own code path rounds it (its
    # output equals this bit for bit wherever it was reproducible: every image from
    # 120 x 160 up), so the figures measured with it stand (see the module's note).
    exact = signed_distance(inside[:, :, None])[:, :, 0]
    distance = (np.abs(exact) + 0.5).astype(np.float32)  # to the other kind's nearest centre
    return np.ascontiguousarray(np.where(inside, np.float32(0.5) - distance, distance - np.float32(0.5)), dtype=np.float64)


def silhouette_views(cameras: Sequence[Any], masks: Sequence[NDArray[Any]]) -> list[tuple[Any, ...]]:
    """One ``(K, dist, R, t, signed distance)`` per camera, for ``FitCore.fit_frame(views=)``.

    Parameters
    ----------
    cameras : sequence of :class:`elastocap.cameras.Camera`
        The rig's cameras.
    masks : sequence of (H, W) bool or None
        One mask per camera, the camera's image size; a camera whose mask is None is left
        out.
    """
    if len(cameras) != len(masks):
        raise InvalidInputError(f"need one mask per camera: {len(masks)} masks for {len(cameras)} cameras")
    views = []
    for camera, mask in zip(cameras, masks):
        if mask is None:
            continue
        dist = np.ravel(np.asarray(camera.full_dist, dtype=np.float64))
        views.append((
            np.asarray(camera.K, dtype=np.float64).ravel().tolist(),
            dist.tolist(),
            np.asarray(camera.R, dtype=np.float64).ravel().tolist(),
            np.asarray(camera.t, dtype=np.float64).ravel().tolist(),
            np.ascontiguousarray(signed_mask_distance(mask)),
        ))
    return views
