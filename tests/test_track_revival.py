"""Revival's acceptance (issue 15, branch track9): a revived point must intersect near its
predicted position: a match that converged to a nearby wrong place keeps its error for the
point's whole life (its anchor holds it there)."""

from __future__ import annotations

import numpy as np
import pytest

import elastocap
from elastocap.tracking import TrackFlag, settings, track_points
from elastocap.tracking.accuracy import track_accuracy
from elastocap.tracking.filters import pixel_size
from elastocap.tracking.revival import Lost
from track_scene import blank_band, write_scene


@pytest.fixture(scope="module")
def banded(tmp_path_factory: pytest.TempPathFactory):
    # The points seen only in a band blanked on frames 3 and 4 lose every view there and are
    # looked for again from frame 5 (tests/test_track.py: with revival they come back right).
    root = tmp_path_factory.mktemp("revival_band")
    truth = write_scene(root, frames=8, cameras=6, seed=2, points=2500)
    capture = elastocap.Capture.open(root)
    blank_band(root, capture.rig.names, (3, 4))
    return capture, truth


def _revived(tracks) -> np.ndarray:
    ok = tracks.flags == TrackFlag.TRACKED
    return ok[2] & ~ok[3] & ~ok[4] & ok[5:].any(axis=0)


def test_revival_accepts_only_intersections_near_the_prediction(banded, monkeypatch):
    # The predictions moved by a known distance (pixel equivalents) along one direction:
    # within the search box the anchors are still found where the points are, so the
    # intersection lands that far from the prediction. Moved 6 px-eq, it is refused with
    # the reach at 4 and taken at 8 (it is the reach that refuses, not the search); moved
    # 1.5 px-eq, it is taken at 4. Taken points are right.
    capture, truth = banded
    cameras = capture.rig.cameras
    direction = cameras[0].R[0]  # camera 0's image x axis, in world coordinates
    original = Lost.predict
    counts = {}
    for offset, reach in ((6.0, 4.0), (6.0, 8.0), (1.5, 4.0)):
        def moved(self, rows, now, offset=offset, **kwargs):
            out = original(self, rows, now, **kwargs)
            size = pixel_size(cameras, out, np.ones((len(out), len(cameras)), bool))
            return out + offset * size[:, None] * direction

        monkeypatch.setattr(Lost, "predict", moved)
        monkeypatch.setattr(settings, "REVIVE_REACH", reach)
        tracks = track_points(capture, revive=True)
        back = _revived(tracks)
        counts[offset, reach] = int(back.sum())
        if back.any():
            acc = track_accuracy(tracks, cameras, truth.positions, truth.visible, truth.part)
            assert np.nanmedian(acc.error[5:, back]) < 0.2
    assert counts[6.0, 4.0] == 0
    assert counts[6.0, 8.0] >= 10
    assert counts[1.5, 4.0] >= 10


def test_a_lost_point_is_predicted_by_its_neighbours_rigid_motion(monkeypatch):
    # A limb (points on a cylinder) swings 30 degrees about a joint at its top while one of
    # its points is lost: the point predicted by the rigid motion of its tracked neighbours
    # lands where it is; their median shift alone misses by the rotation's lever arm.
    rng = np.random.default_rng(3)
    angle = rng.uniform(0, 2 * np.pi, 300)
    along = rng.uniform(0.0, 0.6, 300)
    limb = np.column_stack([0.05 * np.cos(angle), -along, 0.05 * np.sin(angle)])
    turn = np.radians(30.0)
    r = np.array([[1, 0, 0], [0, np.cos(turn), -np.sin(turn)], [0, np.sin(turn), np.cos(turn)]])
    moved = limb @ r.T
    lost = Lost(window=15)
    lost.remember(0, limb)
    lost.remember(1, limb)
    died = np.zeros(len(limb), bool)
    died[:5] = True
    lost.record(died, limb, frame=2)
    now = np.where(died[:, None], np.nan, moved)
    errors = {}
    for rigid in (True, False):
        monkeypatch.setattr(settings, "REVIVE_RIGID", rigid)
        predicted = lost.predict(np.arange(5), now)
        errors[rigid] = np.linalg.norm(predicted - moved[:5], axis=1)
    assert errors[True].max() < 1e-9
    # The lever arm from the neighbours' centre is millimetres to centimetres here.
    assert errors[False].max() > 1e-3


def _rotation(axis: int, degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    i, j = [k for k in range(3) if k != axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def test_a_lost_point_is_predicted_from_its_own_parts_motion(monkeypatch):
    # Two rigid patches (an arm and the torso, 1 cm grids). Since the points were seeded
    # the arm has swung down by the torso: on the frame before the loss its edge points
    # lie 1 cm from the torso's, so half the nearest points then are the torso's. While
    # the edge points are lost the arm swings on 25 degrees and the torso turns the other
    # way: the nearest points' rigid motion mixes the two and misses; the neighbours whose
    # distance to the point kept since the seeding (the own-part rule) are the arm's, and
    # their rigid motion lands on the point exactly.
    g = np.stack(np.meshgrid(np.arange(8), np.arange(8), indexing="ij"), -1).reshape(-1, 2) * 0.01
    arm0 = np.column_stack([g[:, 0] + 0.2, g[:, 1], np.zeros(len(g))])     # seeded 20 cm away
    torso0 = np.column_stack([-g[:, 0] - 0.01, g[:, 1], np.zeros(len(g))])
    arm_then = arm0 - [0.2, 0, 0]                                             # came close: 1 cm gap
    torso_then = torso0.copy()
    pivot = np.array([0.07, 0.035, 0.0])
    arm_now = (arm_then - pivot) @ _rotation(1, 25).T + pivot
    torso_now = torso_then @ _rotation(2, -10).T + [0, 0, 0.02]
    seed = np.concatenate([arm0, torso0])
    then = np.concatenate([arm_then, torso_then])
    truth_now = np.concatenate([arm_now, torso_now])
    edge = np.flatnonzero(np.isclose(arm_then[:, 0], 0.0))                    # arm points by the torso
    lost = Lost(window=15)
    lost.remember(0, seed)
    lost.remember(4, then)
    died = np.zeros(len(then), bool)
    died[edge] = True
    lost.record(died, then, frame=5)
    now = np.where(died[:, None], np.nan, truth_now)
    seeded = np.zeros(len(then), np.int64)
    pixel = np.full(len(edge), 0.003)   # 3 mm a pixel: the torso's points moved by 20 cm = 67 px
    errors = {}
    for own in (False, True):
        monkeypatch.setattr(settings, "REVIVE_OWN_PART", own)
        monkeypatch.setattr(settings, "REVIVE_RIGID", True)
        predicted = lost.predict(edge, now, seeded=seeded, seeds={0: seed}, pixel=pixel)
        errors[own] = np.linalg.norm(predicted - truth_now[edge], axis=1)
    assert errors[True].max() < 1e-9
    assert errors[False].max() > 0.01   # a grid step (2.8 cm here)


def _textured(seed: int, shape=(120, 160)) -> np.ndarray:
    import cv2

    noise = np.random.default_rng(seed).uniform(0, 255, (shape[0] // 3, shape[1] // 3)).astype(np.float32)
    return cv2.GaussianBlur(cv2.resize(noise, shape[::-1], interpolation=cv2.INTER_CUBIC), (0, 0), 0.7)


def test_an_anchor_turned_with_its_part_is_found_by_its_warped_patch():
    # One camera's image turned by 35 degrees and foreshortened by 0.7 along one axis about a
    # point between the frame its anchor patches were cut on and now: the plain anchor search
    # (a translation-only box search first) loses most of them; warped by the known affine
    # they are found where the points went, within 0.05 px (the warped patch's corners
    # fall outside what was cut and weigh nothing, so a few are still missed). With the identity the warped
    # search is the plain one, to the bit.
    import cv2
    from types import SimpleNamespace

    from elastocap.tracking.anchors import Anchors
    from elastocap.tracking.revival_warp import warped_search

    before = _textured(4)
    a = np.radians(35.0)
    affine = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) @ np.diag([1.0, 0.7])
    pivot = np.array([80.0, 60.0])
    warp = np.hstack([affine, (pivot - affine @ pivot)[:, None]])
    after = cv2.warpAffine(before, warp, before.shape[::-1], flags=cv2.INTER_CUBIC)
    grid = np.stack(np.meshgrid(np.arange(55.0, 106.0, 10.0), np.arange(40.0, 81.0, 10.0)), -1).reshape(-1, 2) + 0.3
    n = len(grid)
    anchors = Anchors(1, 15)
    anchors.cut([before], grid[:, None], np.ones((n, 1), bool), 0)
    moved = (grid - pivot) @ affine.T + pivot
    starts = (moved + [1.5, -1.0])[:, None]  # a prediction a pixel or two off
    tracker = SimpleNamespace(anchors=anchors, min_correlation=0.75, o={"forward_backward": 0.6}, keep_texture=0.0)
    where = np.ones((n, 1), bool)
    rows = np.arange(n)
    kwargs = dict(radius=settings.REVIVE_RADIUS, min_correlation=0.75, box_correlation=min(0.75, settings.BOX_CORRELATION),
                  forward_backward=0.6, min_texture=0.0, max_iterations=settings.STEP_ITERATIONS)
    plain, _ = anchors.search([after], starts, where, **kwargs)
    same, _ = warped_search(tracker, [after], starts, where, rows, np.broadcast_to(np.eye(2), (n, 1, 2, 2)))
    np.testing.assert_array_equal(same, plain)
    warped, cov = warped_search(tracker, [after], starts, where, rows, np.broadcast_to(affine, (n, 1, 2, 2)))
    found = np.isfinite(warped[:, 0, 0])
    assert found.mean() >= 0.8
    assert np.isfinite(plain[:, 0, 0]).mean() <= 0.2
    assert np.abs(warped[found, 0] - moved[found]).max() < 0.05
    assert np.isfinite(cov[found]).all()


def test_anchors_cut_again_at_the_loss_still_bring_the_points_back_right(banded, monkeypatch):
    # With the anchors of a lost point cut again from its last tracked frame
    # (settings.REVIVE_LAST_PATCH), the band's points come back under their ids where they
    # are: a patch cut at the wrong place or from the wrong image would revive them off, or
    # not at all.
    capture, truth = banded
    monkeypatch.setattr(settings, "REVIVE_LAST_PATCH", True)
    tracks = track_points(capture, revive=True)
    back = _revived(tracks)
    assert back.sum() >= 10
    acc = track_accuracy(tracks, capture.rig.cameras, truth.positions, truth.visible, truth.part)
    assert np.nanmedian(acc.error[5:, back]) < 0.2
