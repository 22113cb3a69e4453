"""The anchor's richer correction smoothed over frames (``settings.ANCHOR_REFINE_SMOOTH``):
the affine centre plus the richer model's departure from it, exponentially smoothed from the
patch's cut on. The richer model's centre is noisier than the affine one frame to frame
(8 more unknowns); its departure from the affine centre (the affine model's slide on a
turning, shaded patch) changes slowly. Unsmoothed, that noise ended tracks in the trajectory
checks (benches/README.md, lsm29)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st

from elastocap.tracking import settings
from elastocap.tracking.anchors import Anchors

SIZE = 15
REFINE = {"warp": "quadratic", "gain_gradient": True, "warp_sigma": 0.1, "gain_sigma": 0.05, "fallback": True}


@pytest.fixture
def restore() -> object:
    saved = settings.ANCHOR_REFINE, settings.ANCHOR_REFINE_SMOOTH
    yield None
    settings.ANCHOR_REFINE, settings.ANCHOR_REFINE_SMOOTH = saved


def _texture(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A smooth random texture (blurred at 2 px, 40 grey levels RMS) and 64 points inside it."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.normal(0, 1, (200, 200)).astype(np.float32), (0, 0), 2.0)
    tex = (128 + 40 * tex / tex.std()).astype(np.float32)
    grid = np.arange(30.0, 171.0, 20.0)
    points = np.stack(np.meshgrid(grid, grid), axis=-1).reshape(-1, 2) + rng.uniform(-0.5, 0.5, (64, 2))
    return tex, points


def _corrected(tex: np.ndarray, points: np.ndarray, frames: list[np.ndarray], refine: object, smooth: float, *,
               start: np.ndarray | None = None) -> np.ndarray:
    """(F, N, 2) the anchors' corrections of ``points`` (cut in ``tex``) in each of ``frames``,
    started at ``start`` (default: where the points are), NaN where the anchor did not match."""
    start = points if start is None else start
    settings.ANCHOR_REFINE, settings.ANCHOR_REFINE_SMOOTH = refine, smooth
    anchors = Anchors(1, SIZE)
    anchors.cut([tex], points[:, None], np.ones((len(points), 1), bool), 0)
    out = []
    for image in frames:
        uv, stale = anchors.correct([image], start[:, None].copy(), min_correlation=0.7, reach=1.5, min_texture=1.0)
        out.append(np.where(stale[..., None], np.nan, uv)[:, 0])
    return np.array(out)


def test_a_steady_departure_is_kept_whole(restore: object) -> None:
    # The same image every frame: the departure does not change, and the smoothed
    # correction is the richer centre on every frame (the first departure starts the
    # smoothing; a constant one stays).
    tex, points = _texture(1)
    # A slight affine map about the image's centre (a point p of ``tex`` shows at A p + t).
    a = np.array([[1.02, 0.01], [-0.01, 0.99]])
    t = np.array([100.0, 100.0]) - a @ [100.0, 100.0] + [0.3, -0.2]
    shifted = cv2.warpAffine(tex, np.column_stack([a, t]).astype(np.float32), (200, 200), flags=cv2.INTER_CUBIC)
    moved = points @ a.T + t
    rich = _corrected(tex, points, [shifted] * 4, REFINE, 1.0, start=moved)
    smoothed = _corrected(tex, points, [shifted] * 4, REFINE, 0.3, start=moved)
    assert np.isfinite(rich).all(axis=2).sum() >= 0.9 * rich[..., 0].size
    np.testing.assert_allclose(smoothed, rich, atol=1e-9)


def test_off_without_the_richer_model(restore: object) -> None:
    tex, points = _texture(2)
    noisy = [tex + np.random.default_rng(k).normal(0, 2, tex.shape).astype(np.float32) for k in range(3)]
    np.testing.assert_array_equal(_corrected(tex, points, noisy, None, 0.3), _corrected(tex, points, noisy, None, 1.0))


@hsettings(max_examples=3, deadline=None)
@given(st.integers(0, 1000))
def test_smoothing_cuts_the_richer_centres_noise(seed: int) -> None:
    # A texture that does not move, new image noise (2 grey levels) every frame: every
    # centre jitters; the richer model's (quadratic warp, gain gradient) more than the
    # affine one's. Smoothed, the correction jitters about as little as the affine one.
    saved = settings.ANCHOR_REFINE, settings.ANCHOR_REFINE_SMOOTH
    try:
        tex, points = _texture(seed)
        rng = np.random.default_rng(seed + 1)
        frames = [tex + rng.normal(0, 2.0, tex.shape).astype(np.float32) for _ in range(12)]

        def jitter(refine: object, smooth: float) -> float:
            step = np.linalg.norm(np.diff(_corrected(tex, points, frames, refine, smooth), axis=0), axis=2)
            return float(np.nanmedian(step))

        affine, rich, smoothed = jitter(None, 1.0), jitter(REFINE, 1.0), jitter(REFINE, 0.3)
        # (Measured: affine 0.019 px, richer 0.034-0.038, smoothed 0.020-0.021.)
        assert rich > 1.4 * affine
        assert smoothed < 0.7 * rich
        assert smoothed < 1.25 * affine
    finally:
        settings.ANCHOR_REFINE, settings.ANCHOR_REFINE_SMOOTH = saved


def test_the_smoothing_restarts_when_the_patch_is_cut_again(restore: object) -> None:
    tex, points = _texture(4)
    settings.ANCHOR_REFINE, settings.ANCHOR_REFINE_SMOOTH = REFINE, 0.3
    anchors = Anchors(1, SIZE)
    where = np.ones((len(points), 1), bool)
    anchors.cut([tex], points[:, None], where, 0)
    anchors.correct([tex], points[:, None].copy(), min_correlation=0.7, reach=1.5, min_texture=1.0)
    assert np.isfinite(anchors.offset[:, 0, 0]).mean() > 0.9
    anchors.cut([tex], points[:, None], where, 1)
    assert np.isnan(anchors.offset).all()
