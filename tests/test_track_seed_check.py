"""A seed's depth re-matched with a small window (``tracking.seed_check.rematch_depth``,
``settings.SEED_DEPTH_SIZE``): on convex textured balls a large window puts seeds behind
the surface; the small window's seeds lie nearer it, the seed's own view never moves, no
view moves farther than the reach, and views that were not matched stay unmatched."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import elastocap
from elastocap.tracking import settings
from elastocap.tracking.seed_check import rematch_depth
from elastocap.tracking.seeding import seed_points
from elastocap.tracking.views import intersect_views
from track_scene import _poses, write_scene


@pytest.fixture(scope="module")
def seeded(tmp_path_factory: pytest.TempPathFactory):
    """Frame 0 of the balls scene seeded with the tracker's 15 px window, the depth check off."""
    root = tmp_path_factory.mktemp("seed_check_scene")
    write_scene(root, frames=1, cameras=6, seed=5, size=(320, 240), points=100)
    capture = elastocap.Capture.open(root)
    cameras = capture.rig.cameras
    frame = capture.frames[0]
    grey = [np.ascontiguousarray(cv2.cvtColor(capture.image(c.name, frame), cv2.COLOR_RGB2GRAY).astype(np.float32))
            for c in cameras]
    masks = [capture.mask(c.name, frame) for c in cameras]
    views = seed_points(grey, masks, cameras, np.zeros((0, len(cameras), 2)), spacing=8, size=15, min_correlation=0.75,
                        min_views=2, min_texture=1.0, tolerance=2.0, max_residual=2.0, floor=settings.FLOOR)
    return grey, masks, cameras, views


def _seed_camera(views: np.ndarray) -> np.ndarray:
    on_centre = np.isfinite(views).all(axis=2) & (np.abs(views - np.round(views)) < 1e-9).all(axis=2)
    return np.argmax(on_centre, axis=1)


def _behind(cameras, views: np.ndarray) -> np.ndarray:
    """(M,) signed distance (m) of each seed's intersection from the nearest ball's
    surface: positive inside the ball (behind the surface seen)."""
    cov = np.where(np.isfinite(views)[..., None], np.eye(2) * 0.01, np.nan)
    x = intersect_views(cameras, views, cov, max_residual=2.0, floor=settings.FLOOR)[0]
    inside = np.stack([r - np.linalg.norm(x - c, axis=1) for _, c, r in _poses(0, 1.0)], axis=1)
    return inside[np.arange(len(x)), np.argmin(np.abs(inside), axis=1)]


def test_the_small_window_brings_seeds_on_convex_balls_nearer_their_surface(seeded):
    grey, _, cameras, views = seeded
    assert len(views) >= 100
    k = _seed_camera(views)
    small = views.copy()
    for cam in np.unique(k):
        rows = k == cam
        small[rows] = rematch_depth(grey, cameras, int(cam), views[rows], size=7, min_correlation=0.75, min_texture=1.0)
    before, after = _behind(cameras, views), _behind(cameras, small)
    ok = np.isfinite(before) & np.isfinite(after)
    assert ok.mean() > 0.95
    # The large window's seeds lie behind the surface (the patch's mean depth on a ball) ...
    assert np.median(before[ok]) > 0
    # ... the small window's nearer it, by most of the bias.
    assert abs(np.median(after[ok])) < 0.6 * np.median(before[ok])
    assert np.mean(np.abs(after[ok])) < np.mean(np.abs(before[ok]))


def test_the_seed_view_stays_and_no_view_moves_past_the_reach(seeded):
    grey, _, cameras, views = seeded
    k = _seed_camera(views)
    cam = int(np.bincount(k).argmax())
    rows = views[k == cam]
    # A view that is not matched stays NaN; a view knocked 3 px along the line is out of the
    # small window's reach and keeps its (wrong) start.
    rows[0, (cam + 3) % len(cameras)] = np.nan
    out = rematch_depth(grey, cameras, cam, rows, size=7, min_correlation=0.75, min_texture=1.0, reach=0.5)
    assert np.array_equal(out[:, cam], rows[:, cam])
    assert np.array_equal(np.isnan(out), np.isnan(rows))
    moved = np.linalg.norm(np.nan_to_num(out - rows), axis=2)
    assert moved.max() <= 0.5 + 1e-9
    assert (moved > 0.01).sum() >= len(rows) // 4  # it does re-match
    assert rematch_depth(grey, cameras, cam, rows[:0], size=7, min_correlation=0.75, min_texture=1.0).shape == (0, len(cameras), 2)


def test_off_by_default():
    assert settings.SEED_DEPTH_SIZE == 0
