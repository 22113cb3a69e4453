"""Starts of the pose search read from the data (:mod:`elastocap.body.starts`): the body's
volume from points or masks, its trunk's heading and its far points as hands and feet,
and the search that finds a pose its fixed starts miss."""

from __future__ import annotations

import numpy as np
import pytest

from elastocap.body import BodyModel, BodyState
from elastocap.body.model import Z_UP_TO_WORLD
from elastocap.body.search import search_pose
from elastocap.body.starts import body_volume, data_starts

MODEL = BodyModel.default_human()
NAMES = MODEL.motion_names
JOINTS = ("l_forearm", "r_forearm", "l_hand", "r_hand", "l_shin", "r_shin", "l_foot", "r_foot")
#: Between two of the fixed grid's eight headings (45 and 90 degrees): 18 degrees from both.
HEADING = 1.1


def _walking(heading: float = HEADING) -> BodyState:
    """A stride with one arm forward, the other back, and a bent knee, turned to
    ``heading``."""
    motion = MODEL.rest_state(position=(0.2, -0.1, 1.0)).motion.copy()
    motion[3] = heading
    for name, angle in {"l_upperarm.0": -0.9, "r_upperarm.0": 0.6, "l_forearm.0": 0.6, "l_thigh.0": 0.4, "r_thigh.0": -0.3,
                        "r_shin.0": -0.5}.items():
        motion[NAMES.index(name)] = angle
    return BodyState(np.ones(MODEL.n_shape), motion)


def _joints(state: BodyState) -> np.ndarray:
    return MODEL.pose(state)[1][[MODEL.part_names.index(p) for p in JOINTS]]


def _rms(a: BodyState, b: BodyState) -> float:
    return float(np.sqrt(np.mean(np.sum((_joints(a) - _joints(b)) ** 2, axis=1))))


def _facing(angle: float) -> float:
    return abs((angle + np.pi) % (2 * np.pi) - np.pi)


def test_the_data_starts_recover_a_pose_from_its_skin_points() -> None:
    """The volume of the model's own skin points, turned to a heading no fixed start has:
    one of the eight starts has the heading within 10 degrees and the elbows, wrists,
    knees and ankles within 6 cm RMS; starts facing the other way are among them."""
    truth = _walking()
    points = MODEL.skin_points(truth, 6000, seed=1)
    volume = body_volume(np.median(points, axis=0), points=points)
    starts = data_starts(MODEL, np.ones(MODEL.n_shape), volume)
    assert len(starts) == 8
    best = min(starts, key=lambda s: _rms(s, truth))
    assert _rms(best, truth) < 0.06
    assert _facing(float(best.motion[3]) - HEADING) < np.radians(10)
    assert np.linalg.norm(best.motion[:3] - truth.motion[:3]) < 0.08
    assert any(_facing(float(s.motion[3]) - HEADING - np.pi) < np.radians(10) for s in starts)
    # the limbs assigned the other way round are starts too, and worse
    assert sorted(_rms(s, truth) for s in starts)[1] > 2 * _rms(best, truth)


def test_the_volume_from_masks_gives_the_same_starts() -> None:
    """The visual hull of the model's silhouettes in a ring of cameras (the tracker's
    masks-only case) reads the same heading and limbs as its skin points."""
    from elastocap.synth.capture import ring_rig

    truth = _walking()
    cameras = [c.replace(R=c.R @ Z_UP_TO_WORLD) for c in ring_rig(8, width=240, height=180, look_at=(0.2, 1.0, 0.1)).cameras]
    masks = [MODEL.silhouette(truth, c) for c in cameras]
    masks[3] = None  # a camera without a mask carves nothing
    volume = body_volume(truth.motion[:3], masks=masks, cameras=cameras)
    assert volume is not None
    best = min(data_starts(MODEL, np.ones(MODEL.n_shape), volume), key=lambda s: _rms(s, truth))
    assert _rms(best, truth) < 0.08
    assert _facing(float(best.motion[3]) - HEADING) < np.radians(15)


def test_no_volume_no_starts_and_bad_input_is_named() -> None:
    assert data_starts(MODEL, np.ones(MODEL.n_shape), None) == []
    assert body_volume(np.zeros(3), points=np.zeros((0, 3))) is None
    # points far from the box: nothing occupied
    assert body_volume(np.zeros(3), points=np.full((50, 3), 10.0)) is None
    with pytest.raises(ValueError, match="one camera per mask"):
        body_volume(np.zeros(3), masks=[np.ones((4, 4), bool)], cameras=None)


def test_the_search_finds_from_the_data_a_heading_its_fixed_starts_miss() -> None:
    """Only the true heading (between two of the grid's) with the left arm forward explains
    the frame, and the fit does not move (so no start the grid has gets there): the search
    returns it with the data's starts and misses it without them."""
    truth = _walking()
    points = MODEL.skin_points(truth, 6000, seed=2)
    volume = body_volume(np.median(points, axis=0), points=points)
    shoulder = NAMES.index("l_upperarm.0")

    def fit(state: BodyState, shape, iterations: int, rays) -> BodyState:
        return state

    def score(state: BodyState) -> tuple[float, float]:
        if _facing(float(state.motion[3]) - HEADING) < np.radians(10) and abs(state.motion[shoulder] + 0.9) < 0.3:
            return 0.002, 0.95
        return 0.02, 0.7

    shape = np.ones(MODEL.n_shape)
    centre = np.median(points, axis=0)
    assert score(search_pose(MODEL, centre, shape, fit, score, fit_shape=False, headings=8))[0] == 0.02
    found = search_pose(MODEL, centre, shape, fit, score, fit_shape=False, headings=8, volume=volume)
    assert score(found)[0] == 0.002
    assert _rms(found, truth) < 0.06


def test_the_tracker_searches_with_the_volume_of_the_frames_masks(monkeypatch: pytest.MonkeyPatch) -> None:
    """With ``data_starts`` the tracker's search is given the visual hull of the frame's
    masks (which holds the body's joints), and the stored frame keeps no masks; without it
    (the default) no volume."""
    from body_scenes import z_up_cameras

    from elastocap.body import track
    from elastocap.body.starts import BodyVolume

    truth = _walking()
    cameras = z_up_cameras(6, width=240, height=180)
    masks = [MODEL.silhouette(truth, c) for c in cameras]
    given: dict[str, object] = {}

    def search(model, centre, shape, fit, score, **options):
        given.update(options)
        return truth

    monkeypatch.setattr(track, "search_pose", search)
    track.BodyTracker(MODEL, cameras=cameras).update({"masks": masks})
    assert given["volume"] is None
    tracker = track.BodyTracker(MODEL, cameras=cameras, data_starts=True)
    tracker.update({"masks": masks})
    volume = given["volume"]
    assert isinstance(volume, BodyVolume)
    cells = np.round((_joints(truth) - volume.origin) / volume.spacing).astype(int)
    assert volume.occupancy[tuple(cells.T)].all()
    assert tracker._frames[0].masks is None
