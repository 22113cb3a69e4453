"""New points that hold no narrow stereo pair, dropped as they are seeded
(``settings.SEED_NEEDS_PAIR``, :mod:`elastocap.tracking.seed_pairs`)."""

from __future__ import annotations

import numpy as np
import pytest

from elastocap.synth.textured import stereo_rig
from elastocap.tracking.seed_pairs import drop_unpaired, nearest_cameras, paired
from elastocap.tracking.step import FrameTracker


def test_the_textured_rigs_nearest_cameras_are_its_stereo_pairs():
    rig, groups = stereo_rig()
    nearest = nearest_cameras(rig.cameras)
    # Four pairs ~90 degrees apart around the figure: each camera's nearest is its pair's other.
    index = {name: k for k, name in enumerate(rig.names)}
    assert len(groups) == 4
    for a, b in groups:
        assert nearest[index[a]] == index[b] and nearest[index[b]] == index[a]


def test_paired_asks_for_a_camera_and_its_partner():
    nearest = np.array([1, 0, 3, 2, 5, 4, 7, 6])
    views = np.zeros((6, 8), bool)
    views[0, [0, 1]] = True  # a pair
    views[1, [0, 3]] = True  # two cameras of two pairs (a wide-baseline match)
    views[2, [4, 7]] = True
    views[3, [2, 3, 4]] = True  # a pair and another camera
    views[4, [1, 2, 5]] = True  # three cameras, no two a pair
    np.testing.assert_array_equal(paired(views, nearest), [True, False, False, True, False, False])
    with pytest.raises(ValueError):
        paired(views[:, :6], nearest)


def test_only_the_new_unpaired_points_are_dropped_and_the_state_follows():
    cameras = stereo_rig()[0].cameras
    assert list(nearest_cameras(cameras)) == [1, 0, 3, 2, 5, 4, 7, 6]
    tracker = object.__new__(FrameTracker)
    tracker.cameras = cameras
    c, old, new = len(cameras), 4, 5
    n = old + new
    uv = np.full((n, c, 2), np.nan)
    uv[0, [0, 3]] = 10.0  # an old point without a pair (a revival, a re-acquisition) stays
    uv[1:old, [2, 3]] = 20.0
    uv[old + 0, [0, 1]] = 30.0
    uv[old + 1, [4, 7]] = 40.0  # new, unpaired
    uv[old + 2, [6, 7, 1]] = 50.0
    uv[old + 3, [1, 6]] = 60.0  # new, unpaired
    uv[old + 4, [4, 5]] = 70.0
    x = np.arange(n * 3, dtype=float).reshape(n, 3)
    xcov = np.tile(np.eye(3), (n, 1, 1)) * np.arange(n)[:, None, None]
    flags = np.arange(n, dtype=np.uint8)
    flags2d = np.tile(np.arange(n, dtype=np.uint8)[:, None], (1, c))
    # The tracker's state as add_new_points leaves it: grown by the new rows (NaN).
    tracker.uv = np.concatenate([uv[:old] + 1.0, np.full((new, c, 2), np.nan)])
    tracker.x_last = np.concatenate([x[:old] + 1.0, np.full((new, 3), np.nan)])
    tracker.x_before = np.concatenate([x[:old] + 2.0, np.full((new, 3), np.nan)])
    before = tracker.uv[:old].copy()
    out = drop_unpaired(tracker, old, uv, x, xcov, flags, flags2d)
    keep = np.array([0, 1, 2, 3, old + 0, old + 2, old + 4])
    for got, want in zip(out, (uv, x, xcov, flags, flags2d)):
        np.testing.assert_array_equal(got, want[keep])
    assert len(tracker.uv) == len(tracker.x_last) == len(tracker.x_before) == len(keep)
    np.testing.assert_array_equal(tracker.uv[:old], before)
    np.testing.assert_array_equal(tracker.x_before[:old], x[:old] + 2.0)
    # Nothing new, or nothing to drop: the arrays come back as they were.
    same = drop_unpaired(tracker, len(keep), *out)
    assert all(a is b for a, b in zip(same, out))
