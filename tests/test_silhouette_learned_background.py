"""Each static view's background learned by the silhouette loop (issue 16, branch sil7): a
strip of dark clutter glued to a dark figure's outline, which the colour model over frames
learns as the subject's and keeps, is removed against the learned background; the model
follows a dimming light and a sweeping bright band, and does not trust a pixel a distractor
is passing over."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from elastocap import InvalidInputError
from elastocap.silhouettes.appearance import ColourModel, appearance_silhouette
from elastocap.silhouettes.learned_background import LearnedBackground, background_outline

H, W = 120, 160


def disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def backdrop(rng: np.random.Generator) -> np.ndarray:
    """Blocky clutter, half of it dark (the colours of the figure's clothes)."""
    blocks = rng.uniform(60, 200, (H // 8, W // 8, 3))
    blocks[rng.random(blocks.shape[:2]) < 0.5] = rng.uniform(15, 45, 3)
    return cv2.resize(blocks, (W, H), interpolation=cv2.INTER_NEAREST) + rng.normal(0, 8, (H, W, 3))


def light(frame: int, frames: int) -> np.ndarray:
    """The clutter scene's kind of light: a dimming gain and a bright band sweeping across."""
    columns = np.arange(W, dtype=np.float64)
    centre = frame * 9.0 - 20
    gain = (1.0 - 0.4 * frame / frames) * (1.0 + 0.35 * np.exp(-(((columns - centre) / 20.0) ** 2)))
    return gain[None, :, None]


def figure(frame: int) -> np.ndarray:
    """A torso that sways and an arm that swings: the background next to the outline of a
    frame was seen, far from the figure, on some earlier frame."""
    mask = np.zeros((H, W), np.uint8)
    x = int(round(80 + 14 * np.sin(0.6 * frame)))
    cv2.ellipse(mask, (x, 70), (18, 40), 0, 0, 360, 1, -1)
    angle = np.deg2rad(20 + 8 * frame)
    end = (int(x + 45 * np.sin(angle)), int(45 + 45 * np.cos(angle)))
    cv2.line(mask, (x, 45), end, 1, 9)
    return mask != 0


def render(back: np.ndarray, truth: np.ndarray, frame: int, frames: int, rng: np.random.Generator) -> np.ndarray:
    image = back.copy()
    # Dark clothes with a texture, as dark as the dark clutter.
    image[truth] = np.array([35.0, 30.0, 40.0]) + rng.normal(0, 6, (int(truth.sum()), 3))
    return np.clip(image * light(frame, frames) + rng.normal(0, 3, image.shape), 0, 255).astype(np.uint8)


def learned(frames: int = 12, seed: int = 0) -> tuple[LearnedBackground, list[np.ndarray], list[np.ndarray]]:
    rng = np.random.default_rng(seed)
    back = backdrop(rng)
    model = LearnedBackground()
    images, truths = [], []
    for f in range(frames):
        truth = figure(f)
        image = render(back, truth, f, frames, rng)
        images.append(image)
        truths.append(truth)
        model.update(image, ~(cv2.dilate(truth.astype(np.uint8), disk(10)) != 0))
    return model, images, truths


def test_a_fat_outline_into_dark_clutter_is_removed_where_the_colour_model_keeps_it() -> None:
    model, images, truths = learned(frames=12)
    rng = np.random.default_rng(5)
    back = backdrop(np.random.default_rng(0))
    f = 12
    truth = figure(f)
    image = render(back, truth, f, 14, rng)
    # The segmentation's outline 3 px too fat all round (dark against dark).
    fat = cv2.dilate(truth.astype(np.uint8), disk(3)) != 0
    assert iou(fat, truth) < 0.8
    # Before: the colour model over frames learned the fat masks as the subject (the strip
    # lies inside the body model's silhouette), so it does not drop the strip.
    colours = ColourModel()
    for image_f, truth_f in zip(images, truths):
        colours.update(image_f, cv2.dilate(truth_f.astype(np.uint8), disk(3)))
    kept = appearance_silhouette(fat, colours.log_ratio(image))
    assert iou(kept, truth) < 0.85
    # After: against the learned background, the strip is the background.
    support = ~(cv2.dilate(fat.astype(np.uint8), disk(10)) != 0)
    distance = model.distance(image, support)
    out = background_outline(fat, distance)
    # Where the background next to the outline was confirmed on an earlier frame (about
    # half the strip here), most of the strip goes, and none of the figure.
    known = np.isfinite(distance) & fat & ~truth
    assert known.sum() > 0.4 * (fat & ~truth).sum()
    assert (known & ~out).sum() > 0.75 * known.sum()
    assert (truth & ~out).sum() < 0.01 * truth.sum()
    assert iou(out, truth) > iou(fat, truth) + 0.07
    assert iou(out, truth) > iou(kept, truth) + 0.02
    # Nothing of the figure's inside is touched.
    inner = cv2.erode(fat.astype(np.uint8), disk(3)) != 0
    assert (out | ~inner).all()


def test_the_light_change_is_followed_and_the_background_matches_under_it() -> None:
    model, images, truths = learned(frames=12)
    support = ~(cv2.dilate(truths[-1].astype(np.uint8), disk(10)) != 0)
    gain = model.gain(images[-1], support)
    expected = light(11, 12)[0, :, 0] / light(0, 12)[0, :, 0]
    # The gain field against the reference light (frame 0's) follows the sweep and the dim.
    assert np.median(np.abs(gain[support] / np.broadcast_to(expected, (H, W))[support] - 1)) < 0.05
    d = model.distance(images[-1], support)
    trusted = np.isfinite(d) & support
    assert trusted.mean() > 0.5
    assert np.median(d[trusted]) < 8.0  # the sensor noise is 3 a channel


def test_a_passing_distractor_is_not_trusted_until_the_pixel_holds_still() -> None:
    rng = np.random.default_rng(2)
    back = backdrop(rng)
    model = LearnedBackground(confirmations=3)
    everywhere = np.ones((H, W), bool)
    for f in range(6):
        model.update(np.clip(back + rng.normal(0, 3, back.shape), 0, 255).astype(np.uint8), everywhere)
    assert model.trusted().all()
    for f in range(3):
        image = back.copy()
        image[40:80, 20 + 10 * f : 60 + 10 * f] = (250, 20, 250)  # a magenta box moving right
        model.update(np.clip(image + rng.normal(0, 3, back.shape), 0, 255).astype(np.uint8), everywhere)
    trusted = model.trusted()
    # The pixels the box reached in the last two frames restarted from it, and those it
    # left restarted from the background again: neither is trusted...
    assert not trusted[40:80, 60:80].any()
    assert not trusted[40:80, 20:40].any()
    # ...those it never covered still are.
    assert trusted[:30].all()


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**16), st.integers(1, 5), st.floats(1.0, 60.0))
def test_only_the_outline_band_can_be_dropped(seed: int, band: int, match: float) -> None:
    rng = np.random.default_rng(seed)
    mask = cv2.GaussianBlur(rng.random((40, 50)), (0, 0), 3) > 0.5
    distance = rng.uniform(0, 80, mask.shape)
    distance[rng.random(mask.shape) < 0.2] = np.inf
    out = background_outline(mask, distance, band=band, match=match)
    assert not (out & ~mask).any()
    inner = cv2.erode(mask.astype(np.uint8), disk(band)) != 0
    assert (out | ~inner).all()


def test_bad_input_is_refused() -> None:
    model = LearnedBackground()
    image = np.zeros((H, W, 3), np.uint8)
    with pytest.raises(InvalidInputError, match="not learned"):
        model.distance(image, np.ones((H, W), bool))
    with pytest.raises(InvalidInputError, match="uint8"):
        model.update(image.astype(np.float32), np.ones((H, W), bool))
    model.update(image, np.ones((H, W), bool))
    with pytest.raises(InvalidInputError, match="shape"):
        model.update(np.zeros((H + 1, W, 3), np.uint8), np.ones((H + 1, W), bool))
    with pytest.raises(InvalidInputError, match="confirmed"):
        model.update(image, np.ones((H, W + 1), bool))
    with pytest.raises(InvalidInputError, match="NaN"):
        background_outline(np.ones((4, 4), bool), np.full((4, 4), np.nan))
    with pytest.raises(InvalidInputError, match="shape"):
        background_outline(np.ones((4, 4), bool), np.zeros((4, 5)))
    with pytest.raises(InvalidInputError, match="band"):
        background_outline(np.ones((4, 4), bool), np.zeros((4, 4)), band=0)
    with pytest.raises(InvalidInputError, match="tolerance"):
        LearnedBackground(tolerance=0)


def test_a_gain_computed_once_gives_the_same_model_and_distance() -> None:
    # The loop computes the frame's gain once for the outline test and the update.
    a, images, truths = learned(frames=6)
    b, _, _ = learned(frames=6)
    rng = np.random.default_rng(9)
    truth = figure(6)
    image = render(backdrop(np.random.default_rng(0)), truth, 6, 12, rng)
    support = ~(cv2.dilate(truth.astype(np.uint8), disk(10)) != 0)
    gain = b.gain(image, support)
    np.testing.assert_array_equal(a.distance(image, support), b.distance(image, None, gain=gain))
    a.update(image, support)
    b.update(image, support, gain=gain)
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(a.count, b.count)
    with pytest.raises(InvalidInputError, match="gain"):
        b.update(image, support, gain=np.zeros((H, W)))
    with pytest.raises(InvalidInputError, match="gain"):
        b.distance(image, None, gain=np.ones((H, W + 1)))


def test_the_gain_field_at_a_quarter_resolution_follows_the_light_as_the_full_one() -> None:
    # The field is smooth (sigma 12 px): estimated on a 4x coarser grid (the default) it
    # must follow the sweep and the dim as the full-resolution one does, across the
    # figure's gap too (filled from around it), and give the same outline test.
    model, images, truths = learned(frames=12)
    full = LearnedBackground(gain_scale=1)
    full.mean, full.count = model.mean, model.count
    support = ~(cv2.dilate(truths[-1].astype(np.uint8), disk(10)) != 0)
    coarse_gain, full_gain = model.gain(images[-1], support), full.gain(images[-1], support)
    assert coarse_gain.shape == full_gain.shape == (H, W)
    expected = np.broadcast_to(light(11, 12)[0, :, 0] / light(0, 12)[0, :, 0], (H, W))
    assert np.median(np.abs(coarse_gain / expected - 1)) < 0.05
    assert np.percentile(np.abs(coarse_gain / full_gain - 1), 95) < 0.02
    fat = cv2.dilate(truths[-1].astype(np.uint8), disk(3)) != 0
    a = background_outline(fat, model.distance(images[-1], None, gain=coarse_gain))
    b = background_outline(fat, full.distance(images[-1], None, gain=full_gain))
    assert (a != b).sum() <= 0.02 * fat.sum()
    with pytest.raises(InvalidInputError, match="gain_scale"):
        LearnedBackground(gain_scale=0)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_the_channel_sums_equal_numpys_norm_and_sum_bit_for_bit(seed: int) -> None:
    # The module's per-pixel colour distance and brightness skip numpy's strided reduction
    # over the last axis; they must give the very values it gives (a test above compares
    # models and distances for equality).
    from elastocap.silhouettes.learned_background import _brightness, _norm

    x = np.random.default_rng(seed).normal(0, 80, (17, 23, 3)).astype(np.float32)
    np.testing.assert_array_equal(_norm(x), np.linalg.norm(x, axis=2).astype(np.float32))
    np.testing.assert_array_equal(_brightness(x), x.sum(axis=2))
