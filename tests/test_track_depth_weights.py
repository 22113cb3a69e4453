"""The frame-to-frame step's templates cut at depth edges (elastocap.tracking.depth_weights):
a textured limb moving fast in front of a textured torso moving otherwise."""

from __future__ import annotations

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from elastocap import Camera
from elastocap.tracking.depth_weights import depth_edges, depth_images, rust_step, straddling, track_step_by_depth
from elastocap.tracking.flags import TrackFlag

W, H = 400, 320
SIZE = 15
CAMERA = Camera("c", [[600.0, 0.0, W / 2], [0.0, 600.0, H / 2], [0.0, 0.0, 1.0]], None, np.eye(3), np.zeros(3), W, H)
TORSO_Z, LIMB_Z = 2.3, 2.0
LIMB = (150.0, 172.0)  # the limb's columns on the previous frame (22 px wide, a forearm)
LIMB_MOTION = np.array([9.0, 5.0])
TORSO_MOTION = np.array([-2.0, 1.0])


def _texture(seed: int) -> np.ndarray:
    noise = np.random.default_rng(seed).normal(0.0, 1.0, (H + 80, W + 80)).astype(np.float32)
    image = cv2.GaussianBlur(noise, (0, 0), 1.5)
    return 128.0 + 50.0 * image / image.std()


def _frame(torso: np.ndarray, limb: np.ndarray, shift_torso: np.ndarray, shift_limb: np.ndarray) -> np.ndarray:
    """The torso texture moved by ``shift_torso`` with the limb strip (its own texture moved
    by ``shift_limb``) in front."""

    def moved(t: np.ndarray, s: np.ndarray) -> np.ndarray:
        m = np.array([[1.0, 0.0, s[0] - 40], [0.0, 1.0, s[1] - 40]])
        return cv2.warpAffine(t, m, (W, H), flags=cv2.INTER_CUBIC)

    image = moved(torso, shift_torso)
    u = np.arange(W)[None, :].repeat(H, 0)
    on = (u >= LIMB[0] + shift_limb[0]) & (u < LIMB[1] + shift_limb[0])
    image[on] = moved(limb, shift_limb)[on]
    return np.ascontiguousarray(image, dtype=np.float32)


def _back(uv: np.ndarray, z: np.ndarray) -> np.ndarray:
    return np.column_stack([(uv[:, 0] - W / 2) * z / 600.0, (uv[:, 1] - H / 2) * z / 600.0, z])


def _scene():
    torso, limb = _texture(1), _texture(2)
    previous = _frame(torso, limb, np.zeros(2), np.zeros(2))
    current = _frame(torso, limb, TORSO_MOTION, LIMB_MOTION)
    # Limb points 3.5 px inside its edges and on its axis; torso points on a 6 px grid
    # where the torso is seen on both frames, beside the limb and away from it.
    v = np.arange(100.0, 221.0, 6.0)
    limb_u = np.array([LIMB[0] + 3.5, 0.5 * (LIMB[0] + LIMB[1]), LIMB[1] - 3.5])
    lu, lv = np.meshgrid(limb_u, v)
    columns = np.arange(99.0, 280.0, 6.0)
    tu, tv = np.meshgrid(columns[(columns < LIMB[0] - 1) | (columns > LIMB[1] + 1)], v)
    limb_uv = np.column_stack([lu.ravel(), lv.ravel()])
    torso_uv = np.column_stack([tu.ravel(), tv.ravel()])
    uv = np.concatenate([limb_uv, torso_uv])
    on_limb = np.arange(len(uv)) < len(limb_uv)
    z = np.where(on_limb, LIMB_Z, TORSO_Z)
    motion = np.where(on_limb[:, None], LIMB_MOTION, TORSO_MOTION)
    # A velocity history: the linear prediction is right, so only the template matters.
    x_last = _back(uv, z)
    x_before = _back(uv - motion, z)
    return previous, current, uv[:, None], (uv - motion)[:, None], uv + motion, x_last, x_before, on_limb


OPTIONS = dict(size=SIZE, radius=6, min_correlation=0.5, forward_backward=0.6, min_texture=0.0, max_iterations=8)


def _held(pos: np.ndarray, flags: np.ndarray, corr: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Tracked at the tracker's correlation (0.75) within 0.5 px of the truth."""
    return (flags[:, 0] == TrackFlag.TRACKED) & (corr[:, 0] >= 0.75) & (np.linalg.norm(pos[:, 0] - truth, axis=1) < 0.5)


def test_limb_points_on_its_edge_are_held_with_the_depth_edges_and_lost_without():
    previous, current, last, before, truth, x_last, x_before, on_limb = _scene()
    masks = [np.ones((H, W), bool)]
    ones = [np.ones((H, W), np.float32)]
    step = rust_step([previous], [current])
    pos, flags, _, corr = step(last, before, weights=(ones, ones), **OPTIONS)
    plain = _held(pos, flags, corr, truth)
    edges = depth_edges([CAMERA], last, x_last, x_before, masks, masks, reach=12.0, tolerance=6.0, band=4)
    dpos, dflags, _, dcorr = track_step_by_depth(step, last, before, (ones, ones), edges, half=SIZE // 2, width=0.5,
                                                 **OPTIONS)
    cut = _held(dpos, dflags, dcorr, truth)
    axis = on_limb & (np.abs(last[:, 0, 0] - 0.5 * sum(LIMB)) < 1)
    rim = on_limb & ~axis
    assert plain[rim].mean() < 0.35  # the patch straddles onto the torso, which moves otherwise
    # (The rest are lost by the box search, whose NCC the Rust step does not weigh.)
    assert cut[rim].mean() > 0.85
    error = np.linalg.norm(dpos[rim & cut, 0] - truth[rim & cut], axis=1)
    assert np.median(error) < 0.1
    # The torso's points are not harmed, nor the limb's axis.
    assert cut[~on_limb].sum() >= plain[~on_limb].sum()
    u0, u1 = last[:, 0, 0], truth[:, 0]
    clear = ~on_limb & ((u0 < LIMB[0] - 8) | (u0 > LIMB[1] + 8)) & ((u1 < LIMB[0] + LIMB_MOTION[0] - 8)
                                                                   | (u1 > LIMB[1] + LIMB_MOTION[0] + 8))
    assert cut[clear].mean() > 0.97
    assert cut[axis].mean() >= plain[axis].mean()
    # Views with no depth edge in their patch are matched exactly as before.
    far = ~on_limb & (np.abs(last[:, 0, 0] - 0.5 * sum(LIMB)) > 40)
    np.testing.assert_array_equal(dpos[far], pos[far])


def test_depth_images_label_pixels_by_the_nearest_held_view():
    previous, current, last, before, truth, x_last, x_before, on_limb = _scene()
    mask = np.ones((H, W), bool)
    mask[:, :50] = False
    depth = depth_images([CAMERA], last, x_last, [mask], reach=12.0)[0]
    # At the views themselves: their own depth.
    pix = np.rint(last[:, 0]).astype(int)
    np.testing.assert_allclose(depth[pix[:, 1], pix[:, 0]], np.where(on_limb, LIMB_Z, TORSO_Z), rtol=1e-6)
    # Outside the mask, and far from every view: unknown.
    assert np.isnan(depth[:, :50]).all() and np.isnan(depth[5, 395])
    # A view not held in the camera labels nothing.
    held = last.copy()
    held[on_limb] = np.nan
    without = depth_images([CAMERA], held, x_last, [mask], reach=12.0)[0]
    assert np.nanmax(np.abs(without - TORSO_Z)) < 1e-6


@settings(max_examples=30, deadline=None)
@given(st.floats(0.5, 3.0), st.floats(-1.0, 1.0), st.integers(2, 9))
def test_straddling_is_a_depth_difference_beyond_the_tolerance_within_the_patch(z, offset, half):
    depth = np.full((60, 60), z, np.float32)
    depth[:, 40:] = z + offset
    uv = np.array([[30.0, 30.0], [20.0, 30.0]])
    got = straddling(depth, uv, np.array([z, z]), half, 0.1)
    assert got[0] == (abs(offset) > 0.1 + 1e-6 and 30 + half >= 40)
    assert not got[1] or 20 + half >= 40
    # NaN depths (nothing known) never straddle.
    assert not straddling(np.full((60, 60), np.nan, np.float32), uv, np.array([z, z]), half, 0.1).any()


def test_the_weighted_box_search_holds_the_limbs_edge_points_the_plain_box_refuses():
    # The same cut, with the box search weighed as the match is (`weighted_box`, settings.WEIGHTED_BOX):
    # the rim's points the plain box search refused are held too, the others as they were.
    previous, current, last, before, truth, x_last, x_before, on_limb = _scene()
    masks = [np.ones((H, W), bool)]
    ones = [np.ones((H, W), np.float32)]
    step = rust_step([previous], [current])
    edges = depth_edges([CAMERA], last, x_last, x_before, masks, masks, reach=12.0, tolerance=6.0, band=4)
    runs = [track_step_by_depth(step, last, before, (ones, ones), edges, half=SIZE // 2, width=0.5,
                                **OPTIONS, weighted_box=weighted) for weighted in (False, True)]
    (pos, flags, _, corr), (wpos, wflags, _, wcorr) = runs
    cut, boxed = _held(pos, flags, corr, truth), _held(wpos, wflags, wcorr, truth)
    axis = on_limb & (np.abs(last[:, 0, 0] - 0.5 * sum(LIMB)) < 1)
    rim = on_limb & ~axis
    assert boxed[rim].mean() > cut[rim].mean() and boxed[rim].mean() > 0.95
    assert np.median(np.linalg.norm(wpos[rim & boxed, 0] - truth[rim & boxed], axis=1)) < 0.1
    assert boxed[~on_limb].sum() >= cut[~on_limb].sum() and boxed[axis].mean() >= cut[axis].mean()
    # Views with no depth edge in their patch (weights all 1): the plain search, to the bit.
    far = ~on_limb & (np.abs(last[:, 0, 0] - 0.5 * sum(LIMB)) > 40)
    np.testing.assert_array_equal(wpos[far], pos[far])
