"""Phantom components of a carved hull: pieces no silhouette pixel needs.

A camera that does not see a voxel does not carve it (SPEC 2), so space seen by only two
or three cameras keeps every voxel whose rays in those cameras pass through the subject's
silhouettes: blobs far from the subject (up to a metre away on the textured captures, up
to a third of the hull's voxels) that the elastic model would take for part of the body.
Such a component explains nothing: in every camera, each silhouette pixel it covers is
covered by the rest of the hull too. A real separate piece (a hand apart from the arm at
the grid's resolution, a second object) covers pixels of its own in some camera.

So the components (26-connected) are examined one at a time, and one is dropped when in no
camera it covers at least ``min_pixels`` silhouette pixels that the components still kept
do not cover. The order matters, because two pieces can cover each other's pixels: the
components seen by fewest cameras go first (a phantom exists because few cameras see it;
in front of one camera it can be larger than the subject and hide it in that camera), the
smaller first among equals, and the last one, the best seen, is never dropped.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from elastocap._core import InvalidInputError
from elastocap._validate import as_count
from elastocap.cameras.rig import Rig
from elastocap.hull.carve import Hull, masks_in_rig_order

__all__ = ["drop_phantoms"]

# sqrt(3) / 2: a voxel's half-diagonal in voxel sides, the radius its projection can reach.
_HALF_DIAGONAL = 0.8661


def _footprints(
    uv: NDArray[np.float64], labels: NDArray[np.intp], count: int, shape: tuple[int, int], radius: int
) -> tuple[list[tuple[slice, slice] | None], list[NDArray[np.bool_] | None]]:
    """Each component's projected footprint in one camera: its voxel centres' pixels grown
    by ``radius`` (a disc), as a crop (its window in the image and the boolean patch)."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    pixels = np.rint(uv).astype(np.intp)
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(count + 1))
    windows: list[tuple[slice, slice] | None] = []
    patches: list[NDArray[np.bool_] | None] = []
    for k in range(count):
        p = pixels[order[bounds[k] : bounds[k + 1]]]
        if len(p) == 0:  # no voxel of this component in this camera's image
            windows.append(None)
            patches.append(None)
            continue
        lo = np.maximum(p.min(axis=0) - radius, 0)
        hi = np.minimum(p.max(axis=0) + radius + 1, (shape[1], shape[0]))
        patch = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), np.uint8)
        patch[p[:, 1] - lo[1], p[:, 0] - lo[0]] = 1
        windows.append((slice(lo[1], hi[1]), slice(lo[0], hi[0])))
        patches.append(cv2.dilate(patch, kernel) > 0)
    return windows, patches


def drop_phantoms(hull: Hull, masks: Any, rig: Rig, *, min_pixels: int = 4) -> Hull:
    """The hull without its phantom components (see the module's notes).

    Parameters
    ----------
    hull : Hull
        A carved hull (:func:`~elastocap.hull.carve.visual_hull` of the same masks and rig).
    masks : dict of str to (H, W) array, or sequence of (H, W) arrays in rig order
        The silhouettes it was carved from, non-zero = foreground.
    rig : Rig
        The calibrated cameras.
    min_pixels : int, keyword-only
        A component is kept when in some camera it covers at least this many silhouette
        pixels that no other kept component covers. Each voxel is drawn as a disc of its
        projected half-diagonal around its centre's pixel.

    Returns
    -------
    Hull
        ``hull`` itself when it has one component or none is a phantom; else a new hull on
        the same grid without the phantoms' voxels.
    """
    if not isinstance(hull, Hull):
        raise InvalidInputError(f"hull must be a Hull, got {type(hull)}")
    if not isinstance(rig, Rig) or len(rig) == 0:
        raise InvalidInputError("rig must be a Rig with at least one camera")
    min_pixels = as_count("min_pixels", min_pixels, minimum=1)
    silhouettes = [m != 0 for m in masks_in_rig_order(masks, rig)]
    occupancy = hull.occupancy
    labelled, count = ndimage.label(occupancy, structure=np.ones((3, 3, 3), dtype=bool))
    if count <= 1:
        return hull
    centres = hull.grid.centers()[occupancy]
    labels = labelled[occupancy] - 1
    sizes = np.bincount(labels, minlength=count)
    # A camera sees a component when it sees at least half of its voxels.
    seen_by = np.zeros(count, dtype=np.intp)

    # Per camera: every component's footprint, and how many kept components cover a pixel.
    footprints = []
    for camera, silhouette in zip(rig.cameras, silhouettes):
        seen = camera.visible(centres)
        seen_by += 2 * np.bincount(labels[seen], minlength=count) >= sizes
        uv, depth = camera.project(centres[seen])
        radius = 1
        if seen.any():
            focal = max(abs(camera.K[0, 0]), abs(camera.K[1, 1]))
            radius = max(1, int(np.ceil(focal * _HALF_DIAGONAL * hull.grid.spacing / depth.min())))
        windows, patches = _footprints(uv, labels[seen], count, silhouette.shape, radius)
        cover = np.zeros(silhouette.shape, np.int32)
        for window, patch in zip(windows, patches):
            if window is not None:
                cover[window] += patch
        footprints.append((silhouette, cover, windows, patches))

    phantom = np.zeros(count, dtype=bool)
    for k in np.lexsort((sizes, seen_by))[:-1]:  # the best seen is never dropped
        explains = False
        for silhouette, cover, windows, patches in footprints:
            window, patch = windows[k], patches[k]
            if window is None:
                continue
            own = patch & silhouette[window] & (cover[window] == 1)
            if int(own.sum()) >= min_pixels:
                explains = True
                break
        if not explains:
            phantom[k] = True
            for _, cover, windows, patches in footprints:
                if windows[k] is not None:
                    cover[windows[k]] -= patches[k]
    if not phantom.any():
        return hull
    kept = occupancy.copy()
    kept[occupancy] = ~phantom[labels]
    return Hull(kept, hull.grid)
