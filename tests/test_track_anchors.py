"""The temporal match's anchors (``elastocap.tracking.anchors``): a view's first-appearance
patch, matched again to pull the frame-to-frame match back from its drift."""

from __future__ import annotations

import cv2
import numpy as np

from elastocap.tracking.anchors import Anchors

SIZE = 15
CENTRE = np.array([[150.0, 150.0]])


def _texture(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.normal(0, 1, (400, 400)).astype(np.float32), (0, 0), 2.0)
    return (128 + 40 * tex / tex.std()).astype(np.float32)


def test_one_anchor_in_a_camera_is_matched_from_its_own_patch() -> None:
    # A camera with a single held view: its mosaic is one tile, whose reshapes are views of
    # the tile buffer; the weights must not overwrite the patch (it then read as flat, and a
    # lone view could be neither corrected nor rescued). Found by track24 (session 23).
    tex = _texture(5)
    a = Anchors(1, SIZE)
    a.cut([tex], CENTRE[:, None], np.ones((1, 1), bool), 0)
    out, stale = a.correct([tex], (CENTRE + [0.4, -0.3])[:, None], min_correlation=0.75, reach=1.5, min_texture=1.0)
    assert not stale.any()
    np.testing.assert_allclose(out[0, 0], CENTRE[0], atol=0.02)


def test_two_anchors_in_a_camera_are_each_matched_from_their_own_patch() -> None:
    # The mosaic of several tiles (the path that always copied) gives the same answer.
    tex = _texture(6)
    centres = np.array([[150.0, 150.0], [250.0, 220.0]])
    a = Anchors(1, SIZE)
    a.cut([tex], centres[:, None], np.ones((2, 1), bool), 0)
    out, stale = a.correct([tex], (centres + [[0.4, -0.3], [-0.5, 0.2]])[:, None], min_correlation=0.75, reach=1.5,
                           min_texture=1.0)
    assert not stale.any()
    np.testing.assert_allclose(out[:, 0], centres, atol=0.02)
