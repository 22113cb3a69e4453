"""The tracks' measure against the true surface point they were seeded on
(:mod:`elastocap.synth.track_reference`), and the second reading of "through" (the visible
stretch from seeding)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from elastocap import InvalidInputError
from elastocap.synth import load_textured_truth, write_textured_capture
from elastocap.synth.textured import TexturedTruth
from elastocap.synth.track_reference import NoReference, _read_depth, surface_reference
from elastocap.tracking import TrackFlag, Tracks
from elastocap.tracking.accuracy import track_accuracy

# The reference at seeding is the depth map's point (on the marching-cubes mesh) put on
# the figure's field zero level, where the truth's points live: within ~1 mm of the mesh
# (test_textured's ON_MESH_MAX 2 mm), about 0.1 px-equivalents at 320 x 240 from 3 m.
ON_MESH_MAX = 2e-3
# The tracks' seeded positions lie this many pixel equivalents off the surface, along the
# seed camera's ray (the seeds' depth errors: median 1.0, 90th percentile 2.9 px-eq on the
# textured capture).
SEED_DEPTH_ERROR = 3.0


@pytest.fixture(scope="module")
def truth(tmp_path_factory: pytest.TempPathFactory) -> TexturedTruth:
    root = write_textured_capture(tmp_path_factory.mktemp("reference") / "capture", frames=3, cameras=6,
                                  image_size=(320, 240), supersample=1, noise=0.0, points=800, progress=False)
    return load_textured_truth(root)


def _seeds(truth: TexturedTruth) -> tuple[np.ndarray, np.ndarray]:
    """Truth points cam00 and cam01 see on every frame, material throughout, well inside
    cam00's silhouette; and their pixel centres in cam00 at frame 0."""
    cam = truth.rig.cameras[0]
    ok = truth.visible[:, 0].all(axis=0) & truth.visible[:, 1].all(axis=0) & truth.material.all(axis=0)
    pixel = np.round(cam.project(truth.positions[0])[0])
    depth = truth.depth(cam.name, 0)
    u, v = pixel[:, 0].astype(int), pixel[:, 1].astype(int)
    inside = (u >= 4) & (v >= 4) & (u < cam.width - 4) & (v < cam.height - 4)
    for du in range(-3, 4):
        for dv in range(-3, 4):
            inside &= np.isfinite(depth[np.clip(v + dv, 0, cam.height - 1), np.clip(u + du, 0, cam.width - 1)])
    rows = np.flatnonzero(ok & inside)
    return rows, pixel[rows]


def _tracks(truth: TexturedTruth, reference: np.ndarray, pixel: np.ndarray, wide: int) -> Tracks:
    """Tracks that follow ``reference`` (F, M, 3) exactly from frame 1 on, seeded on
    ``pixel`` in cam00 with their position :data:`SEED_DEPTH_ERROR` px-eq off along its ray."""
    cams = truth.rig.cameras
    f, m = reference.shape[:2]
    origin, direction = cams[0].rays(pixel)
    depth = cams[0].to_camera(reference[0])[:, 2]
    positions = reference.copy()
    positions[0] -= direction * (SEED_DEPTH_ERROR * depth / cams[0].K[0, 0])[:, None]
    views = np.full((f, m, len(cams), 2), np.nan)
    for t in range(f):
        for k in (0, 1, wide):
            if t > 0 or k != wide:
                views[t, :, k] = cams[k].project(positions[t])[0]
    views[0, :, 0] = pixel
    return Tracks(np.arange(f), np.arange(m), positions, np.tile(np.eye(3) * 1e-6, (f, m, 1, 1)),
                  np.zeros((f, m), np.uint8), views)


def test_a_seed_triangulated_off_the_surface_is_measured_against_the_true_point(truth):
    cams = truth.rig.cameras
    rows, pixel = _seeds(truth)
    assert rows.size >= 50
    f = len(truth.frames)
    # The true point on each seed pixel, by ray casting the ground-truth mesh (not the depth
    # maps the reference reads).
    mesh = trimesh.load(truth.mesh_path(0))
    origin, direction = cams[0].rays(pixel)
    hits, ray, _ = mesh.ray.intersects_location(origin, direction, multiple_hits=False)
    hit = np.full((rows.size, 3), np.nan)
    hit[ray] = hits
    # A perfect tracker following those points, carried with their part as the truth is.
    dummy = Tracks(np.arange(f), np.arange(rows.size), np.zeros((f, rows.size, 3)), np.zeros((f, rows.size, 3, 3)),
                   np.zeros((f, rows.size), np.uint8),
                   np.where(np.arange(len(cams))[None, None, :, None] == 0, pixel[None, :, None, :], np.nan).repeat(f, 0))
    ref = surface_reference(dummy, truth)
    good = ref.reason == NoReference.NONE
    assert good.mean() >= 0.9 and (ref.camera == 0).all()
    near = np.isfinite(hit).all(axis=1) & good
    assert near.mean() >= 0.85
    assert np.linalg.norm(ref.positions[0, near] - hit[near], axis=1).max() < ON_MESH_MAX
    # Carried rigidly with the truth point it was picked near (the same part).
    same = good & (truth.part[rows] == np.argmin(truth.figure.part_distances(ref.positions[0], 0), axis=1))
    gap = np.linalg.norm(ref.positions[:, same] - truth.positions[:, rows[same]], axis=2)
    np.testing.assert_allclose(gap, np.broadcast_to(gap[0], gap.shape), atol=1e-5)  # 0.01 mm: the blend's Newton steps
    assert (np.ptp(ref.positions[:, same, 0], axis=0) > 1e-3).mean() > 0.5  # they do move

    keep = np.flatnonzero(good)
    # The camera of another pair (120 degrees round the ring) that sees most of them.
    wide = 2 + int(np.argmax(truth.visible[1:, 2:][:, :, rows[keep]].sum(axis=(0, 2))))
    tracks = _tracks(truth, ref.positions[:, keep], pixel[keep], wide)
    # Every held view counted (the truth's visibility needs all 8 neighbours seen, which few
    # points are in a camera 120 degrees away on 3 frames; it does not move the reference).
    args = (tracks, cams, truth.positions, np.ones_like(truth.visible), truth.part)
    seeded = track_accuracy(*args)
    true = track_accuracy(*args, reference=ref.positions[:, keep])
    assert true.measured.all() and seeded.measured.mean() >= 0.9
    # Against the true point the perfect tracker is exact after its seeding frame, and its
    # seeding frame shows the seed's depth error.
    assert np.nanmax(true.error3d[1:]) < 0.2
    assert np.nanmax(true.error[1:]) < 0.05
    np.testing.assert_allclose(true.error3d[0], SEED_DEPTH_ERROR, rtol=0.2)  # px-eq over all cameras, not cam00
    # Against the carried seeded position (the measure before) it is off by the seed's
    # depth error for its whole life, and the camera of the other pair sees that as image
    # error.
    m = seeded.measured
    assert np.nanmedian(seeded.error3d[1:, m]) > 0.8 * SEED_DEPTH_ERROR
    wide_seen = np.isfinite(tracks.views[1:, :, wide, 0]) & truth.visible[1:, wide][:, rows[keep]] & m[None, :]
    assert wide_seen.sum() >= 10
    wrong = np.linalg.norm(cams[wide].project(ref.positions[1:, keep][wide_seen])[0] - tracks.views[1:, :, wide][wide_seen], axis=1)
    assert wrong.max() < 1e-6
    assert np.nanmedian(seeded.error[1:][wide_seen]) > 0.5 * SEED_DEPTH_ERROR
    assert np.nanmedian(seeded.rms[m]) > 3 * np.nanmedian(true.rms)


def test_seeds_without_a_readable_depth_are_left_out_and_counted(truth):
    cams = truth.rig.cameras
    rows, pixel = _seeds(truth)
    f, m = len(truth.frames), 4
    depth = truth.depth(cams[0].name, 0)
    # A pixel centre off the figure next to it (its 4 x 4 block straddles the silhouette).
    vs, us = np.nonzero(np.isfinite(depth))
    edge = np.array([us.max() + 1.0, vs[np.argmax(us)]])
    views = np.full((f, m, len(cams), 2), np.nan)
    views[:, 0, 0] = pixel[0]
    views[:, 1, 0] = edge
    views[:, 2, 0] = pixel[1] + 0.25  # no view on a pixel centre
    views[:, 3, 0] = pixel[2]
    flags = np.zeros((f, m), np.uint8)
    flags[:, 3] = TrackFlag.FEW_VIEWS  # never tracked
    positions = np.where(flags[..., None] == 0, np.zeros((f, m, 3)), np.nan)
    tracks = Tracks(np.arange(f), np.arange(m), positions, np.zeros((f, m, 3, 3)), flags, views)
    ref = surface_reference(tracks, truth)
    assert list(ref.reason) == [NoReference.NONE, NoReference.SILHOUETTE, NoReference.NO_SEED_VIEW, NoReference.NOT_TRACKED]
    assert np.isfinite(ref.positions[:, 0]).all() and np.isnan(ref.positions[:, 1:]).all()
    acc = track_accuracy(tracks, cams, truth.positions, truth.visible, truth.part, reference=ref.positions)
    assert not acc.measured[1:].any()
    with pytest.raises(InvalidInputError, match="views"):
        surface_reference(Tracks(tracks.frames, tracks.ids, positions, tracks.covariances, flags), truth)
    with pytest.raises(InvalidInputError, match="frames"):
        surface_reference(Tracks(tracks.frames + 10, tracks.ids, positions, tracks.covariances, flags, views), truth)
    with pytest.raises(InvalidInputError, match="reference"):
        track_accuracy(tracks, cams, truth.positions, truth.visible, truth.part, reference=ref.positions[:2])


def test_depth_is_read_bilinearly_on_one_surface_only():
    f = 500.0
    v, u = np.mgrid[0:20, 0:20].astype(float)
    plane = (3.0 + 0.002 * u + 0.001 * v).astype(np.float32)  # a tilted plane: bilinear is exact
    z, why = _read_depth(plane, np.array([[7.3, 9.6], [10.0, 4.0]]), f, 3.0)
    np.testing.assert_allclose(z, [3.0 + 0.002 * 7.3 + 0.001 * 9.6, 3.0 + 0.02 + 0.004], rtol=1e-6)
    assert (why == 0).all()
    step = plane.copy()
    step[:, 11:] -= 0.1  # an arm 10 cm in front: 17 px-eq at 3 m with f = 500
    z, why = _read_depth(step, np.array([[10.0, 9.0], [5.0, 9.0], [11.5, 9.0]]), f, 3.0)
    assert list(why) == [NoReference.DEPTH_JUMP, NoReference.NONE, NoReference.DEPTH_JUMP] and np.isnan(z[[0, 2]]).all()
    hole = plane.copy()
    hole[9, 12] = np.nan
    z, why = _read_depth(hole, np.array([[11.0, 9.0], [1.0, 1.0], [0.2, 5.0]]), f, 3.0)
    assert list(why) == [NoReference.SILHOUETTE, NoReference.NONE, NoReference.SILHOUETTE]


def test_through_the_visible_stretch_forgives_a_point_lost_in_its_gap():
    from elastocap.synth.capture import ring_rig

    cams = ring_rig(4, width=320, height=240, seed=0).cameras[:2]
    f, m = 6, 4
    truth = np.repeat(np.array([0.0, 0.9, 0.0]) + np.random.default_rng(1).normal(0, 0.05, (1, m, 3)), f, axis=0)
    visible = np.ones((f, 2, m), bool)
    visible[2:4, 1] = False  # frames 2-3: one camera only, for every point
    flags = np.zeros((f, m), np.uint8)
    flags[2:, 0] = TrackFlag.FEW_VIEWS  # lost in its gap, never back
    flags[1:, 1] = TrackFlag.LOW_CORRELATION  # lost while seen
    flags[2:4, 2] = TrackFlag.FEW_VIEWS  # lost in its gap and back after it
    flags[0, 3] = TrackFlag.NOT_SEEDED  # seeded on frame 1
    flags[4:, 3] = TrackFlag.FEW_VIEWS
    positions = np.where(flags[..., None] == 0, truth, np.nan)
    tracks = Tracks(np.arange(f), np.arange(m), positions, np.tile(np.eye(3), (f, m, 1, 1)), flags)
    acc = track_accuracy(tracks, cams, truth, visible)
    assert list(acc.through) == [False, False, True, False]
    assert list(acc.through_span) == [True, False, True, True]
