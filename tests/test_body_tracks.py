"""Issue 15, item 4: tracks in the body fit (``fit_body(..., tracks=)``).

Two frames of a synthetic body: frame 0 fully seen (skin points), frame 1 with the right
arm moved and no skin point on that arm (occluded). Only correspondences can say where it
went: tracks of frame-0 skin points on that arm, carried to frame 1 with the true motion
(ground truth plus 3 mm noise, not the tracker's), recover its angles; without them the
arm stays where the fit starts.
"""

from __future__ import annotations

import numpy as np
import pytest

from body_scenes import random_state
from elastocap import InvalidInputError, Tracks
from elastocap.body import BodyModel, BodyObservations, fit_body
from elastocap.body.tracks import nearest_part
from elastocap.tracking.flags import TrackFlag

MODEL = BodyModel.default_human()
ARM = [i for i, n in enumerate(MODEL.motion_names) if n.startswith(("r_upperarm", "r_forearm"))]
ARM_PARTS = [MODEL.part_names.index(n) for n in ("r_upperarm", "r_forearm", "r_hand")]
NOISE = 0.003


@pytest.fixture(scope="module")
def scene() -> tuple:
    rng = np.random.default_rng(5)
    first = random_state(MODEL, rng, spread=0.3)
    motion = first.motion.copy()
    motion[ARM] += np.radians([25.0, -20.0, 15.0, 30.0])[: len(ARM)]
    second = first.replace(motion=np.clip(motion, MODEL.lower, MODEL.upper))
    points0 = MODEL.skin_points(first, 3000, seed=1)
    points1 = MODEL.skin_points(second, 3000, seed=2)
    on_arm = np.isin(nearest_part(MODEL, second, points1), ARM_PARTS)
    frames = [BodyObservations(points=points0), BodyObservations(points=points1[~on_arm])]
    # Tracks: frame-0 skin points moved with their part into frame 1.
    part = nearest_part(MODEL, first, points0)
    r0, o0 = MODEL.pose(first)
    r1, o1 = MODEL.pose(second)
    local = np.einsum("tji,tj->ti", r0[part], points0 - o0[part])
    moved = o1[part] + np.einsum("tij,tj->ti", r1[part], local)
    positions = np.stack([points0, moved]) + rng.normal(0, NOISE, (2, len(points0), 3))
    covariances = np.broadcast_to(NOISE**2 * np.eye(3), (2, len(points0), 3, 3)).copy()
    tracks = Tracks(np.array([0, 1]), np.arange(len(points0)), positions, covariances, np.zeros((2, len(points0)), np.uint8))
    return first, second, frames, tracks


def _arm_error_degrees(fit, truth) -> float:
    return float(np.degrees(np.abs(fit.motion[1][ARM] - truth.motion[ARM]).max()))


def test_tracks_recover_an_occluded_arm(scene: tuple) -> None:
    first, second, frames, tracks = scene
    init = [first, first]
    shape = first.shape
    without = fit_body(MODEL, frames, init=init, shape=shape)
    fit = fit_body(MODEL, frames, init=init, shape=shape, tracks=tracks)
    print("right arm's worst angle error, degrees, without / with tracks:",
          _arm_error_degrees(without, second), _arm_error_degrees(fit, second))
    assert _arm_error_degrees(without, second) > 10
    assert _arm_error_degrees(fit, second) < 3
    # The rest of the body stays where the points put it.
    others = [i for i in range(6, MODEL.n_motion) if i not in ARM]
    assert np.degrees(np.abs(fit.motion[1][others] - second.motion[others]).max()) < 3


def test_empty_and_bad_tracks(scene: tuple) -> None:
    first, _, frames, tracks = scene
    plain = fit_body(MODEL, frames, init=[first, first], shape=first.shape)
    empty = Tracks(np.array([0, 1]), np.zeros(0, np.int64), np.zeros((2, 0, 3)), np.zeros((2, 0, 3, 3)), np.zeros((2, 0), np.uint8))
    same = fit_body(MODEL, frames, init=[first, first], shape=first.shape, tracks=empty)
    np.testing.assert_array_equal(same.motion, plain.motion)
    with pytest.raises(InvalidInputError, match="tracks must be"):
        fit_body(MODEL, frames, init=[first, first], tracks=np.zeros((2, 3, 3)))
    far = Tracks(np.array([0, 9]), tracks.ids, tracks.positions, tracks.covariances, tracks.flags)
    with pytest.raises(InvalidInputError, match=r"frames \[9\]"):
        fit_body(MODEL, frames, init=[first, first], tracks=far)
    nan = Tracks(tracks.frames, tracks.ids, tracks.positions.copy(), tracks.covariances.copy(), tracks.flags)
    nan.covariances[1, 0] = np.nan
    with pytest.raises(InvalidInputError, match="not finite"):
        fit_body(MODEL, frames, init=[first, first], tracks=nan)
    assert TrackFlag.TRACKED == 0
    # Anchored observations given directly are checked too.
    bad = BodyObservations(points=frames[0].points, anchored=(np.zeros((2, 3)), np.array([0, 99]), np.zeros((2, 3)), np.full(2, 0.01)))
    with pytest.raises(InvalidInputError, match="part indices"):
        fit_body(MODEL, [bad], init=first)
