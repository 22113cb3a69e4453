"""Tracks followed backward from the frame they were seeded on (issue 15, branch trackfit5):
a point seeded after the first frame gets the part of its trajectory before it, against
the truth, with the forward part unchanged."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

import elastocap
from elastocap import InvalidInputError, load_tracks
from elastocap.tracking import TrackFlag, track_points
from elastocap.tracking.backward import track_backward
from elastocap.tracking.tracks import Tracks
from track_scene import write_scene

FRAMES = 10


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("backward")
    truth = write_scene(root, frames=FRAMES, cameras=6, seed=1, points=2500)
    capture = elastocap.Capture.open(root)
    forward = track_points(capture, reseed_every=5)
    both = track_points(capture, reseed_every=5, backward=FRAMES)
    return capture, truth, forward, both


def _rigid(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotation and centres taking the points ``a`` onto ``b`` (Kabsch)."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T, ca, cb


def test_a_point_seeded_later_is_followed_back_to_where_it_was_first_seen(scene):
    capture, truth, forward, both = scene
    tracked, after = forward.flags == TrackFlag.TRACKED, both.flags == TrackFlag.TRACKED
    # The forward part is the forward pass's, to the bit, and nothing else is added after
    # a track's seeding frame.
    assert np.array_equal(both.ids, forward.ids)
    assert np.array_equal(both.positions[tracked], forward.positions[tracked])
    assert np.array_equal(both.covariances[tracked], forward.covariances[tracked])
    first = np.where(tracked.any(axis=0), tracked.argmax(axis=0), -1)
    later = np.arange(len(forward.frames))[:, None] >= first[None, :]
    assert np.array_equal(after & later, tracked)
    assert np.array_equal(both.flags[later], forward.flags[later])
    seeded = np.flatnonzero(first == 5)
    assert len(seeded) >= 15
    # Each ball moves rigidly: where a point seeded at frame 5 truly was at an earlier frame
    # is its seeded position carried by its ball's motion between the two frames.
    _, nearest = cKDTree(truth.positions[5]).query(forward.positions[5, seeded])
    part = truth.part[nearest]
    errors = []
    for j in range(5):
        for p in (0, 1):
            on = truth.part == p
            rotation, ca, cb = _rigid(truth.positions[5][on], truth.positions[j][on])
            rows = seeded[(part == p) & after[j, seeded]]
            expected = (forward.positions[5, rows] - ca) @ rotation.T + cb
            errors.append(np.linalg.norm(both.positions[j, rows] - expected, axis=1))
    errors = np.concatenate(errors)
    assert len(errors) >= 3 * len(seeded)
    assert np.median(errors) < 0.002 and np.percentile(errors, 90) < 0.01
    # Back to the frame it became visible (in two cameras or more, continuously up to its
    # seeding): most of those visible from the first frame are followed back to it.
    seen = truth.visible[:6, :, nearest].sum(axis=1) >= 2
    since = np.array([5 - np.argmin(np.append(seen[::-1, i], False)) + 1 for i in range(len(seeded))])
    reached = np.where(after[:, seeded].any(axis=0), after[:, seeded].argmax(axis=0), -1)
    assert (since == 0).sum() >= 10
    assert np.mean(reached[since == 0] == 0) >= 0.7
    assert (reached >= since).all()


def test_the_tracks_followed_backward_are_written_once_and_read_back(scene, tmp_path):
    capture, truth, forward, both = scene
    written = track_points(capture, reseed_every=5, backward=FRAMES, out=tmp_path)
    read = load_tracks(tmp_path)
    for tracks in (written, read):
        assert np.array_equal(tracks.ids, both.ids)
        assert np.array_equal(tracks.flags, both.flags)
        assert np.array_equal(tracks.positions, both.positions, equal_nan=True)
        assert np.array_equal(tracks.views, both.views, equal_nan=True)
    assert (tmp_path / "tracks" / "backward.json").exists()
    # Asked again, the folder is read back, not followed backward a second time.
    again = track_points(capture, reseed_every=5, backward=FRAMES, out=tmp_path)
    assert np.array_equal(again.positions, both.positions, equal_nan=True)
    # Its forward state does not know the backward positions: no more frames on it.
    # (The last frame's file removed: resuming would track that frame again.)
    sorted((tmp_path / "tracks").glob("[0-9]*.npz"))[-1].unlink()
    with pytest.raises(InvalidInputError, match="followed backward"):
        track_points(capture, reseed_every=5, backward=FRAMES, out=tmp_path)


def test_backward_refuses_bad_input(scene):
    capture, truth, forward, both = scene
    with pytest.raises(InvalidInputError, match="backward"):
        track_points(capture, backward=-1)
    bare = Tracks(forward.frames, forward.ids, forward.positions, forward.covariances, forward.flags)
    with pytest.raises(InvalidInputError, match="views"):
        track_backward(capture, bare, reach=3, spacing=10, size=15, radius=6, min_correlation=0.75, options={})
