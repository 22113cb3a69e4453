"""Reported positions outside a camera's silhouette (``settings.OUTSIDE``,
:func:`elastocap.tracking.silhouette.outside_silhouettes`, flag OUTSIDE), and positions
whose drift covariance before the fusion is too wide (``settings.UNCERTAIN_DRIFT_SD``)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st
from scipy.ndimage import distance_transform_edt
from scipy.spatial.transform import Rotation

import elastocap
from elastocap.cameras import Camera
from elastocap.tracking import TrackFlag, settings, track_points
from elastocap.tracking.silhouette import outside_silhouettes
from elastocap.tracking.step import FrameTracker
from elastocap.tracking.step_report import reported
from track_scene import write_scene

PIXEL = 0.003  # world units per pixel 3 m from a camera with f = 1000 px
RADIUS = 0.1  # the limb: a vertical cylinder on the y axis, 33 px across its radius


def _camera(name: str, yaw: float) -> Camera:
    """A 640 x 480 camera 3 m from the origin looking at it, turned ``yaw`` about y (0: at -z)."""
    centre = np.array([-3.0 * np.sin(yaw), 0.0, -3.0 * np.cos(yaw)])
    r = Rotation.from_euler("y", -yaw).as_matrix()  # its optical axis (row 3) towards the origin
    k = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
    return Camera(name, k, None, r, -r @ centre, 640, 480)


def _silhouette(cam: Camera) -> np.ndarray:
    """(480, 640) the pixels whose ray meets the cylinder (ray-cast, no distortion)."""
    v, u = np.mgrid[0:480, 0:640]
    rays = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1) @ np.linalg.inv(cam.K).T @ cam.R
    o = cam.center
    # The ray o + s d meets the cylinder x^2 + z^2 = R^2 where its distance to the axis
    # in the xz plane is at most R.
    d2 = rays[:, [0, 2]]
    s = -(d2 @ o[[0, 2]]) / np.einsum("ij,ij->i", d2, d2)
    nearest = o[[0, 2]] + s[:, None] * d2
    return (np.linalg.norm(nearest, axis=1) <= RADIUS).reshape(480, 640)


def _limb(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Surface points facing the pair (at -z) over +-80 degrees, and their angles."""
    theta = np.deg2rad(rng.uniform(-80.0, 80.0, n))
    x = np.column_stack([RADIUS * np.sin(theta), rng.uniform(-0.3, 0.3, n), -RADIUS * np.cos(theta)])
    return x, theta


def test_a_point_in_front_of_the_surface_along_its_pairs_rays_is_outside_the_side_cameras_silhouette():
    # A narrow pair (6 degrees) in front of the limb places its points well across its
    # rays but poorly along them; a camera at 90 degrees sees a depth error of the pair as
    # a shift across its own image, and a point pushed in front of the surface where the
    # limb faces the pair lands beside that camera's silhouette.
    rng = np.random.default_rng(3)
    cameras = [_camera("a", -0.05), _camera("b", 0.05), _camera("side", -np.pi / 2)]
    masks = [_silhouette(c) for c in cameras]
    x, theta = _limb(400, rng)
    towards = np.array([0.0, 0.0, -1.0])  # to the pair
    # On the surface, off by what a kept position mostly is (0.2 px-eq sd across the rays,
    # up to 2.5 along them: the 95th percentile on the capture): none.
    noisy = x + PIXEL * (0.2 * rng.normal(size=x.shape) * [1, 1, 0] + rng.uniform(-2.5, 2.5, (len(x), 1)) * towards)
    assert not outside_silhouettes(cameras, masks, noisy, 3.0).any()
    # Pushed 8 px-eq in front: outside the side camera by ~8 - R (1 - cos theta) px.
    front = outside_silhouettes(cameras, masks, x + 8 * PIXEL * towards, 3.0)
    facing = np.abs(theta) < np.deg2rad(20.0)
    assert front[facing].all()
    # Where the limb turns away from the pair the push stays inside the side silhouette.
    assert not front[np.abs(theta) > np.deg2rad(50.0)].any()
    # Pushed 8 px-eq behind the surface (into the limb): inside every silhouette.
    assert not outside_silhouettes(cameras, masks, x - 8 * PIXEL * towards, 3.0).any()
    # A margin wider than the push leaves them all.
    assert not outside_silhouettes(cameras, masks, x + 8 * PIXEL * towards, 9.0).any()


@hsettings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), margin=st.sampled_from([0.0, 1.0, 2.5, 3.0, 5.0]))
def test_outside_is_the_distance_transform_beyond_the_margin(seed, margin):
    # Against scipy's Euclidean distance transform of a random silhouette, at the
    # projection's nearest pixel; points behind the camera or off its image never count.
    rng = np.random.default_rng(seed)
    cam = _camera("c", rng.uniform(-0.3, 0.3))
    blobs = rng.uniform([100, 80], [540, 400], size=(4, 2))
    v, u = np.mgrid[0:480, 0:640]
    mask = np.zeros((480, 640), bool)
    for b, r in zip(blobs, rng.uniform(10, 80, 4)):
        mask |= (u - b[0]) ** 2 + (v - b[1]) ** 2 <= r**2
    uv = rng.uniform([-40, -40], [680, 520], size=(300, 2))
    depth = rng.uniform(-1.0, 5.0, 300)
    rays = np.column_stack([uv, np.ones(300)]) @ np.linalg.inv(cam.K).T
    points = (cam.R.T @ (rays * depth[:, None] - cam.t).T).T
    points[::37] = np.nan
    got = outside_silhouettes([cam], [mask], points, margin)
    dist = distance_transform_edt(~mask)
    puv, _ = cam.project(np.nan_to_num(points))
    iu, iv = np.round(puv[:, 0]), np.round(puv[:, 1])
    seen = np.isfinite(points).all(axis=1) & (depth > 0) & (iu >= 0) & (iv >= 0) & (iu <= 639) & (iv <= 479)
    want = np.zeros(300, bool)
    want[seen] = dist[iv[seen].astype(int), iu[seen].astype(int)] > margin
    np.testing.assert_array_equal(got, want)


def _reporter(cameras: list[Camera], masks: list[np.ndarray], n: int) -> FrameTracker:
    """The part of a FrameTracker that ``reported`` reads (the tests turn the fusion and
    SLID off: the checks here are the last ones)."""
    tracker = object.__new__(FrameTracker)
    tracker.cameras = cameras
    tracker.masks = masks
    tracker.anchors = None
    tracker.seeded_at = np.zeros(n, np.int64)
    tracker.history = {0: np.zeros((n, 3))}
    tracker.slid = np.zeros(n, bool)
    return tracker


def test_the_tracker_withholds_points_outside_a_silhouette_on_that_frame_only(monkeypatch):
    rng = np.random.default_rng(5)
    cameras = [_camera("a", -0.05), _camera("b", 0.05), _camera("side", -np.pi / 2)]
    masks = [_silhouette(c) for c in cameras]
    x, theta = _limb(200, rng)
    facing = np.abs(theta) < np.deg2rad(20.0)
    x[facing] += 8 * PIXEL * np.array([0.0, 0.0, -1.0])
    n = len(x)
    cov = np.tile(np.eye(3) * PIXEL**2, (n, 1, 1))
    uv = np.full((n, 3, 2), np.nan)
    uv[:, :2] = 100.0  # held by the pair
    flags = np.zeros(n, np.uint8)
    monkeypatch.setattr(settings, "RIGID", False)
    monkeypatch.setattr(settings, "SLIDE", float("inf"))
    monkeypatch.setattr(settings, "OUTSIDE", 3.0)
    tracker = _reporter(cameras, masks, n)
    got, got_cov, got_flags = reported(tracker, uv, x, cov, flags)
    np.testing.assert_array_equal(got_flags == TrackFlag.OUTSIDE, facing)
    assert np.isnan(got[facing]).all() and np.isnan(got_cov[facing]).all()
    np.testing.assert_array_equal(got[~facing], x[~facing])
    assert np.isfinite(x).all() and (flags == 0).all()  # the tracker's state is not touched
    # Back on the surface next frame: kept (not sticky).
    x[facing] -= 8 * PIXEL * np.array([0.0, 0.0, -1.0])
    _, _, again = reported(tracker, uv, x, cov, flags)
    assert (again == TrackFlag.TRACKED).all()
    # Off: main's output.
    monkeypatch.setattr(settings, "OUTSIDE", float("inf"))
    x[facing] += 8 * PIXEL * np.array([0.0, 0.0, -1.0])
    off, _, off_flags = reported(_reporter(cameras, masks, n), uv, x, cov, flags)
    assert (off_flags == TrackFlag.TRACKED).all()
    np.testing.assert_array_equal(off, x)


def test_a_wide_drift_covariance_before_the_fusion_is_withheld(monkeypatch):
    # The bound reads the covariance with the drift, before the fusion narrows it.
    rng = np.random.default_rng(8)
    cameras = [_camera("a", -0.05), _camera("b", 0.05)]
    masks = [np.ones((480, 640), bool)] * 2
    x, _ = _limb(50, rng)
    n = len(x)
    sd = np.where(np.arange(n) % 5 == 0, 6.0, 1.0)  # px-eq along z
    cov = np.zeros((n, 3, 3))
    cov[:, 0, 0] = cov[:, 1, 1] = (0.2 * PIXEL) ** 2
    cov[:, 2, 2] = (sd * PIXEL) ** 2
    uv = np.full((n, 2, 2), np.nan)
    uv[:, :2] = 100.0
    flags = np.zeros(n, np.uint8)
    monkeypatch.setattr(settings, "DRIFT_SCALE", (1.0, 0.0))  # the drift term: none
    monkeypatch.setattr(settings, "DRIFT_VARIANCE", (0.0, 0.0))
    monkeypatch.setattr(settings, "RIGID", False)
    monkeypatch.setattr(settings, "SLIDE", float("inf"))
    monkeypatch.setattr(settings, "UNCERTAIN_DRIFT_SD", 4.0)
    got, _, got_flags = reported(_reporter(cameras, masks, n), uv, x, cov, flags)
    np.testing.assert_array_equal(got_flags == TrackFlag.UNCERTAIN, sd > 4.0)
    assert np.isnan(got[sd > 4.0]).all() and np.isfinite(got[sd < 4.0]).all()
    monkeypatch.setattr(settings, "UNCERTAIN_DRIFT_SD", float("inf"))
    _, _, off = reported(_reporter(cameras, masks, n), uv, x, cov, flags)
    assert (off == TrackFlag.TRACKED).all()


def test_points_outside_a_silhouette_are_withheld_without_changing_what_is_tracked(tmp_path, monkeypatch):
    # Output only: with the check the tracker follows exactly the points and views it
    # follows without it, and on the ray-cast scene (true silhouettes) it withholds few.
    write_scene(tmp_path / "s", frames=4, cameras=6, seed=1, points=500)
    capture = elastocap.Capture.open(tmp_path / "s")
    monkeypatch.setattr(settings, "OUTSIDE", float("inf"))
    free = track_points(capture)
    monkeypatch.setattr(settings, "OUTSIDE", 0.0)  # the strictest: any pixel off the silhouette
    strict = track_points(capture)
    ok = free.flags == TrackFlag.TRACKED
    out = strict.flags == TrackFlag.OUTSIDE
    assert ok.sum() >= 200 and out.sum() <= 0.1 * ok.sum()
    np.testing.assert_array_equal(ok, (strict.flags == TrackFlag.TRACKED) | out)
    np.testing.assert_array_equal(free.views, strict.views)
    assert np.isnan(strict.positions[out]).all()
    kept = strict.flags == TrackFlag.TRACKED
    np.testing.assert_array_equal(free.positions[kept], strict.positions[kept])
