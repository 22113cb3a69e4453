"""Multi-view consistency of silhouettes: :func:`view_support` and :func:`consistent_silhouettes`.

Six calibrated views of one subject constrain each other. What one view's mask claims must
lie inside the projection of the visual hull carved by the *other* views' masks: a
distractor glued to the subject in one view (clutter the snake or the colour cut took for
the subject) has no support in the others, since it is not where they see the subject,
and is carved away. Conversely a part of the subject every other view sees (a thin limb
one view's contour missed) lies inside that projection while the view's own mask lacks it;
it is restored where the view's own evidence (its disparity mask, its colours) agrees, so
that the hull's fatness (a hull of a few views is larger than the subject) is not added.

The carving is :func:`~elastocap.hull.carve.visual_hull` (``rust/carve.rs``): the view
under test is given an all-foreground mask, so it never carves, and the others carve
with ``tolerance`` of them allowed to disagree (one other view may itself have missed a
part).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.cameras.rig import Rig
from elastocap.hull.carve import visual_hull
from elastocap.hull.grid import Grid, space_seen_by

__all__ = ["consistent_silhouettes", "view_support"]

#: Voxels along the longest side of the coarse hull that bounds the subject.
COARSE_RESOLUTION = 48


def _disk(radius: int) -> NDArray[np.uint8]:
    return np.asarray(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1)), dtype=np.uint8)


def _checked_masks(rig: Rig, masks: Mapping[str, Any]) -> dict[str, NDArray[np.bool_]]:
    if not isinstance(rig, Rig):
        raise InvalidInputError(f"rig must be an elastocap.Rig, got {type(rig).__name__}")
    if len(rig) < 3:
        raise InvalidInputError(f"multi-view consistency needs at least 3 cameras (a view against two others), got {len(rig)}")
    missing = [n for n in rig.names if n not in masks]
    if missing:
        raise InvalidInputError(f"masks lack camera(s) {missing}")
    out = {}
    for camera in rig.cameras:
        m = np.asarray(masks[camera.name])
        if m.shape != (camera.height, camera.width):
            raise InvalidInputError(f"mask of camera {camera.name!r} has shape {m.shape}, the camera images ({camera.height}, {camera.width})")
        out[camera.name] = m != 0
    return out


#: The coarse grid over the space every camera sees and which of its voxels they all see,
#: per calibration: they depend on the rig only, and cost ~0.6 CPU s a frame to redo
#: (110k points projected into every camera twice; 6 cameras of 480x360, branch sil8).
_SPACE_CACHE: dict[bytes, tuple[Grid, NDArray[np.bool_]]] = {}
_SPACE_CACHE_SIZE = 8


def _calibration_key(rig: Rig) -> bytes:
    parts = []
    for camera in rig.cameras:
        dist = np.zeros(0) if camera.dist is None else np.asarray(camera.dist, dtype=np.float64)
        for array in (camera.K, camera.R, camera.t, dist, (camera.width, camera.height, camera.fold_radius)):
            parts.append(np.ascontiguousarray(array, dtype=np.float64).tobytes())
        parts.append(b"|")
    return b"".join(parts)


def _coarse_space(rig: Rig) -> tuple[Grid, NDArray[np.bool_]]:
    key = _calibration_key(rig)
    cached = _SPACE_CACHE.get(key)
    if cached is None:
        lower, upper = space_seen_by(rig)
        coarse = Grid.around(lower, upper, COARSE_RESOLUTION)
        centres = coarse.centers().reshape(-1, 3)
        seen = np.logical_and.reduce([camera.visible(centres) for camera in rig.cameras]).reshape(coarse.shape)
        if len(_SPACE_CACHE) >= _SPACE_CACHE_SIZE:
            _SPACE_CACHE.pop(next(iter(_SPACE_CACHE)))
        cached = _SPACE_CACHE[key] = (coarse, seen)
    return cached


def _subject_grid(rig: Rig, masks: Mapping[str, NDArray[np.bool_]], pixels: float) -> Grid | None:
    """A grid around what all the masks agree on (one may disagree), with voxels that
    project to about ``pixels`` pixels; None when they agree on nothing."""
    coarse, seen = _coarse_space(rig)
    from scipy import ndimage

    hull = visual_hull(masks, rig, coarse, tolerance=1, footprint="conservative")
    # Only the space every camera sees (a voxel outside a view is not carved by it), and
    # its largest connected part: the subject.
    labels, count = ndimage.label(hull.occupancy & seen)
    if count == 0:
        return None
    sizes = ndimage.sum(np.ones(coarse.shape), labels, index=np.arange(1, count + 1))
    index = np.argwhere(labels == 1 + int(np.argmax(sizes)))
    lo = coarse.origin + coarse.spacing * (index.min(axis=0) - 1.5)
    hi = coarse.origin + coarse.spacing * (index.max(axis=0) + 1.5)
    # The voxel's edge: ``pixels`` pixels at the subject's distance in the nearest camera.
    centre = 0.5 * (lo + hi)
    sizes = []
    for camera in rig.cameras:
        depth = float(camera.to_camera(centre[None])[0, 2])
        if depth > 0:
            sizes.append(pixels * depth / float(max(camera.K[0, 0], camera.K[1, 1])))
    if not sizes:
        return None
    spacing = min(sizes)
    shape = np.maximum(1, np.ceil((hi - lo) / spacing)).astype(int)
    return Grid(lo + spacing / 2, spacing, tuple(shape))


def view_support(rig: Rig, masks: Mapping[str, Any], *, tolerance: int = 1, pixels: float = 3.0) -> dict[str, NDArray[np.bool_]]:
    """Per camera, the projection of the visual hull the *other* cameras' masks carve.

    Parameters
    ----------
    rig : Rig
        At least 3 cameras.
    masks : mapping of camera name to (H, W) array_like
        Silhouettes, non-zero = subject.
    tolerance : int, keyword-only
        How many of the other cameras may reject a voxel that is kept (below the number of
        cameras minus one).
    pixels : float, keyword-only
        Voxel edge in pixels at the subject's distance (nearest camera).

    Returns
    -------
    dict of camera name to (H, W) bool
        A superset of the subject's silhouette when the other masks are supersets of
        theirs (conservative carving, each voxel's footprint drawn); all False when the
        masks agree on nothing.

    Raises
    ------
    InvalidInputError
        Fewer than 3 cameras, a missing or misshapen mask, a tolerance that carves nothing.
    """
    from scipy import ndimage

    checked = _checked_masks(rig, masks)
    if not 0 <= int(tolerance) < len(rig) - 1:
        raise InvalidInputError(f"tolerance must be in 0..{len(rig) - 2} (the other cameras less one), got {tolerance}")
    grid = _subject_grid(rig, checked, float(pixels))
    out = {}
    for camera in rig.cameras:
        h, w = camera.height, camera.width
        support = np.zeros((h, w), dtype=bool)
        if grid is not None:
            others = {n: (np.ones((h, w), dtype=bool) if n == camera.name else m) for n, m in checked.items()}
            occupancy = visual_hull(others, rig, grid, tolerance=int(tolerance), footprint="conservative").occupancy
            # The hull's outline in a view is drawn by its surface voxels (a solid's
            # projection has no holes its surface does not): ~10x fewer to project.
            index = np.argwhere(occupancy & ~ndimage.binary_erosion(occupancy))
            if len(index):
                centres = grid.origin + grid.spacing * index
                # A voxel some camera does not see was not carved by it: not support.
                keep = np.logical_and.reduce([c.visible(centres) for c in rig.cameras])
                uv, depth = camera.project(centres)
                cols = np.rint(uv[keep, 0]).astype(np.intp)
                rows = np.rint(uv[keep, 1]).astype(np.intp)
                support[rows, cols] = True
                # Each voxel covers a footprint of half its diagonal around its centre's
                # pixel: drawn by a dilation, so the support stays a superset.
                radius = int(np.ceil(0.87 * grid.spacing * float(camera.K[0, 0]) / float(depth[keep].min()) - 0.5))
                if radius > 0:
                    support = cv2.dilate(support.astype(np.uint8), _disk(radius)) != 0
        out[camera.name] = support
    return out


def _fill_small_holes(mask: NDArray[np.bool_], area: int) -> NDArray[np.bool_]:
    """``mask`` with its holes (background not connected to the border) of fewer than
    ``area`` pixels filled: stereo's holes on poorly textured skin are small, the gaps
    between limbs are not, and must stay open."""
    padded = np.pad(~mask, 1, constant_values=True).astype(np.uint8)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(padded, connectivity=4)
    small = stats[:, cv2.CC_STAT_AREA] < int(area)
    small[labels[0, 0]] = False  # the background around the image
    return mask | small[labels[1:-1, 1:-1]]


def _drop_small(mask: NDArray[np.bool_], area: int) -> NDArray[np.bool_]:
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = stats[:, cv2.CC_STAT_AREA] >= int(area)
    keep[0] = False
    return np.asarray(keep[labels])


def consistent_silhouettes(
    rig: Rig,
    masks: Mapping[str, Any],
    *,
    model_masks: Mapping[str, Any] | None = None,
    disparity_masks: Mapping[str, Any] | None = None,
    tolerance: int = 1,
    pixels: float = 3.0,
    slack: int = 1,
    fattening: int = 3,
    hole_area: int = 400,
    opening: int = 2,
    min_area: int = 50,
) -> dict[str, NDArray[np.bool_]]:
    """Each view's mask checked against the other views (see the module docstring).

    Carve: what a mask claims outside its :func:`view_support` (grown by ``slack``) is
    dropped. Restore: what a mask lacks is added where three sources agree: the other
    views (the support), the body model fitted to all views (``model_masks``), and this
    view's stereo (``disparity_masks``, shrunk by ``fattening``, since stereo fattens the
    foreground, with its small holes filled). The support alone is too fat to restore from
    (a hull of five views covers ~1.6x the subject's silhouette in the sixth: measured on
    the clutter scene, ``benches/README.md``, branch sil4), the model alone does not fit
    the subject's shape, stereo alone holds near distractors.

    Parameters
    ----------
    rig, masks, tolerance, pixels
        As :func:`view_support`.
    model_masks : mapping of camera name to (H, W) array_like, optional, keyword-only
        The fitted body model's silhouettes. Without them (or without
        ``disparity_masks``) nothing is restored.
    disparity_masks : mapping of camera name to (H, W) array_like, optional, keyword-only
        The stereo stage's binarised disparity; a camera may lack one (nothing restored
        there).
    slack : int, keyword-only
        Pixels the support is grown by before it carves (calibration and contour error).
    fattening : int, keyword-only
        Pixels stereo's foreground extends past the subject.
    hole_area : int, keyword-only
        Holes of the disparity mask smaller than this (pixels) are filled.
    opening, min_area : int, keyword-only
        Restored pixels are opened by a disc of radius ``opening`` (slivers along the
        outline are contour error, not a missed part) and kept in pieces of at least
        ``min_area`` pixels; pieces of the carved mask below ``min_area`` are dropped.

    Returns
    -------
    dict of camera name to (H, W) bool
        A view whose support is empty (the masks agree on nothing) keeps its mask.

    Raises
    ------
    InvalidInputError
        As :func:`view_support`; model or disparity masks of the wrong shape.
    """
    checked = _checked_masks(rig, masks)
    support = view_support(rig, checked, tolerance=tolerance, pixels=pixels)
    out = {}
    for camera in rig.cameras:
        name = camera.name
        mask, s = checked[name], support[name]
        if not s.any():
            out[name] = mask
            continue
        s = cv2.dilate(s.astype(np.uint8), _disk(int(slack))) != 0 if slack > 0 else s
        carved = _drop_small(mask & s, min_area)
        if model_masks is None or disparity_masks is None or disparity_masks.get(name) is None or model_masks.get(name) is None:
            out[name] = carved
            continue
        model = np.asarray(model_masks[name]) != 0
        near = np.asarray(disparity_masks[name]) != 0
        if model.shape != mask.shape or near.shape != mask.shape:
            raise InvalidInputError(f"model and disparity masks of camera {name!r} must have its image's shape {mask.shape}, got {model.shape} and {near.shape}")
        near = cv2.morphologyEx(near.astype(np.uint8), cv2.MORPH_OPEN, _disk(2)) != 0
        core = cv2.erode(_fill_small_holes(near, hole_area).astype(np.uint8), _disk(int(fattening))) != 0 if fattening > 0 else near
        missed = s & model & core & ~carved
        if opening > 0:
            missed = cv2.morphologyEx(missed.astype(np.uint8), cv2.MORPH_OPEN, _disk(int(opening))) != 0
        out[name] = carved | _drop_small(missed, min_area)
    return out
