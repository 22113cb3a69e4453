"""Points whose narrow pair's depth slides off their neighbours' rigid map, withheld along
the rays (``settings.SLIDE_ALONG``, :mod:`elastocap.tracking.depth_slide`)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_track_slide import PIXEL, _pair, _tracker, withheld_on_frame

from elastocap import InvalidInputError
from elastocap.tracking import settings
from elastocap.tracking.depth_slide import slid_in_depth
from elastocap.tracking.rigidity import RigidResiduals


def _run(monkeypatch, along: float, rate: float, over: int = 1, frames: int = 40, leaves: bool = True) -> tuple[list[bool], list[bool]]:
    """A forearm-sized patch of 60 points turning and moving rigidly over ``frames`` frames,
    seen by a narrow pair looking along z; one point's depth slides ``rate`` px-eq a frame
    along the rays (the pair's disparity drifting: its intersection agrees with itself),
    withheld once beyond ``along`` px-eq on ``over`` consecutive frames.
    Intersections carry the noise of a re-tied pair: 0.2 px-eq across the rays, 0.7 along
    them (the seeding frame's and this one's together: a median 0.95 px-eq along the rays
    from the rigid prediction, as m15's kept positions within 5 px-eq of the truth have).
    Once found, the slider leaves its neighbours' rigid fits when ``leaves``
    (``settings.SLIDE_ALONG_LEAVES``).
    Returns, per frame, whether the slider was withheld and whether any other point was."""
    monkeypatch.setattr(settings, "SLIDE", 4.0)
    monkeypatch.setattr(settings, "SLIDE_SCALE", 0.5)
    monkeypatch.setattr(settings, "SLIDE_STICKY", True)
    monkeypatch.setattr(settings, "SLIDE_ALONG", along)
    monkeypatch.setattr(settings, "SLIDE_ALONG_FRAMES", over)
    monkeypatch.setattr(settings, "SLIDE_ALONG_LEAVES", leaves)
    rng = np.random.default_rng(3)
    m = 60
    angle = rng.uniform(-1.0, 1.0, m)
    base = np.column_stack([0.1 * np.sin(angle), rng.uniform(-0.15, 0.15, m), -0.1 * np.cos(angle)])
    tracker = _tracker(_pair())
    slider = 11
    ray = np.array([0.0, 0.0, 1.0])
    across = (0.2 * PIXEL) ** 2
    cov = np.tile(across * np.eye(3) + ((0.7 * PIXEL) ** 2 - across) * np.outer(ray, ray), (m, 1, 1))
    pixel = np.full(m, PIXEL)
    views = np.ones((m, 2), bool)
    mine, others = [], []
    for f in range(frames):
        # A small turn: the rays stay along z in the patch's frame, so the slide stays along them.
        rot = Rotation.from_euler("xyz", [0.2 * f, 0.3 * f, -0.1 * f], degrees=True).as_matrix()
        truth = base @ rot.T + np.array([0.004 * f, -0.002 * f, 0.0])
        x = truth + rng.normal(0, 0.2 * PIXEL, (m, 3)) + rng.normal(0, 0.7 * PIXEL, (m, 1)) * ray
        x[slider] += rate * PIXEL * f * ray
        withheld = withheld_on_frame(tracker, f, x, cov, pixel, views)
        mine.append(bool(withheld[slider]))
        others.append(bool(withheld[np.arange(m) != slider].any()))
    return mine, others


@pytest.mark.parametrize(("along", "over"), [(6.0, 1), (5.0, 2)])
@pytest.mark.parametrize("rate", [0.3, 0.6])
def test_a_point_whose_depth_slides_is_withheld_and_its_neighbours_are_not(monkeypatch, rate, along, over):
    mine, others = _run(monkeypatch, along, rate, over)
    assert not any(others), "a rigidly moving neighbour withheld"
    first = mine.index(True)
    # Found once the slide passes the bound, give or take the pair's depth noise and the
    # pull of the fusion (and the frames it must stay there); withheld on every frame
    # after (sticky).
    assert (along - 3.0) / rate <= first <= (along + 3.0) / rate + over - 1
    assert all(mine[first:])


def test_a_point_slid_in_depth_left_in_its_neighbours_fits_drags_them_over(monkeypatch):
    # Withheld but still tracked, the slider pulls its neighbours' rigid predictions by a
    # share of its offset: left in their fits, some follow it over the bound.
    mine, others = _run(monkeypatch, 6.0, 0.6, leaves=False)
    assert mine.index(True) < others.index(True)


def test_the_slide_along_the_rays_passes_the_across_check_alone(monkeypatch):
    # The SLID check looks across the rays: without the bound the sliding depth is kept.
    mine, others = _run(monkeypatch, float("inf"), 0.5)
    assert not any(mine) and not any(others)


def _residuals(along: list[float]) -> RigidResiduals:
    n = len(along)
    return RigidResiduals(across=np.zeros(n), along=np.array(along), spread=np.zeros(n), held_out=np.zeros(n),
                          predicted=np.zeros((n, 3)))


def test_the_bound_reads_the_along_residual_on_consecutive_frames_and_refuses_nonsense(monkeypatch):
    tracker = _tracker(_pair())
    monkeypatch.setattr(settings, "SLIDE_ALONG", 6.0)
    monkeypatch.setattr(settings, "SLIDE_ALONG_FRAMES", 1)
    np.testing.assert_array_equal(slid_in_depth(tracker, _residuals([0.0, 5.9, 6.1, np.nan, 40.0])),
                                  [False, False, True, False, True])
    monkeypatch.setattr(settings, "SLIDE_ALONG_FRAMES", 2)
    tracker.along_run = np.zeros(0, np.int64)
    frames = [[7.0, 7.0, 1.0, 7.0], [7.0, np.nan, 7.0, 7.0], [7.0, 7.0, 7.0, 1.0, 7.0]]  # a point seeded on the last
    got = [slid_in_depth(tracker, _residuals(f)).tolist() for f in frames]
    assert got == [[False] * 4, [True, False, False, True], [True, False, True, False, False]]
    np.testing.assert_array_equal(tracker.along_run, [3, 1, 2, 0, 1])
    monkeypatch.setattr(settings, "SLIDE_ALONG", float("inf"))
    assert not slid_in_depth(tracker, _residuals([40.0] * 5)).any()
    for name, bad in (("SLIDE_ALONG", float("nan")), ("SLIDE_ALONG", 0.0), ("SLIDE_ALONG", -1.0),
                      ("SLIDE_ALONG_FRAMES", 0), ("SLIDE_ALONG_FRAMES", 1.5)):
        monkeypatch.setattr(settings, "SLIDE_ALONG", 6.0)
        monkeypatch.setattr(settings, "SLIDE_ALONG_FRAMES", 2)
        monkeypatch.setattr(settings, name, bad)
        with pytest.raises(InvalidInputError):
            slid_in_depth(tracker, _residuals([1.0] * 5))
