"""A tracked frame's work batched across cameras (branch frame1): each batched call gives
every view the bits the per-camera call it replaces gave it.

- ``_core.track_step`` of C cameras in one call (the revival's search now makes one) against
  one call per camera, with and without template weights, with the weighted box, on images of
  different sizes.
- ``Anchors.search`` (the revival's search, every camera's mosaic in one step call) against
  its former loop of one ``track_step`` call per camera.
- ``box_scores_cameras`` (the coarse-to-fine search's correlation, one core call for every
  camera) against ``box_scores`` per camera; ``Pyramids`` against ``pyramid``.
- ``rigid_fusion`` / ``rigid_residuals`` given the neighbours chosen once
  (``neighbour_plans``) against choosing them each.

Scenes: per camera a smooth random print moved by a camera's own shift (some views far off
their prediction: failed box searches), a patch of the current frame replaced (failed
matches), points at and beyond the border, NaN rows."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.ndimage import gaussian_filter, shift as nd_shift

from elastocap import _core
from elastocap.tracking.anchors import Anchors
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.pyramid_search import Pyramids, box_scores, box_scores_cameras, pyramid
from elastocap.tracking.rigidity import neighbour_plans, rigid_fusion, rigid_residuals

STEP = dict(size=15, radius=6, min_correlation=0.5, forward_backward=0.6, min_texture=0.0, max_iterations=8)


def same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal to the bit (NaN where NaN)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a.view(np.uint8), b.view(np.uint8))


def print_image(shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """A print with detail at 2-8 px, grey levels 40-220, float32."""
    base = np.zeros(shape, np.float32)
    for sigma, gain in ((1.5, 0.6), (3.0, 1.0), (6.0, 1.0)):
        base += gain * gaussian_filter(rng.normal(size=shape).astype(np.float32), sigma, mode="wrap")
    base = (base - base.min()) / (base.max() - base.min())
    return np.ascontiguousarray(40.0 + 180.0 * base, dtype=np.float32)


def camera_scene(k: int, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Camera ``k``'s two frames (its own size and shift), masks (a band of zeros), and
    ``n`` views: inside, at the border, NaN; ``before`` predicting the true shift, no
    motion, or 10 px off."""
    h, w = 90 + 13 * k, 120 + 17 * k
    previous = print_image((h, w), rng)
    shift = rng.uniform(-2.5, 2.5, 2)
    current = np.ascontiguousarray(nd_shift(previous, (shift[1], shift[0]), order=1, mode="reflect"), dtype=np.float32)
    current[10:30, 10:30] = 255.0 - current[10:30, 10:30]  # an occluder: failed matches
    masks = [np.ones((h, w), np.float32) for _ in range(2)]
    masks[0][:, (w // 3): (w // 3) + 4] = 0.0
    masks[1][(h // 2): (h // 2) + 4, :] = 0.0
    last = np.column_stack([rng.uniform(-3, w + 3, n), rng.uniform(-3, h + 3, n)])
    last[rng.random(n) < 0.1] = np.nan
    kind = rng.integers(0, 3, n)
    before = np.where((kind == 0)[:, None], last - shift, np.where((kind == 1)[:, None], np.nan, last + 10.0))
    return dict(previous=previous, current=current, prev_mask=masks[0], mask=masks[1], last=last, before=before)


@settings(max_examples=4, deadline=None)
@given(seed=st.integers(0, 2**31), weighted=st.booleans(), weighted_box=st.booleans())
def test_the_step_of_every_camera_at_once_equals_one_call_per_camera(seed: int, weighted: bool,
                                                                     weighted_box: bool) -> None:
    rng = np.random.default_rng(seed)
    n = 50
    scenes = [camera_scene(k, n, rng) for k in range(3)]
    weights = ([s["prev_mask"] for s in scenes], [s["mask"] for s in scenes]) if weighted else None
    together = _core.track_step([s["previous"] for s in scenes], [s["current"] for s in scenes],
                                np.stack([s["last"] for s in scenes]), np.stack([s["before"] for s in scenes]),
                                weights=weights, weighted_box=weighted_box, **STEP)
    flags = together[1]
    for k, s in enumerate(scenes):
        alone = _core.track_step([s["previous"]], [s["current"]], s["last"][None], s["before"][None],
                                 weights=None if weights is None else ([weights[0][k]], [weights[1][k]]),
                                 weighted_box=weighted_box, **STEP)
        for got, want in zip(together, alone):
            assert same(got[k], want[0]), k
    # The scenes hold tracked views and the failures.
    assert (flags == TrackFlag.TRACKED).sum() > 0.15 * flags.size
    for flag in (TrackFlag.NOT_SEEDED, TrackFlag.IMAGE_BORDER):
        assert (flags == flag).any(), flag


def test_the_anchors_search_equals_one_step_per_camera() -> None:
    """``Anchors.search`` (the revival's) steps every camera's mosaic in one call; the former
    loop stepped camera by camera, with weights of ones on the current image."""
    rng = np.random.default_rng(3)
    c, n = 4, 70
    scenes = [camera_scene(k, n, rng) for k in range(c)]
    images = [s["previous"] for s in scenes]
    later = [s["current"] for s in scenes]
    # The views where each camera's print is inside its image (the anchors are cut there).
    uv = np.full((n, c, 2), np.nan)
    for k, s in enumerate(scenes):
        h, w = s["previous"].shape
        uv[:, k] = np.column_stack([rng.uniform(12, w - 12, n), rng.uniform(12, h - 12, n)])
    held = rng.random((n, c)) < 0.6
    held[:, 2] = False  # a camera without anchors
    anchors = Anchors(c, 15)
    anchors.cut(images, uv, held, 0, weights=[s["prev_mask"] for s in scenes])
    targets = uv + rng.uniform(-3, 3, uv.shape)
    where = held & (rng.random((n, c)) < 0.9)
    options = dict(radius=6, min_correlation=0.75, box_correlation=0.5, forward_backward=0.6, min_texture=0.0,
                   max_iterations=8)
    got, got_cov = anchors.search(later, targets, where, **options)
    # The former loop, written out.
    want = np.full((n, c, 2), np.nan)
    want_cov = np.full((n, c, 2, 2), np.nan)
    ask = where & anchors.held[:n] & np.isfinite(targets).all(axis=2)
    for k in range(c):
        rows = np.flatnonzero(ask[:, k])
        if rows.size == 0:
            continue
        mosaic, weighs, centres = anchors._mosaic(rows, k)
        before = 2 * centres - targets[rows, k]
        pos, flags, pcov, corr = _core.track_step(
            [mosaic], [later[k]], centres[None], before[None], size=15, radius=6, min_correlation=0.5,
            forward_backward=0.6, min_texture=0.0, max_iterations=8, weights=([weighs], [np.ones_like(later[k])]))
        good = (flags[0] == 0) & (corr[0] >= 0.75)
        want[rows[good], k] = pos[0, good]
        want_cov[rows[good], k] = pcov[0, good]
    assert same(got, want) and same(got_cov, want_cov)
    found = np.isfinite(got[..., 0])
    assert found.sum() > 0.5 * ask.sum() and not found[:, 2].any()
    # Nothing asked: nothing found.
    none, none_cov = anchors.search(later, targets, np.zeros((n, c), bool), **options)
    assert np.isnan(none).all() and np.isnan(none_cov).all()


@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 2**31), radius=st.sampled_from([3, 15]), size=st.sampled_from([5, 7]))
def test_the_coarse_scores_of_every_camera_at_once_equal_one_call_per_camera(seed: int, radius: int,
                                                                              size: int) -> None:
    rng = np.random.default_rng(seed)
    c = 3
    templates = [print_image((40 + 7 * k, 50 + 5 * k), rng) for k in range(c)]
    searches = [np.ascontiguousarray(nd_shift(t, rng.uniform(-3, 3, 2), order=1, mode="reflect"), dtype=np.float32)
                for t in templates]
    searches[1][5:15, 5:15] = 100.0  # flat: NaN scores -> -inf
    m = 40
    cameras = rng.integers(0, c, m)
    shape = np.array([t.shape[::-1] for t in templates], float)[cameras]
    points = rng.uniform(0, 1, (m, 2)) * (shape + 4) - 2  # some at and beyond the border
    centres = points + rng.uniform(-4, 4, (m, 2))
    candidates, scores = box_scores_cameras(templates, points, searches, centres, cameras, size=size, radius=radius)
    assert scores.shape == (m, (2 * radius + 1) ** 2)
    for k in range(c):
        rows = np.flatnonzero(cameras == k)
        want_c, want_s = box_scores(templates[k], points[rows], searches[k], centres[rows], size=size, radius=radius)
        assert same(candidates[rows], want_c) and same(scores[rows], want_s)
    assert np.isfinite(scores).any() and np.isneginf(scores).any()
    with pytest.raises(Exception, match="cameras"):
        box_scores_cameras(templates, points, searches, centres, np.full(m, c), size=size, radius=radius)


def test_pyramids_reduce_each_list_of_images_once() -> None:
    rng = np.random.default_rng(1)
    frames = [[print_image((64, 80), rng) for _ in range(2)] for _ in range(3)]
    kept = Pyramids()
    first = kept.get(frames[0], 2)
    for a, b in zip(first, pyramid(frames[0], 2)):
        assert same(a, b)
    assert kept.get(frames[0], 2) is first  # found again
    second = kept.get(frames[1], 2)
    assert kept.get(frames[0], 2) is first and kept.get(frames[1], 2) is second  # the last two kept
    assert kept.get(frames[1], 1) is not second  # another level
    kept.get(frames[2], 2)
    # Equal content in other arrays is another entry (found by identity).
    copy = [f.copy() for f in frames[2]]
    again = kept.get(copy, 2)
    for a, b in zip(again, pyramid(frames[2], 2)):
        assert same(a, b)


def test_the_fusion_and_the_residuals_with_their_neighbours_chosen_once_are_unchanged() -> None:
    rng = np.random.default_rng(7)
    m = 160
    pixel_size = 0.004
    before = np.column_stack([rng.uniform(-0.2, 0.2, m), rng.uniform(-0.3, 0.3, m), rng.uniform(-0.05, 0.05, m)])
    angle = 0.3
    rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    x = before @ rot.T + [0.02, -0.01, 0.03] + rng.normal(0, pixel_size, (m, 3))
    x[rng.random(m) < 0.05] = np.nan
    cov = np.tile(np.diag([1.0, 1.0, 9.0]) * pixel_size**2, (m, 1, 1))
    pixel = np.full(m, pixel_size)
    seeded = np.where(rng.random(m) < 0.8, 0, 2)
    history = {0: before, 2: x.copy()}
    towards = np.tile([0.0, 0.0, -1.0], (m, 1))
    options = dict(neighbours=8, both_frames=1.0, candidates=16, stretch=8.0)
    plans = neighbour_plans(x, cov, pixel, seeded, history, **options)
    fused, fcov = rigid_fusion(x, cov, pixel, seeded, history, sigma=2.0, **options)
    fused_p, fcov_p = rigid_fusion(x, cov, pixel, seeded, history, sigma=2.0, **options, plans=plans)
    assert same(fused, fused_p) and same(fcov, fcov_p)
    assert not same(fused, x)  # the fusion moved points
    res = rigid_residuals(x, fused, cov, pixel, towards, seeded, history, **options)
    res_p = rigid_residuals(x, fused, cov, pixel, towards, seeded, history, **options, plans=plans)
    for a, b in zip(res, res_p):
        assert same(a, b)
    assert np.isfinite(res.across).sum() > m // 2
