"""Points that slide along the surface in both views, withheld against their neighbours'
rigid map since their seeding frame (``settings.SLIDE``, :func:`elastocap.tracking.rigidity.rigid_residuals`,
``step_report.withhold_slid``)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from elastocap.cameras import Camera
from elastocap.tracking import settings
from elastocap.tracking.depth_slide import planned_positions
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.rigidity import neighbour_plans, rigid_fusion, rigid_residuals
from elastocap.tracking.step import FrameTracker
from elastocap.tracking.step_report import withhold_slid

PIXEL = 0.003  # world units per pixel at the points (3 m, f = 1000 px)


def _pair() -> list[Camera]:
    """A narrow stereo pair 3 m in front of the origin, 6 degrees apart (the capture's)."""
    cams = []
    for i, yaw in enumerate((-0.05, 0.05)):
        r = Rotation.from_euler("y", yaw).as_matrix()
        centre = np.array([-3.0 * np.sin(yaw), 0.0, -3.0 * np.cos(yaw)])
        k = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
        cams.append(Camera(f"c{i}", k, None, r, -r @ centre, 640, 480))
    return cams


def _tracker(cameras: list[Camera]) -> FrameTracker:
    """The part of a FrameTracker that the withholding reads."""
    tracker = object.__new__(FrameTracker)
    tracker.cameras = cameras
    tracker.seeded_at = np.zeros(0, np.int64)
    tracker.history = {}
    tracker.slid = np.zeros(0, bool)
    tracker.along_run = np.zeros(0, np.int64)
    tracker.depth_slid = np.zeros(0, bool)
    return tracker


def withheld_on_frame(tracker: FrameTracker, frame: int, x: np.ndarray, cov: np.ndarray, pixel: np.ndarray,
                      views: np.ndarray) -> np.ndarray:
    """(M,) which of the intersections ``x`` (M, 3) the report withholds as SLID on ``frame``
    (frame 0 seeds them all), after the rigid fusion, with the neighbours the step's report
    chooses (:func:`~elastocap.tracking.step_report.reported`)."""
    m = len(x)
    if frame == 0:
        tracker.seeded_at = np.zeros(m, np.int64)
        tracker.history = {0: x.copy()}
    options = dict(neighbours=settings.RIGID_NEIGHBOURS, both_frames=settings.RIGID_BOTH_FRAMES,
                   candidates=settings.RIGID_CANDIDATES, stretch=settings.RIGID_STRETCH)
    plans = neighbour_plans(planned_positions(tracker, x), cov, pixel, tracker.seeded_at, tracker.history, **options)
    fused, fcov = rigid_fusion(x, cov, pixel, tracker.seeded_at, tracker.history, sigma=settings.RIGID_SIGMA,
                               plans=plans, **options)
    out, _, flags = withhold_slid(tracker, x, cov, fused, fcov, np.zeros(m, np.uint8), pixel, views, plans=plans)
    withheld = flags == TrackFlag.SLID
    np.testing.assert_array_equal(np.isnan(out).all(axis=1), withheld)
    return withheld


@pytest.mark.parametrize("rate", [0.25, 0.5])
def test_a_point_sliding_in_both_views_is_withheld_and_its_neighbours_are_not(monkeypatch, rate):
    # A forearm-sized patch of 60 points turns and moves rigidly over 40 frames; one point
    # slides `rate` px-eq a frame along the surface (across the rays, so both views of the
    # pair see it alike and the intersection agrees with itself), far below any one-frame
    # check (velocity 40, uniformity 4 px-eq a frame). Intersections carry noise as the
    # narrow pair gives it: 0.2 px-eq across the rays, 1.5 along them.
    monkeypatch.setattr(settings, "SLIDE", 4.0)
    monkeypatch.setattr(settings, "SLIDE_SCALE", 1.0)
    monkeypatch.setattr(settings, "SLIDE_STICKY", True)
    # The check across the rays alone: the depth noise below (1.5 px-eq a frame, drawn
    # afresh) is the along check's to judge (test_track_depth_slide.py).
    monkeypatch.setattr(settings, "SLIDE_ALONG", float("inf"))
    rng = np.random.default_rng(11)
    m, frames = 60, 40
    angle = rng.uniform(-1.0, 1.0, m)
    base = np.column_stack([0.1 * np.sin(angle), rng.uniform(-0.15, 0.15, m), -0.1 * np.cos(angle)])
    cameras = _pair()
    tracker = _tracker(cameras)
    slider = 7
    ray = np.array([0.0, 0.0, 1.0])
    across = (0.2 * PIXEL) ** 2
    cov = np.tile(across * np.eye(3) + ((1.5 * PIXEL) ** 2 - across) * np.outer(ray, ray), (m, 1, 1))
    pixel = np.full(m, PIXEL)
    views = np.ones((m, 2), bool)
    flagged_at = []
    for f in range(frames):
        rot = Rotation.from_euler("xyz", [0.6 * f, 1.2 * f, -0.4 * f], degrees=True).as_matrix()
        local = base.copy()
        # The slide: along the limb's axis (y), across the rays.
        local[slider, 1] += rate * PIXEL * f
        truth = local @ rot.T + np.array([0.004 * f, -0.002 * f, 0.0])
        x = truth + rng.normal(0, 0.2 * PIXEL, (m, 3)) + rng.normal(0, 1.5 * PIXEL, (m, 1)) * ray
        withheld = withheld_on_frame(tracker, f, x, cov, pixel, views)
        assert not withheld[np.arange(m) != slider].any(), f"a rigidly moving neighbour withheld on frame {f}"
        flagged_at.append(bool(withheld[slider]))
    first = flagged_at.index(True)
    # Found once its slide exceeds the threshold plus the neighbours' residual (~0.3-1
    # px-eq here), and withheld on every frame after (sticky).
    assert 4.0 / rate <= first <= 4.0 / rate + 2.0 / rate + 2
    assert all(flagged_at[first:])


def test_residuals_of_a_rigid_patch_are_small_and_the_slide_is_across_the_rays():
    rng = np.random.default_rng(5)
    m = 50
    angle = rng.uniform(-1.0, 1.0, m)
    before = np.column_stack([0.1 * np.sin(angle), rng.uniform(-0.15, 0.15, m), -0.1 * np.cos(angle)])
    rot = Rotation.from_euler("xyz", [10, -25, 5], degrees=True).as_matrix()
    now = before @ rot.T + np.array([0.05, 0.0, 0.02])
    x = now.copy()
    x[3] += np.array([6.0, 0.0, 0.0]) * PIXEL  # across the rays (the cameras look along z)
    x[9] += np.array([0.0, 0.0, 6.0]) * PIXEL  # along them
    towards = np.tile([0.0, 0.0, -1.0], (m, 1))
    res = rigid_residuals(x, now, np.tile(np.eye(3) * PIXEL**2, (m, 1, 1)), np.full(m, PIXEL), towards,
                          np.zeros(m, np.int64), {0: before}, neighbours=8, both_frames=1.0, candidates=16, stretch=8.0)
    np.testing.assert_allclose(res.across[3], 6.0, atol=1e-6)
    np.testing.assert_allclose(res.along[3], 0.0, atol=1e-6)
    np.testing.assert_allclose(res.along[9], 6.0, atol=1e-6)
    np.testing.assert_allclose(res.across[9], 0.0, atol=1e-6)
    others = np.setdiff1d(np.arange(m), [3, 9])
    assert np.abs(res.across[others]).max() < 1e-6 and np.abs(res.held_out).max() < 1e-6
    np.testing.assert_allclose(res.predicted, now, atol=1e-9)
    # Points seeded on this frame have no prediction.
    seeded = np.zeros(m, np.int64)
    seeded[:5] = 1
    res = rigid_residuals(x, now, np.tile(np.eye(3) * PIXEL**2, (m, 1, 1)), np.full(m, PIXEL), towards, seeded,
                          {0: before, 1: x}, neighbours=8)
    assert np.isnan(res.across[:5]).all() and np.isfinite(res.across[5:]).all()
