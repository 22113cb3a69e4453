"""The silhouette term's input (issue 17, item 2): per camera, the mask's signed distance in
pixels, computed once per frame with the exact Euclidean distance transform of
:func:`elastocap.hull.sdf.signed_distance` (float64) over the part of the image the term can
read (:func:`term_margins`), and the camera's parameters, as
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

__all__ = ["signed_mask_distance", "silhouette_views", "term_margins"]

# How much a node's projected support may grow while a frame is fitted, over its value at
# the frame's start: a part coming 1/3 closer to a camera within one frame.
MARGIN_SLACK = 1.5
# The pixels the term's sampling reads beyond a node's image (bilinear, then differences
# half a pixel apart), with one to spare.
SAMPLING_PIXELS = 4


def signed_mask_distance(mask: NDArray[Any], margin: int | None = None) -> NDArray[np.float64]:
    """The signed distance of a mask's outline, in pixels.

    Parameters
    ----------
    mask : (H, W) array, bool or 0/1
        True on the silhouette.
    margin : int, optional
        Compute the exact distance only within ``margin`` pixels of the mask's bounding
        box (at least 1). Outside that box the result is a lower bound: the distance to
        the mask's bounding box, at least ``margin``. Default: exact everywhere.

    Returns
    -------
    (H, W) float64
        Distance (exact, rounded to float32 before the half pixel is taken off: OpenCV's
        ``distanceTransform(DIST_MASK_PRECISE)`` on its own code path) from each pixel centre to the outline (the boundary between mask and
        background pixels, half a pixel from the centres on either side): positive outside
        the mask, negative inside. An empty mask is everywhere as far as the image's
        diagonal outside.

    Notes
    -----
    The box with its margin holds every pixel's nearest pixel of the other kind: the mask
    lies inside it, and a ring of background pixels at least one pixel wide encloses the
    mask within it (or the image ends there), so any path from an inside pixel out of the
    box crosses a background pixel first. So the distances in the box are the whole image's
    to the bit, at a fraction of its cost (a person fills a few percent of a frame).
    """
    inside = np.asarray(mask).astype(bool)
    if inside.ndim != 2:
        raise InvalidInputError(f"a mask must have shape (H, W), got {inside.shape}")
    if margin is not None and not (isinstance(margin, (int, np.integer)) and margin >= 1):
        raise InvalidInputError(f"margin must be a whole number of pixels >= 1, got {margin!r}")
    if not inside.any():
        return np.full(inside.shape, float(np.hypot(*inside.shape)))
    if inside.all():
        return np.full(inside.shape, -float(np.hypot(*inside.shape)))
    if margin is None:
        return _exact_signed(inside)
    window, origin, bounds = _windowed_signed(inside, margin)
    (r0, r1, c0, c1) = bounds
    dr = np.maximum(np.maximum(r0 - np.arange(inside.shape[0]), np.arange(inside.shape[0]) - r1), 0)
    dc = np.maximum(np.maximum(c0 - np.arange(inside.shape[1]), np.arange(inside.shape[1]) - c1), 0)
    out = np.sqrt((dr.astype(np.float64) ** 2)[:, None] + (dc.astype(np.float64) ** 2)[None, :]) - 0.5
    out[origin[0]:origin[0] + window.shape[0], origin[1]:origin[1] + window.shape[1]] = window
    return out


def _windowed_signed(inside: NDArray[np.bool_], margin: int) -> tuple[NDArray[np.float64], tuple[int, int], tuple[int, int, int, int]]:
    """:func:`signed_mask_distance` of a mask with both kinds of pixel within ``margin`` of
    its bounding box only: ``(window (h, w) float64, its first (row, column), the mask's
    bounding box (top, bottom, left, right), inclusive)``. Elsewhere the distance is the
    bounding box's less half a pixel, which ``rust/fit/silhouette.rs`` computes where it
    reads it."""
    rows, columns = np.flatnonzero(inside.any(axis=1)), np.flatnonzero(inside.any(axis=0))
    (r0, r1), (c0, c1) = (int(rows[0]), int(rows[-1])), (int(columns[0]), int(columns[-1]))
    top, left = max(r0 - margin, 0), max(c0 - margin, 0)
    window = _exact_signed(np.ascontiguousarray(inside[top:r1 + margin + 1, left:c1 + margin + 1]))
    return window, (top, left), (r0, r1, c0, c1)


def _exact_signed(inside: NDArray[np.bool_]) -> NDArray[np.float64]:
    """:func:`signed_mask_distance` of a mask with both kinds of pixel, exact everywhere."""
    # Distance to the nearest pixel centre of the other kind, minus half a pixel: the
    # outline. Exact, then rounded to float32 as OpenCV's own code path rounds it (its
    # output equals this bit for bit wherever it was reproducible: every image from
    # 120 x 160 up), so the figures measured with it stand (see the module's note).
    exact = signed_distance(inside[:, :, None])[:, :, 0]
    distance = (np.abs(exact) + 0.5).astype(np.float32)  # to the other kind's nearest centre
    return np.ascontiguousarray(np.where(inside, np.float32(0.5) - distance, distance - np.float32(0.5)), dtype=np.float64)


def term_margins(cameras: Sequence[Any], positions: NDArray[np.float64], support: NDArray[np.float64],
                 slack: float = MARGIN_SLACK) -> list[int | None]:
    """Per camera, how far from a mask the silhouette term can look (pixels), for
    :func:`signed_mask_distance`'s ``margin``.

    The term acts on a node outside a mask only within the node's support projected
    (``rust/fit/silhouette.rs``: farther is a part out of place, left to the other terms),
    and samples the distance a pixel and a half around the node's image. So a mask's
    distances are needed exactly only within the largest projected support of the model
    (``positions`` (N, 3) world units, ``support`` (N,) its nodes' MLS support radii),
    times ``slack`` for the nodes' motion during the frame, plus the sampling's pixels.
    None (exact everywhere) for a camera some node is near or behind.
    """
    positions = np.asarray(positions, dtype=np.float64)
    radius = float(np.max(support))
    margins: list[int | None] = []
    for camera in cameras:
        uv, depth = camera.project(positions)
        if not np.all(depth > 2 * radius):
            margins.append(None)
            continue
        # The projection's Jacobian row norms by differences, as the term takes them.
        h = 1e-4 * radius
        steps = [camera.project(positions + h * np.eye(3)[axis])[0] - uv for axis in range(3)]
        jac = np.stack(steps, axis=2) / h  # (N, 2, 3)
        rows = np.sqrt(np.max(np.sum(jac ** 2, axis=2), axis=1))
        reach = float(np.max(np.asarray(support) * rows))
        margins.append(int(np.ceil(slack * reach)) + SAMPLING_PIXELS if np.isfinite(reach) else None)
    return margins


def silhouette_views(cameras: Sequence[Any], masks: Sequence[NDArray[Any]],
                     margins: Sequence[int | None] | None = None) -> list[tuple[Any, ...]]:
    """One ``(K, dist, R, t, signed distance, placement)`` per camera, for
    ``FitCore.fit_frame(views=)``: with a camera's margin, the signed distance covers the
    window :func:`signed_mask_distance` computes exactly and ``placement`` is ``((width,
    height), (first row, first column), (top, bottom, left, right))`` (the image, the
    window, the mask's bounding box); without one, the whole image and None.

    Parameters
    ----------
    cameras : sequence of :class:`elastocap.cameras.Camera`
        The rig's cameras.
    masks : sequence of (H, W) bool or None
        One mask per camera, the camera's image size; a camera whose mask is None is left
        out.
    margins : sequence of int or None, optional
        Per camera, :func:`signed_mask_distance`'s ``margin`` (:func:`term_margins`);
        default exact everywhere.
    """
    if len(cameras) != len(masks):
        raise InvalidInputError(f"need one mask per camera: {len(masks)} masks for {len(cameras)} cameras")
    if margins is None:
        margins = [None] * len(cameras)
    views = []
    for camera, mask, margin in zip(cameras, masks, margins):
        if mask is None:
            continue
        dist = np.ravel(np.asarray(camera.full_dist, dtype=np.float64))
        inside = np.asarray(mask).astype(bool)
        placement = None
        if margin is not None and inside.ndim == 2 and inside.any() and not inside.all():
            # Only the window is handed over; the term computes the rest where it reads it.
            signed, origin, bounds = _windowed_signed(inside, margin)
            placement = ((inside.shape[1], inside.shape[0]), origin, bounds)
        else:
            signed = signed_mask_distance(inside, margin)
        views.append((
            np.asarray(camera.K, dtype=np.float64).ravel().tolist(),
            dist.tolist(),
            np.asarray(camera.R, dtype=np.float64).ravel().tolist(),
            np.asarray(camera.t, dtype=np.float64).ravel().tolist(),
            np.ascontiguousarray(signed),
            placement,
        ))
    return views
