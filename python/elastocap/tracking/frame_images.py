"""A frame's grey images checked once (issue 15's speed line): the spatial matches and the
anchors' matches take their images through :func:`elastocap.stereo.matching.checked_image`
(C-contiguous float32, finite), which scanned each 1024x768 image for NaN 32 times a frame
(~0.1 ms a scan), and the spatial matches their template weights (the masks as 0/1
floats) 16 times. The tracker's images and weights are checked when read; a list of them
carries that on, and the matches take its arrays as they are. Any other sequence is checked
as before."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Sequence

import numpy as np
from numpy.typing import NDArray

from elastocap.stereo.matching import checked_image, checked_weights

__all__ = ["CheckedImages", "ImagePool", "checked", "checked_weights_of"]


class CheckedImages(list[NDArray[np.float32]]):
    """The frame's grey images (C of (H, W) float32), each through ``checked_image`` when
    listed. Its items must not be written to afterwards (the tracker never does)."""

    def __init__(self, images: Iterable[NDArray[np.float32]]) -> None:
        super().__init__(checked_image(image) for image in images)

    @classmethod
    def listed(cls, images: Iterable[NDArray[np.float32]]) -> CheckedImages:
        """The ``images`` listed as they are, for arrays that are C-contiguous float32 and
        finite by construction (:class:`ImagePool`): the
        scan would find nothing."""
        out = cls(())
        out.extend(images)
        return out


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


class ImagePool:
    """A frame's C images (H, W) of bool or whole numbers converted to float32 (the
    tracker's masks as 0/1 template weights), written into the arrays of an earlier frame
    that nothing holds any more.

    Why: a fresh 1024x768 float32 image is 3 MB, which the allocator may map anew and the
    kernel fault in page by page on the first write (the eight masks' conversion measured
    ~11 ms that way against ~1 ms into arrays already mapped, the same values), and the
    converted masks were scanned for NaN they cannot hold. The tracker keeps the frame
    before's weights, so the arrays of the frame before that are free again on the next
    frame. A list is reused only when the pool's references are its only ones (nothing
    else holds the list, an array of it, or a view into one): what any caller still holds
    is never overwritten."""

    def __init__(self, keep: int = 3) -> None:
        self.keep = keep
        self.lists: list[CheckedImages] = []

    def _free(self, shapes: list[tuple[int, ...]]) -> CheckedImages | None:
        for i in range(len(self.lists)):
            listed = self.lists[i]
            # References: the pool's list, ``listed`` here and getrefcount's argument;
            # for each array its list, ``image`` and the argument (a view holds its base).
            # (Not ``enumerate``: its cached tuple would hold one more.)
            if sys.getrefcount(listed) != 3 or [image.shape for image in listed] != shapes:
                continue
            if all(sys.getrefcount(image) == 3 for image in listed):
                return self.lists.pop(i)
        return None

    def as_float(self, images: Sequence[NDArray[np.generic]]) -> CheckedImages:
        """(C of (H, W) float32) ``images`` (bool or whole numbers) as floats, listed checked
        (finite by construction); the same values as ``np.ascontiguousarray(image,
        dtype=np.float32)``. Any other dtype is converted and scanned as before, not pooled."""
        if any(np.asarray(image).dtype.kind not in "bui" for image in images):
            return CheckedImages(np.ascontiguousarray(image, dtype=np.float32) for image in images)
        shapes = [np.shape(image) for image in images]
        out = self._free(shapes)
        if out is None:
            out = CheckedImages.listed(np.empty(shape, np.float32) for shape in shapes)
        for array, image in zip(out, images):
            np.copyto(array, image, casting="unsafe")
        self.lists.append(out)
        del self.lists[: -self.keep]
        return out
