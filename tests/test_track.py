"""Point tracking (issue 15): tracked positions against ground truth on a textured scene with
self-occlusion, the checks that catch their constructed failures, resume, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import elastocap
from elastocap import _core
from elastocap.pipeline.cli import main
from elastocap.tracking import TrackFlag, Tracks, load_tracks, track_points
from elastocap.tracking.accuracy import track_accuracy
from elastocap.tracking.filters import trajectory_flags
from track_scene import blank_band, write_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("track_scene")
    truth = write_scene(root, frames=8, cameras=6, seed=1, points=2500)
    return root, truth


@pytest.fixture(scope="module")
def tracked(scene):
    root, truth = scene
    capture = elastocap.Capture.open(root)
    tracks = track_points(capture)
    return capture, tracks, track_accuracy(tracks, capture.rig.cameras, truth.positions, truth.visible, truth.part)


def test_tracked_positions_match_the_truth(tracked):
    _, tracks, acc = tracked
    assert len(tracks.ids) >= 100
    assert tracks.positions.shape == (8, len(tracks.ids), 3)
    # Sub-pixel: median RMS image error, and most tracks below 0.5 px.
    assert np.nanmedian(acc.rms) < 0.15
    assert np.mean(acc.rms[np.isfinite(acc.rms)] <= 0.5) >= 0.9
    # Most points stay tracked while the truth says two cameras see them.
    assert acc.through.mean() >= 0.7


def test_occluded_points_are_flagged_not_wrong(tracked):
    _, tracks, acc = tracked
    kept = acc.error[np.isfinite(acc.error)]
    assert np.mean(kept > 2.0) <= 0.005 and kept.max() < 5.0
    # The limb passes in front of the body: points are lost with a reason, not kept wrong.
    lost = (tracks.flags != TrackFlag.TRACKED) & (tracks.flags != TrackFlag.NOT_SEEDED)
    assert lost.any()
    assert set(np.unique(tracks.flags[lost])) <= {f.value for f in TrackFlag} - {0, 1}
    # Where a track is tracked its covariance is finite and positive definite.
    ok = tracks.flags == 0
    assert (np.linalg.eigvalsh(tracks.covariances[ok]) > 0).all()


def _texture(h: int, w: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    import cv2

    return cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), 1.5) * 3 - 255


def test_forward_backward_check_measures_the_round_trip():
    # Unrelated texture at the points: with the correlation test off nothing may pass.
    previous = _texture(120, 160, 0)
    rng = np.random.default_rng(5)
    pts = np.array([[[40.0 + 12 * i, 40.0 + 10 * (i % 4)] for i in range(8)]])
    nan = np.full_like(pts, np.nan)
    pos, flags, _, _ = _core.track_step([previous], [_texture(120, 160, 1)], pts, nan, min_correlation=-1.0)
    assert (flags[0] != TrackFlag.TRACKED).all()
    # A known shift under fresh noise: the round trip misses by a few hundredths of a pixel,
    # so the default tolerance passes every point and a tolerance below the miss flags
    # every one of them as forward-backward, with nothing else changed.
    moved = np.roll(previous, (1, 2), axis=(0, 1)) + rng.normal(0, 4, previous.shape).astype(np.float32)
    pos, flags, _, _ = _core.track_step([previous], [moved], pts, nan, min_correlation=-1.0)
    assert (flags[0] == TrackFlag.TRACKED).all()
    np.testing.assert_allclose(pos[0] - pts[0], np.tile([2.0, 1.0], (8, 1)), atol=0.1)
    _, flags, _, _ = _core.track_step([previous], [moved], pts, nan, min_correlation=-1.0, forward_backward=1e-5)
    assert (flags[0] == TrackFlag.FORWARD_BACKWARD).all()


def test_trajectory_filters_catch_their_failures():
    rng = np.random.default_rng(0)
    grid = rng.uniform(0, 0.2, (200, 3))  # neighbours ~0.035 apart: 17 px equivalents
    step = np.array([0.01, 0.0, 0.0])
    before, last = grid - step, grid
    current = grid + step + rng.normal(0, 1e-4, grid.shape)
    pixel = np.full(200, 0.002)  # 5 px per frame
    options = dict(max_velocity=40.0, max_acceleration=12.0, uniformity=4.0, neighbours=8)
    assert (trajectory_flags(current, last, before, pixel, **options) == 0).all()
    jumped = current.copy()
    jumped[3] += [0.0, 0.03, 0.0]  # 15 px off its neighbours' motion, acceleration 15 px/frame^2
    jumped[7] += [0.0, 0.012, 0.0]  # 6 px off: only the uniformity catches it
    jumped[9] += [0.2, 0.0, 0.0]  # 105 px per frame
    flags = trajectory_flags(jumped, last, before, pixel, **options)
    assert flags[9] == TrackFlag.VELOCITY
    assert flags[3] == TrackFlag.ACCELERATION
    assert flags[7] == TrackFlag.NONUNIFORM
    assert (np.delete(flags, [3, 7, 9]) == 0).all()


def test_files_resume_and_load(scene, tracked, tmp_path):
    root, _ = scene
    capture, whole, _ = tracked
    out = tmp_path / "out"
    first = track_points(capture, frames=capture.frames[:4], out=out)
    assert sorted(p.name for p in (out / "tracks").iterdir()) == [f"{f:06d}.npz" for f in range(4)]
    resumed = track_points(capture, out=out)
    loaded = load_tracks(out)
    np.testing.assert_array_equal(loaded.flags, resumed.flags)
    np.testing.assert_allclose(loaded.positions, whole.positions, equal_nan=True)
    # The anchors' cuts again are restored too: the drift covariance (and the fusion it
    # weighs) continue as in one run.
    np.testing.assert_allclose(loaded.covariances, whole.covariances, equal_nan=True)
    np.testing.assert_array_equal(loaded.flags, whole.flags)
    assert len(first.frames) == 4


def test_track_command(scene, tmp_path, capsys):
    root, _ = scene
    out = tmp_path / "cli"
    assert main(["track", str(root), "--out", str(out), "--frames", "0:3", "--quiet"]) == 0
    assert "tracked" in capsys.readouterr().out
    assert (out / "tracks.png").exists() and (out / "tracks_strip.png").exists()
    assert len(load_tracks(out).frames) == 3


def test_bad_input(scene, tmp_path):
    root, _ = scene
    capture = elastocap.Capture.open(root)
    with pytest.raises(elastocap.InvalidInputError, match="frames"):
        track_points(capture, frames=[0, 99])
    with pytest.raises(elastocap.InvalidInputError, match="empty"):
        track_points(capture, frames=[])
    with pytest.raises(elastocap.InvalidInputError, match="size"):
        track_points(capture, size=10)
    with pytest.raises(FileNotFoundError):
        load_tracks(tmp_path)
    frames, ids = np.arange(2), np.arange(3)
    positions = np.zeros((2, 3, 3))
    positions[1, 2] = np.nan  # NaN while flagged tracked
    with pytest.raises(elastocap.InvalidInputError, match="finite exactly where"):
        Tracks(frames, ids, positions, np.zeros((2, 3, 3, 3)), np.zeros((2, 3), np.uint8))
    with pytest.raises(elastocap.InvalidInputError, match="shape"):
        Tracks(frames, ids, positions[:, :2], np.zeros((2, 3, 3, 3)), np.zeros((2, 3), np.uint8))
    empty = Tracks(frames, ids[:0], np.zeros((2, 0, 3)), np.zeros((2, 0, 3, 3)), np.zeros((2, 0), np.uint8))
    assert empty.velocities().shape == (2, 0, 3)
    with pytest.raises(elastocap.InvalidInputError):
        _core.track_step([np.zeros((20, 20), np.float32)], [], np.zeros((1, 1, 2)), np.zeros((1, 1, 2)))
    with pytest.raises(elastocap.InvalidInputError, match="forward_backward"):
        z = np.zeros((1, 1, 2))
        _core.track_step([np.zeros((20, 20), np.float32)], [np.zeros((20, 20), np.float32)], z, z, forward_backward=0.0)


def test_rms_image_error_counts_every_held_view():
    # Two cameras hold each track: one view 0.6 px off the truth, the other exact. The RMS
    # over every held view is 0.6 / sqrt(2) = 0.42 px (within the 0.5 px); the worst
    # view per frame, which the measure used to square, would say 0.6 px.
    from elastocap.synth.capture import ring_rig

    rig = ring_rig(4, width=320, height=240, seed=0)
    cams = rig.cameras[:2]
    rng = np.random.default_rng(0)
    f, m = 5, 60
    truth = np.repeat((np.array([0.0, 0.9, 0.0]) + rng.normal(0, 0.08, (1, m, 3))), f, axis=0)
    truth += np.arange(f)[:, None, None] * np.array([0.01, 0.0, 0.0])
    visible = np.ones((f, 2, m), bool)
    views = np.stack([np.stack([cam.project(truth[t])[0] for cam in cams], axis=1) for t in range(f)])
    views[:, :, 0, 0] += 0.6
    tracks = Tracks(np.arange(f), np.arange(m), truth.copy(), np.tile(np.eye(3) * 1e-6, (f, m, 1, 1)),
                    np.zeros((f, m), np.uint8), views)
    acc = track_accuracy(tracks, cams, truth, visible)
    np.testing.assert_allclose(acc.rms, 0.6 / np.sqrt(2), atol=1e-6)
    np.testing.assert_allclose(acc.error, 0.6, atol=1e-6)  # the worst view per frame stays
    assert acc.through.all()


def test_tracked_views_keep_going_below_the_seeding_texture_floor(tmp_path, monkeypatch):
    # The texture fades to 0.55^4 = 9% of its contrast by frame 4: the patches of points
    # seeded on frame 0 fall below the seeding floor (1x the noise) while still matching.
    # With the lower floor for tracked views (hysteresis) most points stay, and stay right;
    # with one floor for both, most are lost as "match failed".
    from elastocap.tracking import settings

    truth = write_scene(tmp_path / "fade", frames=5, cameras=6, seed=1, points=500, fade=0.55)
    capture = elastocap.Capture.open(tmp_path / "fade")
    kept = {}
    low, high = settings.KEEP_TEXTURE_OVER_NOISE, settings.TEXTURE_OVER_NOISE
    assert low < high
    for floor in (low, high):
        monkeypatch.setattr(settings, "KEEP_TEXTURE_OVER_NOISE", floor)
        tracks = track_points(capture)
        born = tracks.flags[0] == TrackFlag.TRACKED
        kept[floor] = int((tracks.flags[4][born] == TrackFlag.TRACKED).sum())
        if floor == low:
            acc = track_accuracy(tracks, capture.rig.cameras, truth.positions, truth.visible, truth.part)
            assert np.nanmax(acc.error[4][born]) < 2.0
    assert born.sum() >= 50
    assert kept[low] >= 0.8 * born.sum()
    assert kept[low] >= 1.4 * kept[high]


def test_points_hidden_for_two_frames_come_back_under_their_ids(tmp_path):
    # A band down the middle of every camera's image is blanked (flat grey under noise) on
    # frames 3 and 4: the points seen only inside it lose every view. From frame 5 the
    # revival finds them again from their anchors at the projections of their positions
    # predicted from the points tracked around them, under their own ids and right; without
    # it they stay lost (new seeds take their place under new ids).
    root = tmp_path / "hidden"
    truth = write_scene(root, frames=8, cameras=6, seed=2, points=2500)
    capture = elastocap.Capture.open(root)
    blank_band(root, capture.rig.names, (3, 4))
    back = {}
    for revive in (False, True):
        tracks = track_points(capture, revive=revive)
        ok = tracks.flags == TrackFlag.TRACKED
        hidden = ok[2] & ~ok[3] & ~ok[4]
        back[revive] = hidden & ok[5:].any(axis=0)
        if revive:
            acc = track_accuracy(tracks, capture.rig.cameras, truth.positions, truth.visible, truth.part)
            assert hidden.sum() >= 20
            error = acc.error[5:, back[revive]]
            assert np.nanmedian(error) < 0.1 and np.nanmax(error) < 1.0
    assert back[False].sum() == 0
    assert back[True].sum() >= 10


def test_surface_normals_are_the_neighbours_plane_facing_the_cameras():
    from elastocap.tracking.views import surface_normals

    rng = np.random.default_rng(3)
    normal = np.array([0.3, -0.2, 0.93])
    normal /= np.linalg.norm(normal)
    basis = np.linalg.svd(normal[None])[2][1:]
    cloud = rng.uniform(-0.2, 0.2, (300, 2)) @ basis + rng.normal(0, 1e-4, (300, 1)) * normal
    cloud[::7] = np.nan  # untracked points are ignored
    points = rng.uniform(-0.1, 0.1, (20, 2)) @ basis
    towards = np.tile(-normal + 0.4 * basis[0], (20, 1))  # the cameras look at the other side
    got = surface_normals(points, cloud, towards)
    np.testing.assert_allclose(got, np.tile(-normal, (20, 1)), atol=0.01)
    # Neighbours along a line span no plane: the given direction stays.
    line = np.outer(np.linspace(-0.2, 0.2, 50), basis[0])
    np.testing.assert_array_equal(surface_normals(points, line, towards), towards)


def test_cameras_that_cannot_see_a_point_are_not_asked():
    # Points on a sphere, the cloud of tracked points its whole surface, a second small
    # sphere in front of it for camera 0: a camera is predicted to see a point when the
    # surface faces it and no tracked point is in front of it; the truth is the ray cast.
    from elastocap.synth.capture import ring_rig
    from elastocap.tracking.visibility import predicted_visible

    rig = ring_rig(6, width=320, height=240, seed=0)
    cams = rig.cameras
    rng = np.random.default_rng(4)
    centre = np.array([0.0, 0.9, 0.0])
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    body = centre + 0.25 * d
    towards_cam0 = cams[0].center - centre
    towards_cam0 /= np.linalg.norm(towards_cam0)
    blocker_centre = centre + 0.55 * towards_cam0
    blocker = blocker_centre + 0.1 * d[:800]
    cloud = np.concatenate([body, blocker])
    masks = [np.ones((cam.height, cam.width), bool) for cam in cams]
    points, normals = body[:400], d[:400]
    asked = np.ones((400, len(cams)), bool)
    got = predicted_visible(cams, masks, points, normals, cloud, asked)
    # The truth: the first hit of the ray from each camera (two spheres).
    truth = np.zeros_like(got)
    for k, cam in enumerate(cams):
        for p in range(400):
            o = cam.center
            ray = points[p] - o
            length = np.linalg.norm(ray)
            ray /= length
            hit = np.inf
            for c, r in ((centre, 0.25), (blocker_centre, 0.1)):
                b = ray @ (o - c)
                disc = b * b - (np.sum((o - c) ** 2) - r * r)
                if disc >= 0:
                    hit = min(hit, -b - np.sqrt(disc))
            truth[p, k] = hit > length - 1e-6
    hidden_by_blocker = ~truth[:, 0] & (normals @ (cams[0].center - centre) > 0)
    assert hidden_by_blocker.sum() >= 10
    assert not got[hidden_by_blocker, 0].any()
    agree = (got == truth).mean()
    assert agree >= 0.95, agree
    assert got[truth].mean() >= 0.9 and got[~truth].mean() <= 0.1
    # Outside a camera's silhouette, or not asked: never visible.
    masks[1][:] = False
    assert not predicted_visible(cams, masks, points, normals, cloud, asked)[:, 1].any()
    asked[:, 2] = False
    assert not predicted_visible(cams, masks, points, normals, cloud, asked)[:, 2].any()


def test_cross_camera_search_finds_a_point_whose_depth_is_off():
    # A textured plane seen by two cameras 60 degrees apart. A point held by one camera
    # with its depth 2.5 px-equivalents off projects about 2 px off its true place in the
    # other: the least-squares match started there without a search lands on the truth,
    # outside its tolerance, or not at all; the search with the plane-warped patch finds
    # every point within a tenth of a pixel and accepts it within its wider tolerance.
    import cv2

    from elastocap.synth.capture import ring_rig
    from elastocap.tracking.views import spatial_match, spatial_search

    cams = ring_rig(8, width=320, height=240, seed=0).cameras[:2]
    centre = np.array([0.0, 0.9, 0.0])
    normal = 0.5 * (cams[0].center + cams[1].center) - centre
    normal[1] = 0.0
    normal /= np.linalg.norm(normal)
    e1 = np.cross([0.0, 1.0, 0.0], normal)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    rng = np.random.default_rng(0)
    texel = 0.002  # metres; about 6 texels a pixel
    texture = cv2.GaussianBlur(rng.normal(0, 1, (1000, 1000)).astype(np.float32), (0, 0), 6)
    texture = (128 + 60 * texture / texture.std()).astype(np.float32)
    images = []
    for cam in cams:
        v, u = np.mgrid[0 : cam.height, 0 : cam.width]
        o, d = cam.rays(np.column_stack([u.ravel(), v.ravel()]).astype(float))
        x = o + (((centre - o) @ normal) / (d @ normal))[:, None] * d
        s = (((x - centre) @ e1) / texel + 500).reshape(cam.height, cam.width).astype(np.float32)
        r = (((x - centre) @ e2) / texel + 500).reshape(cam.height, cam.width).astype(np.float32)
        image = cv2.remap(texture, s, r, cv2.INTER_LINEAR)
        images.append(np.ascontiguousarray(image + rng.normal(0, 1, image.shape).astype(np.float32)))
    g = np.linspace(-0.3, 0.3, 9)
    points = (centre + g[:, None, None] * e1 + g[None, :, None] * e2).reshape(-1, 3)
    uv0, truth = cams[0].project(points)[0], cams[1].project(points)[0]
    ray = points - cams[0].center
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    held = points + ray * (2.5 * cams[0].to_camera(points)[:, 2] / cams[0].K[0, 0])[:, None]
    targets = np.full((len(points), 2, 2), np.nan)
    targets[:, 1] = cams[1].project(held)[0]
    assert np.median(np.linalg.norm(targets[:, 1] - truth, axis=1)) > 1.5
    common = dict(cameras=cams, points=held, normals=np.tile(normal, (len(points), 1)), size=15, min_correlation=0.75,
                  min_texture=1.0)
    reference = np.zeros(len(points), np.int64)
    matched, _ = spatial_match(images, reference, uv0, targets, tolerance=1.5, **common)
    found, cov = spatial_search(images, reference, uv0, targets, radius=4, box_correlation=0.5, forward_backward=0.6,
                                tolerance=3.0, max_iterations=20, **common)
    error = np.linalg.norm(found[:, 1] - truth, axis=1)
    assert np.isfinite(error).all() and np.median(error) < 0.1 and error.max() < 0.3
    assert np.isfinite(cov[:, 1]).all() and np.isnan(found[:, 0]).all()
    assert np.isfinite(matched[:, 1, 0]).mean() < 0.2


def test_a_reacquired_view_is_kept_only_when_it_intersects_with_the_held_ones():
    # Points held exactly in cameras 0 and 1; new views in camera 2, right for the first
    # half and 4 px off for the second: the right ones are kept and the points intersected
    # with three views, the wrong ones refused (they would fail the point's intersection on
    # the next frame and end its track) and the held views stay as they were.
    from elastocap.synth.capture import ring_rig
    from elastocap.tracking.views import confirm_views

    cams = ring_rig(4, width=320, height=240, seed=0).cameras[:3]
    rng = np.random.default_rng(5)
    points = np.array([0.0, 0.9, 0.0]) + rng.normal(0, 0.1, (40, 3))
    uv = np.stack([cam.project(points)[0] for cam in cams], axis=1)
    cov = np.tile(np.eye(2) * 1e-4, (40, 3, 1, 1))
    held, held_cov = uv.copy(), cov.copy()
    held[:, 2], held_cov[:, 2] = np.nan, np.nan
    new, new_cov = np.full_like(uv, np.nan), np.full_like(cov, np.nan)
    new[:, 2], new_cov[:, 2] = uv[:, 2], cov[:, 2]
    new[20:, 2, 0] += 4.0
    kept, kept_cov, x, xcov = confirm_views(cams, held, held_cov, new, new_cov, max_residual=1.5, floor=0.1)
    np.testing.assert_allclose(kept[:20, 2], uv[:20, 2])
    assert np.isfinite(kept_cov[:20, 2]).all()
    assert np.isnan(kept[20:]).all() and np.isnan(kept[:, :2]).all()
    np.testing.assert_allclose(x[:20], points[:20], atol=1e-6)
    assert np.isfinite(xcov[:20]).all() and np.isnan(x[20:]).all()
