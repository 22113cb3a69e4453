"""Silhouettes: background subtraction on a synthetic scene, clean-up (holes, specks,
borders), dark-background thresholding, GrabCut refinement and dark-background
segmentation of an object touching a dim cloth, and bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import elastocap
from elastocap.silhouettes.background import (
    clean_mask,
    refine_silhouette,
    segment_dark_background,
    subtract_background,
    threshold_dark_background,
)
from tolerances import DARK_SEGMENT_IOU_MIN, DISC_IOU_MIN

HEIGHT, WIDTH = 120, 160


def disc(centre=(80, 60), radius=40, shape=(HEIGHT, WIDTH)) -> np.ndarray:
    rows, cols = np.mgrid[: shape[0], : shape[1]]
    return (cols - centre[0]) ** 2 + (rows - centre[1]) ** 2 <= radius**2


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


@pytest.mark.parametrize("seed", range(5))
def test_background_subtraction_recovers_a_disc(seed):
    rng = np.random.default_rng(seed)
    # Texture: smooth colour blobs plus a checkerboard, so no single colour is "the"
    # background; no blob is as red as the disc (where they match, no method can tell).
    low, high = np.array([40, 60, 60]), np.array([150, 215, 215])
    blobs = cv2.resize(rng.uniform(low, high, size=(6, 8, 3)).astype(np.float32), (WIDTH, HEIGHT),
                       interpolation=cv2.INTER_CUBIC)
    rows, cols = np.mgrid[:HEIGHT, :WIDTH]
    checker = ((rows // 8 + cols // 8) % 2 * 30 - 15)[..., None]
    background = np.clip(blobs + checker, 0, 255)
    truth = disc()
    scene = background.copy()
    scene[truth] = (200, 40, 60)  # a red disc
    noisy = lambda image: np.clip(image + rng.normal(0, 8, image.shape), 0, 255).astype(np.uint8)
    mask = subtract_background(noisy(scene), noisy(background))
    assert mask.dtype == bool and mask.shape == (HEIGHT, WIDTH)
    assert iou(mask, truth) >= DISC_IOU_MIN, iou(mask, truth)


def test_background_subtraction_of_identical_images_is_empty():
    rng = np.random.default_rng(5)
    image = rng.integers(0, 256, size=(HEIGHT, WIDTH, 3), dtype=np.uint8)
    assert not subtract_background(image, image.copy()).any()


def test_threshold_parameter_decides():
    background = np.full((HEIGHT, WIDTH, 3), 100, np.uint8)
    scene = background.copy()
    scene[disc()] = 110  # Delta E of about 4 in lightness
    assert iou(subtract_background(scene, background, threshold=2.0), disc()) > 0.97
    assert not subtract_background(scene, background, threshold=6.0).any()


def test_fill_holes_fills_an_annulus():
    annulus = disc(radius=40) & ~disc(radius=15)
    filled = clean_mask(annulus, open_radius=0, close_radius=0, fill_holes=True, min_area=0)
    np.testing.assert_array_equal(filled, disc(radius=40))
    kept = clean_mask(annulus, open_radius=0, close_radius=0, fill_holes=False, min_area=0)
    np.testing.assert_array_equal(kept, annulus)


def test_fill_holes_keeps_background_that_touches_the_border():
    # A "C" open to the left image border: its inside is not a hole.
    mask = np.zeros((HEIGHT, WIDTH), bool)
    mask[20:100, 0:120] = True
    mask[40:80, 0:100] = False
    filled = clean_mask(mask, open_radius=0, close_radius=0, fill_holes=True, min_area=0)
    np.testing.assert_array_equal(filled, mask)


def test_min_area_drops_specks():
    mask = disc(radius=30)
    mask[5:8, 5:8] = True  # 9 pixels
    mask[110:115, 140:150] = True  # 50 pixels
    cleaned = clean_mask(mask, open_radius=0, close_radius=0, fill_holes=False, min_area=64)
    np.testing.assert_array_equal(cleaned, disc(radius=30))
    assert clean_mask(mask, open_radius=0, close_radius=0, fill_holes=False, min_area=10).sum() == disc(radius=30).sum() + 50


def test_opening_removes_hairlines_and_closing_bridges_cracks():
    mask = disc(radius=30)
    mask[60, :] = True  # a one-pixel line across the image
    mask[:, 80] &= False  # a one-pixel crack through the disc
    cleaned = clean_mask(mask, open_radius=1, close_radius=2, fill_holes=False, min_area=0)
    assert iou(cleaned, disc(radius=30)) > 0.98
    assert not cleaned[60, :30].any()  # the line is gone
    assert cleaned[60, 80]  # the crack is closed


def test_closing_does_not_glue_to_the_border():
    mask = np.zeros((HEIGHT, WIDTH), bool)
    mask[2:40, 2:40] = True  # two pixels from the top-left corner
    cleaned = clean_mask(mask, open_radius=0, close_radius=5, fill_holes=True, min_area=0)
    np.testing.assert_array_equal(cleaned, mask)


def test_threshold_dark_background():
    image = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    image[disc()] = (90, 80, 70)
    image[3, 3] = (150, 150, 150)  # a single hot pixel: blurred to 150 / 2 pi < 30
    mask = threshold_dark_background(image, 30)
    assert iou(mask, disc()) > 0.97 and not mask[3, 3]
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    np.testing.assert_array_equal(threshold_dark_background(grey, 30), mask)


def object_on_dark_cloth(seed: int):
    """An ellipse lit from above on black, its lower half in shadow (same hue, darker than
    the cloth), touching a dim desaturated cloth with folds on the left; lens blur and
    noise. Returns the image, the true mask and a box around the object (the projection of
    a known bounding volume, as in a calibrated capture)."""
    rng = np.random.default_rng(seed)
    height, width = 160, 200
    rows, cols = np.mgrid[:height, :width]
    cx, cy = 110 + rng.uniform(-8, 8), 80 + rng.uniform(-8, 8)
    a, b = 55 + rng.uniform(-5, 5), 40 + rng.uniform(-5, 5)
    truth = ((cols - cx) / a) ** 2 + ((rows - cy) / b) ** 2 <= 1
    shade = np.clip((rows - cy) / b * 2.0, 0, 1)[..., None]
    colour = np.array([200.0, 170.0, 120.0]) * (1 - shade) + np.array([58.0, 36.0, 10.0]) * shade
    folds = cv2.resize(rng.uniform(35, 70, size=(5, 4)).astype(np.float32), (width, height),
                       interpolation=cv2.INTER_CUBIC)
    cloth = cols < cx - a + 12 + 6 * np.sin(rows / 15.0)
    image = np.zeros((height, width, 3))
    image[cloth] = folds[cloth][:, None] * np.array([1.0, 0.92, 0.88])
    image[truth] = colour[truth]
    image = cv2.GaussianBlur(image.astype(np.float32), (0, 0), 0.8)
    image = np.clip(image + rng.normal(0, 3, image.shape), 0, 255).astype(np.uint8)
    box = np.zeros((height, width), bool)
    box[max(int(cy - b) - 10, 0) : int(cy + b) + 10, max(int(cx - a) - 10, 0) : int(cx + a) + 10] = True
    return image, truth, box


@pytest.mark.parametrize("seed", range(5))
def test_segment_dark_background_separates_the_object_from_a_touching_cloth(seed):
    image, truth, box = object_on_dark_cloth(seed)
    mask = segment_dark_background(image, region=box)
    assert mask.dtype == bool and mask.shape == truth.shape
    assert iou(mask, truth) >= DARK_SEGMENT_IOU_MIN, iou(mask, truth)
    assert not (mask & ~box).any()
    # The shadowed half is darker than the cloth: no threshold separates them.
    grey = cv2.GaussianBlur(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32), (0, 0), 1.0)
    best = max(iou((grey > level) & box, truth) for level in range(256))
    assert best < 0.8, best


def test_segment_dark_background_of_a_black_image_is_empty():
    assert not segment_dark_background(np.full((40, 50, 3), 5, np.uint8)).any()


def test_refine_silhouette_drops_the_cloth_and_keeps_its_seeds():
    image, truth, box = object_on_dark_cloth(0)
    coarse = threshold_dark_background(image, 30) & box  # the object and a strip of cloth
    assert iou(coarse, truth) < 0.8
    sure = np.zeros_like(truth)
    sure[70:80, 100:120] = True
    refined = refine_silhouette(image, coarse, sure_foreground=sure, region=box)
    assert iou(refined, truth) >= DARK_SEGMENT_IOU_MIN, iou(refined, truth)
    assert refined[sure].all() and not (refined & ~box).any()
    # band=0: nothing outside the coarse mask (and the seeds) may be added.
    inside = refine_silhouette(image, coarse, sure_foreground=sure, region=box, band=0)
    assert not (inside & ~coarse).any()
    assert iou(inside, truth) >= DARK_SEGMENT_IOU_MIN, iou(inside, truth)
    # Reproducible (GrabCut's k-means draws from OpenCV's RNG, which is seeded).
    np.testing.assert_array_equal(refine_silhouette(image, coarse, sure_foreground=sure, region=box), refined)


def test_refine_silhouette_with_nothing_to_learn_returns_the_mask():
    image = np.random.default_rng(0).integers(0, 256, size=(30, 40, 3), dtype=np.uint8)
    assert not refine_silhouette(image, np.zeros((30, 40), bool)).any()
    assert refine_silhouette(image, np.ones((30, 40), bool)).all()
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    one = np.zeros((30, 40), bool)
    one[5, 5] = True  # fewer pixels than a colour model has components
    np.testing.assert_array_equal(refine_silhouette(grey, one), one)


@pytest.mark.parametrize(
    ("argument", "call"),
    [
        ("image", lambda: subtract_background(np.zeros((4, 4, 3)), np.zeros((4, 4, 3), np.uint8))),
        ("background", lambda: subtract_background(np.zeros((4, 4, 3), np.uint8), np.zeros((4, 4, 4), np.uint8))),
        ("image", lambda: subtract_background(np.zeros((4, 4, 3), np.uint8), np.zeros((4, 5, 3), np.uint8))),
        ("threshold", lambda: subtract_background(np.zeros((4, 4), np.uint8), np.zeros((4, 4), np.uint8), threshold=-1)),
        ("mask", lambda: clean_mask(np.zeros((4, 4, 2), bool))),
        ("mask", lambda: clean_mask(np.zeros((4, 4)))),
        ("open_radius", lambda: clean_mask(np.zeros((4, 4), bool), open_radius=1.5)),  # type: ignore[arg-type]
        ("min_area", lambda: clean_mask(np.zeros((4, 4), bool), min_area=-1)),
        ("blur_sigma", lambda: threshold_dark_background(np.zeros((4, 4), np.uint8), 30, blur_sigma=np.nan)),
        ("mask", lambda: refine_silhouette(np.zeros((4, 4, 3), np.uint8), np.zeros((4, 5), bool))),
        ("mask", lambda: refine_silhouette(np.zeros((4, 4, 3), np.uint8), np.zeros((4, 4)))),
        ("sure_foreground", lambda: refine_silhouette(np.zeros((4, 4), np.uint8), np.zeros((4, 4), bool),
                                                      sure_foreground=np.zeros((3, 4), bool))),
        ("region", lambda: refine_silhouette(np.zeros((4, 4), np.uint8), np.zeros((4, 4), bool), region=np.ones((4, 4)))),
        ("band", lambda: refine_silhouette(np.zeros((4, 4), np.uint8), np.zeros((4, 4), bool), band=-1)),
        ("iterations", lambda: refine_silhouette(np.zeros((4, 4), np.uint8), np.zeros((4, 4), bool), iterations=0)),
        ("image", lambda: segment_dark_background(np.zeros((4, 4, 2), np.uint8))),
        ("threshold", lambda: segment_dark_background(np.zeros((4, 4), np.uint8), -1)),
        ("region", lambda: segment_dark_background(np.zeros((4, 4), np.uint8), region=np.ones((5, 4), bool))),
        ("sure_erosion", lambda: segment_dark_background(np.zeros((4, 4), np.uint8), sure_erosion=1.5)),  # type: ignore[arg-type]
    ],
)
def test_bad_input(argument, call):
    with pytest.raises(elastocap.InvalidInputError, match=rf"\b{argument}\b"):
        call()
