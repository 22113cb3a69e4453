"""Issue 15: a late track attached ahead of its anchor frame's fit, through the rigid motion
of its older neighbours back to the rest frame (``TrackTerms(ahead=)``,
``TrackAttachments.attach_ahead``, ``rigid_carry``)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from test_fit_tracks import _tracks

from elastocap import InvalidInputError, TrackTerms, fit_sequence
from elastocap.elastic.tracks import TrackAttachments, rigid_carry


def _rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.radians(degrees)
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.floats(0.0, 170.0))
def test_rigid_carry_takes_points_back_through_any_rigid_motion(seed: int, degrees: float) -> None:
    """Reference points and the points between them moved by one rotation and translation:
    carried back exactly, and trusted."""
    rng = np.random.default_rng(seed)
    rest = rng.random((40, 3))
    points = 0.2 + 0.6 * rng.random((10, 3))
    rotation, shift = _rotation(rng.normal(size=3), degrees), rng.normal(size=3)
    carried, good = rigid_carry(rest @ rotation.T + shift, rest, points @ rotation.T + shift, 6, 10.0, 1e-6)
    assert good.all()
    np.testing.assert_allclose(carried, points, atol=1e-9)


def test_rigid_carry_refuses_neighbours_across_a_joint_or_on_a_line() -> None:
    rng = np.random.default_rng(1)
    # Across a joint: three neighbours on each side of x = 0, the two sides turned 60 degrees
    # apart. No rigid motion fits them.
    left, right = rng.random((3, 3)) * 0.1 - (0.1, 0, 0), rng.random((3, 3)) * 0.1
    rest = np.concatenate([left, right])
    moved = np.concatenate([left, right @ _rotation(np.array([0.0, 0, 1]), 60).T])
    _, good = rigid_carry(moved, rest, np.array([[0.0, 0.05, 0.05]]), 6, 1.0, 0.005)
    assert not good.any()
    # On a line: the turn about it is undetermined.
    line = np.outer(np.linspace(0, 1, 8), (1.0, 2.0, 0.5))
    _, good = rigid_carry(line + 0.3, line, np.array([[0.5, 1.0, 0.3]]), 6, 10.0, 1.0)
    assert not good.any()
    # Too far: a neighbour beyond the radius.
    _, good = rigid_carry(rest, rest, np.array([[5.0, 0, 0]]), 6, 1.0, 1.0)
    assert not good.any()


def test_a_late_track_is_attached_ahead_at_its_true_material_point_on_a_rigidly_moving_body() -> None:
    """A body turned 40 degrees and moved between frames 0 and 1; the fit of frame 1 drifted
    along it (a further turn of 8 degrees). Old tracks attached at the rest frame are
    tracked at frame 1; tracks first seen at frame 1 are attached ahead of frame 1's fit at
    their own material points (the relay's median offset, a translation, cannot undo the
    drift's turn), and pull frame 1 itself."""
    rng = np.random.default_rng(3)
    nodes = rng.random((500, 3))
    rotation, shift = _rotation(np.array([1.0, 2, 0.5]), 40), np.array([0.3, -0.1, 0.2])
    drift = _rotation(np.array([0.0, 0, 1]), 8)
    old, new = 0.2 + 0.6 * rng.random((60, 3)), 0.3 + 0.4 * rng.random((5, 3))
    positions = np.full((2, 65, 3), np.nan)
    positions[0, :60] = old
    positions[1, :60] = old @ rotation.T + shift
    positions[1, 60:] = new @ rotation.T + shift
    fitted = ((nodes - 0.5) @ drift.T + 0.5) @ rotation.T + shift
    material = {}
    for ahead in (0, 6):
        terms = TrackTerms(relay=5, relay_radius=0.5, ahead=ahead, ahead_tolerance=1e-6, ahead_check=0.0, relay_memory=0)
        attachments = TrackAttachments.build(_tracks(positions), rest_frame=0, k=20, terms=terms, node_spacing=0.1)
        assert attachments.attach(0, nodes) == 60
        early = attachments.attach_ahead(1)
        assert early == (5 if ahead else 0)
        pulling = attachments.frame_arrays(1)
        assert len(pulling[0]) == 60 + early
        assert attachments.attach(1, fitted) == 5 - early
        assert attachments.early[60:].all() == bool(ahead)
        material[ahead] = np.einsum("tk,tka->ta", attachments.phi[60:], nodes[attachments.neighbours[60:]])
    np.testing.assert_allclose(material[6], new, atol=1e-9)
    # The relay alone leaves the turn's error (a few cm here).
    assert np.linalg.norm(material[0] - new, axis=1).max() > 0.01


def _turning_ball() -> tuple:
    """A ball (300 nodes) and 80 tracked points on it turning 6 degrees a frame about z over
    3 frames, half of them seen only from frame 1 on (late tracks): (model, field, tracks)."""
    import trimesh

    from elastocap import ElasticModel
    from elastocap.elastic.fit import target_field

    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    field = target_field(ball)
    model = ElasticModel.from_mesh(ball, n_nodes=300)
    rng = np.random.default_rng(5)
    points = rng.normal(size=(80, 3))
    points *= 0.5 / np.linalg.norm(points, axis=1, keepdims=True)
    turn = [_rotation(np.array([0.0, 0, 1]), 6 * f) for f in range(3)]
    positions = np.stack([points @ r.T for r in turn])
    positions[0, 40:] = np.nan
    return model, field, _tracks(positions)


def test_track_ahead_in_the_fit_and_its_bad_values() -> None:
    model, field, tracks = _turning_ball()
    fit = fit_sequence(model, [field] * 3, tracks=tracks, track_terms=TrackTerms(ahead=6))
    # Those whose six older neighbours lie within the relay radius (4 node spacings).
    ahead = fit.fits[1].metrics["tracks_attached_ahead"]
    assert ahead >= 30
    assert fit.fits[1].metrics["tracks"] == 40 + ahead
    assert fit.fits[1].metrics["tracks_attached"] == 40
    plain = fit_sequence(model, [field] * 3, tracks=tracks, track_terms=TrackTerms(ahead=0))
    assert plain.fits[1].metrics["tracks"] == 40
    # The carry is on by default.
    default = fit_sequence(model, [field] * 3, tracks=tracks)
    assert default.fits[1].metrics["tracks_attached_ahead"] >= 30
    for value in (-1, 1.5, True):
        with pytest.raises(InvalidInputError, match="TrackTerms.ahead"):
            TrackTerms(ahead=value)
    with pytest.raises(InvalidInputError, match="TrackTerms.ahead_tolerance"):
        TrackTerms(ahead=6, ahead_tolerance=0.0)
