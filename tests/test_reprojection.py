"""The fit's failure signal without ground truth (issue 17, item 6): the fitted surface's
silhouette against each camera's mask, plain and away from the outline."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from elastocap import InvalidInputError
from elastocap.pipeline.reprojection import band_pixels, core_pixels, iou_drops, reprojection_iou
from elastocap.render import render_silhouette
from elastocap.synth.capture import ring_rig


def _core_by_transforms(mask: np.ndarray, band: int) -> np.ndarray:
    # The definition: farther than the band from the outline, by OpenCV's exact transforms.
    inside = mask.astype(np.uint8)
    to_outline = np.where(mask, cv2.distanceTransform(inside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE),
                          cv2.distanceTransform(1 - inside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE))
    return to_outline > band


@given(st.integers(0, 2**32 - 1), st.integers(1, 60), st.integers(1, 60), st.integers(1, 9))
@settings(max_examples=80, deadline=None)
def test_the_core_is_the_threshold_of_the_exact_distance_to_the_outline(seed: int, height: int, width: int,
                                                                       band: int) -> None:
    rng = np.random.default_rng(seed)
    # Blobs, specks, masks touching the border, empty and full masks.
    kind = rng.integers(0, 4)
    if kind == 0:
        mask = rng.random((height, width)) < rng.uniform(0.0, 1.0)
    elif kind == 1:
        yy, xx = np.mgrid[:height, :width]
        cy, cx, r = rng.uniform(-5, height + 5), rng.uniform(-5, width + 5), rng.uniform(0, 40)
        mask = (yy - cy) ** 2 + (xx - cx) ** 2 < r * r
    else:
        mask = np.full((height, width), kind == 2)
    np.testing.assert_array_equal(core_pixels(mask, band), _core_by_transforms(mask, band))


def test_the_core_matches_at_camera_size() -> None:
    yy, xx = np.mgrid[:768, :1024]
    mask = ((xx - 500) ** 2 / 300**2 + (yy - 380) ** 2 / 200**2 < 1) & ~((xx > 480) & (xx < 493))
    band = band_pixels(1024, 768)
    assert band == 5
    np.testing.assert_array_equal(core_pixels(mask, band), _core_by_transforms(mask, band))


@pytest.fixture(scope="module")
def scene() -> tuple:
    rig = ring_rig(4, width=160, height=120, radius=3.0, height_above=1.0, look_at=(0, 1.0, 0), fov=30)
    body = trimesh.creation.box((0.5, 0.8, 0.4))
    body.apply_translation((0, 1.0, 0))
    arm = trimesh.creation.box((0.6, 0.12, 0.12))
    arm.apply_translation((0.5, 1.2, 0))
    figure = trimesh.util.concatenate([body, arm])
    masks = {c.name: render_silhouette(figure, c) for c in rig.cameras}
    return rig, body, figure, masks


def test_a_surface_against_its_own_masks_scores_one(scene: tuple) -> None:
    rig, _, figure, masks = scene
    found = reprojection_iou(figure, rig, masks)
    assert set(found) == set(rig.names)
    assert all(r.iou == 1.0 and r.core_iou == 1.0 for r in found.values())


def test_a_lost_arm_drops_the_core_iou_below_the_plain_one(scene: tuple) -> None:
    rig, body, _, masks = scene
    found = reprojection_iou(body, rig, masks)
    assert min(r.core_iou for r in found.values()) < 0.95
    assert all(r.iou < 1.0 for r in found.values())
    drops = iou_drops({0: {name: r.core_iou for name, r in found.items()}, 1: {name: 1.0 for name in found}})
    assert list(drops) == [0] and drops[0]


def test_bad_masks_are_refused(scene: tuple) -> None:
    rig, _, figure, masks = scene
    with pytest.raises(InvalidInputError, match="no mask"):
        reprojection_iou(figure, rig, {name: m for name, m in masks.items() if name != rig.names[0]})
    with pytest.raises(InvalidInputError, match="shape"):
        reprojection_iou(figure, rig, {name: m[:-1] for name, m in masks.items()})
    with pytest.raises(InvalidInputError, match="trimesh"):
        reprojection_iou(figure.vertices, rig, masks)  # type: ignore[arg-type]
