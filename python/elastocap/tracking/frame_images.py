"""A frame's grey images checked once (issue 15's speed line): the spatial matches and the
anchors' matches take their images through :func:`elastocap.stereo.matching.checked_image`
(C-contiguous float32, finite), which scanned each 1024x768 image for NaN 32 times a frame
(~0.1 ms a scan), and the spatial matches their template weights (the masks as 0/1
floats) 16 times. The tracker's images and weights are checked when read; a list of them
carries that on, and the matches take its arrays as they are. Any other sequence is checked
as before."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
from numpy.typing import NDArray

from elastocap.stereo.matching import checked_image, checked_weights

__all__ = ["CheckedImages", "checked", "checked_weights_of"]


class CheckedImages(list[NDArray[np.float32]]):
    """The frame's grey images (C of (H, W) float32), each through ``checked_image`` when
    listed. Its items must not be written to afterwards (the tracker never does)."""

    def __init__(self, images: Iterable[NDArray[np.generic]]) -> None:
        # Grey levels of any dtype checked_image takes (the tracker's: uint8, converted
        # without a NaN scan).
        super().__init__(checked_image(image) for image in images)


def checked(images: Sequence[NDArray[np.float32]], k: int) -> NDArray[np.float32]:
    """``checked_image(images[k])``, without the second scan when ``images`` were listed
    checked (:class:`CheckedImages`): the same array either way."""
    return images[k] if isinstance(images, CheckedImages) else checked_image(images[k])


def checked_weights_of(weights: Sequence[NDArray[np.float32]], k: int, shape: tuple[int, ...]) -> NDArray[np.float32]:
    """``checked_weights(weights[k], shape)``, without the second scan when ``weights`` were
    listed checked (:class:`CheckedImages`: float32, C-contiguous, finite) and have the
    template's ``shape`` (anything else is checked, and refused, as before)."""
    if isinstance(weights, CheckedImages) and weights[k].shape == shape:
        return weights[k]
    return checked_weights(weights[k], shape)
