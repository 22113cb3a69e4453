"""Issue 15: the late tracks' attachment, session 20 (branch trackfit8): the carry ahead
checked against the relay (``ahead_check``), the relay and the carry from tracks lost
in the frames before (``relay_memory``, ``ahead_memory``), the carried tracks'
age in the spread (``ahead_age``), chained carries (``ahead_chain``) and the
relayed tracks' weight (``relayed_weight``)."""

from __future__ import annotations

import numpy as np
import pytest
from test_fit_tracks import _tracks
from test_fit_tracks_ahead import _rotation, _turning_ball

from elastocap import InvalidInputError, TrackTerms, fit_sequence
from elastocap.elastic.tracks import TrackAttachments


def _material(attachments: TrackAttachments, nodes: np.ndarray, which: slice) -> np.ndarray:
    return np.einsum("tk,tka->ta", attachments.phi[which], nodes[attachments.neighbours[which]])


def test_a_carry_far_from_the_relay_is_dropped_and_left_to_the_relay() -> None:
    """Six old tracks on a narrow strip (3 mm wide), tracked at frame 1 with half a
    millimetre of error across it: their rigid motion turns the strip 18 degrees about its
    length (the residual test passes), which carries a new track 5 cm above the strip 1.5 cm
    off. The relay's median offset (a translation) is off by the tracking error only. With
    ``ahead_check`` 5 mm the carry is dropped and the track attached after the fit by the
    relay; without, it is attached ahead, wrong."""
    rng = np.random.default_rng(7)
    nodes = rng.random((600, 3))
    shift = np.array([0.05, 0.0, 0.0])
    centre = np.full(3, 0.5)
    strip = np.array([[x, y, 0.0] for x in (-0.01, 0.0, 0.01) for y in (-0.0015, 0.0015)])
    error = np.where(strip[:, 1:2] > 0, 1.0, -1.0) * np.array([0.0, 0.0, 0.0005])
    new = centre + np.array([[0.0, 0.0, 0.05]])
    positions = np.full((2, 7, 3), np.nan)
    positions[0, :6] = centre + strip
    positions[1, :6] = centre + strip + shift + error
    positions[1, 6:] = new + shift
    fitted = nodes + shift
    errors = {}
    for check in (0.0, 0.005):
        terms = TrackTerms(relay=5, relay_radius=0.5, ahead=6, ahead_tolerance=0.001, ahead_check=check, relay_memory=0)
        attachments = TrackAttachments.build(_tracks(positions), rest_frame=0, k=20, terms=terms, node_spacing=0.1)
        attachments.attach(0, nodes)
        early = attachments.attach_ahead(1, fitted)
        assert early == (0 if check else 1)
        assert attachments.attach(1, fitted) == (1 if check else 0)
        errors[check] = float(np.linalg.norm(_material(attachments, nodes, slice(6, 7)) - new))
    assert errors[0.0] > 0.01
    assert errors[0.005] < 0.001


@pytest.mark.parametrize("ahead", [False, True])
def test_tracks_lost_the_frame_before_relay_and_carry_the_tracks_that_replace_them(ahead: bool) -> None:
    """A body moved by 5 cm at frames 1 and 2, its fit drifted by 2 cm along it at both.
    Old tracks are tracked at frames 0 and 1 and lost at 2, where new tracks start: no
    track tracked at frame 2 is older, so without memory the new tracks are attached where
    the drifted fit puts them (2 cm off); with ``relay_memory`` 1 the old tracks' offset at
    frame 1 places them at their true material points, after the fit (relay) or, with
    ``ahead_memory``, before it from the frame's start."""
    rng = np.random.default_rng(11)
    nodes = rng.random((600, 3))
    shift, drift = np.array([0.05, 0.0, 0.0]), np.array([0.0, 0.02, 0.0])
    old, new = 0.3 + 0.4 * rng.random((40, 3)), 0.4 + 0.2 * rng.random((6, 3))
    positions = np.full((3, 46, 3), np.nan)
    positions[0, :40] = old
    positions[1, :40] = old + shift
    positions[2, 40:] = new + 2 * shift
    errors = {}
    for memory in (0, 1):
        terms = TrackTerms(relay=5, relay_radius=0.5, ahead=6 if ahead else 0, ahead_tolerance=1e-3, ahead_check=0.0,
                           relay_memory=memory, ahead_memory=ahead)
        attachments = TrackAttachments.build(_tracks(positions), rest_frame=0, k=20, terms=terms, node_spacing=0.1)
        attachments.attach(0, nodes)
        attachments.attach_ahead(1, nodes + shift + drift)
        attachments.attach(1, nodes + shift + drift)
        early = attachments.attach_ahead(2, nodes + 2 * shift + drift)
        assert early == (6 if ahead and memory else 0)
        attachments.attach(2, nodes + 2 * shift + drift)
        assert attachments.attached[40:].all()
        errors[memory] = np.linalg.norm(_material(attachments, nodes, slice(40, 46)) - new, axis=1).max()
    np.testing.assert_allclose(errors[0], 0.02, atol=1e-6)
    assert errors[1] < 1e-6


def test_a_carried_track_is_aged_from_its_carriers_anchors_and_chains_carry_from_the_frames_own() -> None:
    """On a grid body moved rigidly, tracks first seen at frame 2 beside the old tracks (x =
    0.55) are carried ahead by them; those one step farther (x = 0.6) have one old track
    within the radius and are carried only in a chain from the first ones
    (``ahead_chain``), at their exact material points. With ``ahead_age`` a carried track's
    age in the spread at frame 3 is its carriers' (3 frames: they are anchored at the rest
    frame), not its own 1."""
    rng = np.random.default_rng(5)
    nodes = rng.random((800, 3))
    shift = np.array([0.02, 0.01, 0.0])
    axis = np.arange(0.3, 0.501, 0.05)
    old = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    side = np.arange(0.4, 0.501, 0.05)
    new = np.array([[x, y, z] for x in (0.55, 0.6) for y in side for z in side])
    points = np.concatenate([old, new])
    positions = np.stack([points + f * shift for f in range(4)])
    positions[:2, len(old):] = np.nan
    outer = np.flatnonzero(points[:, 0] > 0.58)
    for age, chain in ((False, 0), (True, 0), (False, 2), (True, 2)):
        terms = TrackTerms(relay=5, relay_radius=0.11, ahead=6, ahead_tolerance=1e-3, ahead_check=0.0, ahead_age=age,
                           ahead_chain=chain, relay_memory=0)
        attachments = TrackAttachments.build(_tracks(positions), rest_frame=0, k=20, terms=terms, node_spacing=0.1)
        for f in range(4):
            attachments.attach_ahead(f, nodes + f * shift)
            attachments.attach(f, nodes + f * shift)
        early = attachments.early
        assert not early[: len(old)].any()
        assert early[len(old):].any()
        assert early[outer].all() == (chain > 0)
        assert not early[outer].any() or chain > 0
        carried = np.flatnonzero(early)
        np.testing.assert_allclose(np.einsum("tk,tka->ta", attachments.phi[carried], nodes[attachments.neighbours[carried]]),
                                   points[carried], atol=1e-9)
        ages = attachments.frame_ages(3)
        np.testing.assert_allclose(ages[: len(old)], 3)
        np.testing.assert_allclose(ages[len(old):][early[len(old):]], 3 if age else 1)


def test_the_new_options_in_the_fit_and_their_bad_values() -> None:
    model, field, tracks = _turning_ball()
    plain = fit_sequence(model, [field] * 3, tracks=tracks, track_terms=TrackTerms(ahead=6))
    # Every option at a value that changes nothing on this sequence: the same fit.
    same = fit_sequence(model, [field] * 3, tracks=tracks,
                        track_terms=TrackTerms(ahead=6, ahead_check=10.0, relay_memory=1, ahead_memory=True,
                                               relayed_weight=1.0))
    for f in range(3):
        np.testing.assert_allclose(same.fits[f].positions, plain.fits[f].positions, atol=1e-12)
    # Without the carry the late tracks are attached by the relay after frame 1's fit; at
    # weight 0 they do not pull frame 2.
    relayed = fit_sequence(model, [field] * 3, tracks=tracks, track_terms=TrackTerms(relayed_weight=0.0, spread=0.0))
    unweighted = fit_sequence(model, [field] * 3, tracks=tracks, track_terms=TrackTerms(spread=0.0))
    assert not np.allclose(relayed.fits[2].positions, unweighted.fits[2].positions)
    for name, value in (("ahead_check", -1.0), ("ahead_check", np.nan), ("ahead_chain", -1),
                        ("ahead_chain", 1.5), ("relay_memory", -1), ("relay_memory", True),
                        ("relayed_weight", -0.5), ("relayed_weight", np.inf)):
        with pytest.raises(InvalidInputError, match=f"TrackTerms.{name}"):
            TrackTerms(**{name: value})
