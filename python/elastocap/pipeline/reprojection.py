"""The fit's failure signal that needs no ground truth (issue 17, item 6): per frame and
camera, the intersection over union of the fitted surface's silhouette with the mask.

Two figures per camera: the plain IoU, and the **core IoU**, the IoU over the pixels
farther than a band of ``max(1, round(diagonal / 256))`` pixels (5 at 1024x768) from the
mask's outline. The plain IoU of a good fit is dominated by its outline: on the
fast-motion capture (seeds 0-2, 2,500 nodes, 1024x768) it spread over 0.87-0.96 in frames
where no limb was lost and fell to 0.83-0.88 where one was, so no threshold separates
them. A lost limb is a patch tens of pixels wide, which the band does not hide: the core
IoU stayed at or above 0.961 in every frame whose lost-limb measure was below 3% of the
diagonal and fell to 0.90-0.94 in the frames with a lost arm (8-19%). A frame is flagged
when a camera's core IoU is below :data:`CORE_IOU_FLOOR`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import trimesh
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.cameras import Rig
from elastocap.render import render_silhouette

__all__ = ["CORE_IOU_FLOOR", "Reprojection", "ReprojectionWarning", "band_pixels", "core_pixels", "iou_drops", "reprojection_iou"]

# A camera's core IoU below this flags the frame (measured as in the module docstring:
# good frames >= 0.961, lost arms <= 0.942).
CORE_IOU_FLOOR = 0.95
# The band around a mask's outline left out of the core IoU: one pixel per this many
# pixels of the image diagonal (5 px at 1024x768, about 2 cm at 4 m: a few times the
# fitted surface's usual distance to the hull).
BAND_DIAGONAL_PIXELS = 256


class ReprojectionWarning(UserWarning):
    """The fitted surface's silhouette dropped away from a camera's mask in some frames (a
    limb lost, most likely): the message names the frames and cameras."""


@dataclass(frozen=True)
class Reprojection:
    """The fitted silhouette against one camera's mask.

    Attributes
    ----------
    iou : float
        Intersection over union of the two silhouettes.
    core_iou : float
        The same over the pixels outside the band around the mask's outline.
    """

    iou: float
    core_iou: float


def band_pixels(width: int, height: int) -> int:
    """The band (pixels) around a mask's outline left out of the core IoU."""
    return max(1, round(float(np.hypot(width, height)) / BAND_DIAGONAL_PIXELS))


def _ratio(intersection: NDArray[np.bool_], union: NDArray[np.bool_]) -> float:
    count = int(np.count_nonzero(union))
    return 1.0 if count == 0 else int(np.count_nonzero(intersection)) / count


def core_pixels(mask: NDArray[np.bool_], band: int) -> NDArray[np.bool_]:
    """``(H, W) bool``: the pixels of ``mask``'s image farther than ``band`` pixels
    (Euclidean, between pixel centres) from every pixel of the other side of its outline.

    The same set as thresholding the exact distance transforms of the mask and of its
    complement at ``band`` (``tests/test_reprojection.py`` checks it against OpenCV's), by
    two erosions with a disc of radius ``band``: a few milliseconds at 1024x768 where the
    two transforms took ~60 ms, for every camera of every fitted frame. Pixels beyond the
    image's border count as neither side (the transforms ignore them too).
    """
    reach = np.arange(-band, band + 1)
    disc = ((reach[:, None] ** 2 + reach[None, :] ** 2) <= band * band).astype(np.uint8)
    inside = mask.astype(np.uint8)
    return np.logical_or(cv2.erode(inside, disc), cv2.erode(1 - inside, disc))


def _compare(rendered: NDArray[np.bool_], mask: NDArray[np.bool_]) -> Reprojection:
    core = core_pixels(mask, band_pixels(mask.shape[1], mask.shape[0]))
    both, either = rendered & mask, rendered | mask
    return Reprojection(_ratio(both, either), _ratio(both & core, either & core))


def reprojection_iou(surface: trimesh.Trimesh, rig: Rig, masks: Mapping[str, Any]) -> dict[str, Reprojection]:
    """The IoU of ``surface``'s silhouette with each camera's mask.

    Parameters
    ----------
    surface : trimesh.Trimesh
        The fitted surface, world units, in front of every camera.
    rig : Rig
        The capture's cameras.
    masks : mapping of camera name to (H, W) array
        Silhouettes (non-zero = foreground), one per camera of ``rig`` (others are
        ignored), each of its camera's size.

    Returns
    -------
    dict of str to Reprojection
        Camera name -> the plain and the core IoU, in [0, 1].
    """
    if not isinstance(surface, trimesh.Trimesh):
        raise InvalidInputError(f"surface must be a trimesh.Trimesh, got {type(surface).__name__}")
    out = {}
    for camera in rig.cameras:
        if camera.name not in masks:
            raise InvalidInputError(f"masks has no mask for camera {camera.name!r}")
        mask = np.asarray(masks[camera.name]).astype(bool)
        if mask.shape != (camera.height, camera.width):
            raise InvalidInputError(
                f"the mask of camera {camera.name!r} has shape {mask.shape}, expected {(camera.height, camera.width)}"
            )
        out[camera.name] = _compare(render_silhouette(surface, camera), mask)
    return out


def iou_drops(per_frame: Mapping[int, Mapping[str, float]], *, floor: float = CORE_IOU_FLOOR) -> dict[int, list[str]]:
    """The frames where some camera's core IoU is below ``floor``, with those cameras.

    Parameters
    ----------
    per_frame : mapping of int to (mapping of str to float)
        Frame -> camera -> core IoU.
    floor : float, keyword-only

    Returns
    -------
    dict of int to list of str
        Flagged frame -> its cameras below ``floor`` (frames ascending, cameras in the
        order given).
    """
    out: dict[int, list[str]] = {}
    for frame in sorted(per_frame):
        low = [camera for camera, value in per_frame[frame].items() if value < floor]
        if low:
            out[frame] = low
    return out
