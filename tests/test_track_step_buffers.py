"""The tracker's per-frame buffers: the grey images and mask weights as the step reads them
(converted from their bytes, the same float32 values as before), and the anchors' stores,
which grow with room to spare (the arrays the same as if concatenated on every growth)."""

import numpy as np

from elastocap.tracking.anchors import Anchors
from elastocap.tracking.frame_images import CheckedImages
from elastocap.tracking.step import _grey, _grey_levels, _mask_weights


def test_grey_and_mask_weights_are_the_float32_conversions():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    mask = rng.random((37, 53)) < 0.4
    grey = CheckedImages([_grey_levels(image)])[0]
    import cv2

    expect = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
    assert grey.dtype == np.float32 and grey.flags.c_contiguous
    assert np.array_equal(grey, expect)
    # The float32 reading (the benches') is the same values.
    assert _grey(image).dtype == np.float32 and np.array_equal(_grey(image), expect)
    weights = CheckedImages([_mask_weights(mask)])[0]
    assert weights.dtype == np.float32 and weights.flags.c_contiguous
    assert np.array_equal(weights, mask.astype(np.float32))
    # A mask given as 0/1 numbers (not bool) is taken as its values.
    numeric = CheckedImages([_mask_weights(mask.astype(np.uint8))])[0]
    assert np.array_equal(numeric, mask.astype(np.float32))
    # A strided bool mask (a view) converts alike.
    wide = rng.random((37, 106)) < 0.5
    assert np.array_equal(CheckedImages([_mask_weights(wide[:, ::2])])[0], wide[:, ::2].astype(np.float32))


def test_anchor_stores_grow_like_concatenation():
    rng = np.random.default_rng(1)
    c, size = 3, 5
    anchors = Anchors(c, size)
    images = [rng.uniform(0, 255, (40, 50)).astype(np.float32) for _ in range(c)]
    masks = [(rng.random((40, 50)) < 0.7).astype(np.float32) for _ in range(c)]
    kept_patches = np.zeros((0, c, anchors.side, anchors.side), np.float32)
    for n in (3, 10, 11, 40, 41, 200):
        anchors.grow(n)
        assert len(anchors.patches) == len(anchors.held) == len(anchors.uv) == n
        # New rows hold the start values (nothing held, unit weights, NaN positions).
        new = slice(len(kept_patches), n)
        assert not anchors.held[new].any() and (anchors.frame[new] == -1).all()
        assert (anchors.patches[new] == 0).all() and (anchors.weights[new] == 1).all()
        assert np.isnan(anchors.uv[new]).all() and np.isnan(anchors.offset[new]).all()
        assert (anchors.cuts[new] == 0).all() and (anchors.age[new] == 0).all()
        # Earlier rows keep what was cut into them.
        assert np.array_equal(anchors.patches[: len(kept_patches)], kept_patches)
        uv = np.stack([rng.uniform(10, 38, n), rng.uniform(10, 28, n)], axis=1)[:, None, :].repeat(c, axis=1)
        where = rng.random((n, c)) < 0.3
        anchors.cut(images, uv, where, frame=n, weights=masks)
        assert anchors.held[where].all() and (anchors.frame[where] == n).all()
        kept_patches = anchors.patches.copy()
    # Asking for fewer leaves the arrays alone.
    anchors.grow(5)
    assert len(anchors.held) == 200
