"""Issue 15, session 21 (branch trackfit9): the spread's trust in the tracks attached by the
relay alone (``TrackTerms(spread_relayed=)``, ``spread_pulls(trust=)``,
``TrackAttachments.frame_relayed``).

A late track that the carry cannot take is attached after its anchor frame's fit, where the
relay's offsets put it; on a fast limb that fit has drifted and the relay corrects it only
partly, so the track's material point is wrong and its correction, spread along the surface,
drags every node around it the same wrong way (benches/README.md, trackfit9: seed 14's right
hand)."""

from __future__ import annotations

import numpy as np
import pytest
from test_fit_tracks import _tracks, _two_spheres
from test_fit_tracks_ahead import _rotation, _turning_ball

from elastocap import InvalidInputError, SequenceFit, TrackTerms, fit_sequence
from elastocap.elastic.track_spread import spread_pulls
from elastocap.elastic.track_weights import material_weights
from elastocap.elastic.tracks import TrackAttachments


def test_a_tracks_trust_in_the_spread_scales_its_pulls_and_zero_spreads_nothing() -> None:
    """One track on a sphere: at trust 0.5 every spread pull weighs exactly half of what
    it weighs at trust 1 (no node's pulls reach the share's cap), its own row is unchanged;
    at trust 0 only its own row is left. Bad trusts are refused."""
    start, faces, _ = _two_spheres()
    surface = np.arange(len(start))
    point = np.array([[0.1, 0.0, 0.0]])
    neighbours, phi = material_weights(point, start, 20)
    placed = np.einsum("tk,tkd->td", phi, start[neighbours])
    sigma = 0.005
    arrays = (neighbours, phi, placed + [0.0, 0.01, 0.0], np.eye(3)[None] / sigma**2)
    kwargs = dict(share=1.0, age=5.0, radius=0.05, sigma=sigma)
    full = spread_pulls(arrays, np.zeros(1), start, surface, faces, **kwargs)
    half = spread_pulls(arrays, np.zeros(1), start, surface, faces, trust=np.array([0.5]), **kwargs)
    assert len(full[0]) > 20
    # Rows whose weight falls under the cutoff at half trust are dropped: compare the rest.
    kept = np.isin(full[0][:, 0], half[0][1:, 0])
    kept[0] = True
    for a, b in zip(full, half):
        assert len(b) >= 0.9 * len(a)
    np.testing.assert_array_equal(half[0], full[0][kept])
    np.testing.assert_allclose(half[2], full[2][kept])
    np.testing.assert_allclose(half[3][0], full[3][0])
    np.testing.assert_allclose(half[3][1:], 0.5 * full[3][kept][1:], rtol=1e-12)
    none = spread_pulls(arrays, np.zeros(1), start, surface, faces, trust=np.zeros(1), **kwargs)
    assert len(none[0]) == 1
    for bad in (np.array([-1.0]), np.array([np.nan]), np.ones(2)):
        with pytest.raises(InvalidInputError, match="trust"):
            spread_pulls(arrays, np.zeros(1), start, surface, faces, trust=bad, **kwargs)


def test_the_relayed_tracks_are_the_late_ones_not_carried_ahead() -> None:
    """On the turning ball (40 tracks from frame 0, 40 from frame 1): without the carry the
    40 late tracks pulling frame 2 are all relayed, the 40 old ones none; with it, only the
    late tracks the carry could not take are."""
    model, field, tracks = _turning_ball()
    spacing = float(np.mean(model.volumes) ** (1 / 3))
    for ahead in (0, 6):
        terms = TrackTerms(relay=5, ahead=ahead, ahead_check=0.0, relay_memory=0)
        attachments = TrackAttachments.build(tracks, 0, model.neighbors.shape[1], terms, spacing)
        fitted = [model.nodes @ _rotation(np.array([0.0, 0, 1]), 6 * f).T for f in range(3)]
        for f in range(3):
            attachments.attach_ahead(f, fitted[f])
            attachments.attach(f, fitted[f])
        relayed = attachments.frame_relayed(2)
        use = attachments._pulling(2)
        assert len(relayed) == use.sum() == 80
        late = np.flatnonzero(use) >= 40
        assert not relayed[~late].any()
        np.testing.assert_array_equal(relayed[late], ~attachments.early[40:])
        if ahead == 0:
            assert relayed[late].all()
        else:
            assert attachments.early[40:].sum() >= 30
    assert len(attachments.frame_relayed(7)) == 0


def test_relayed_tracks_attached_wrong_drag_the_surface_less_without_their_spread() -> None:
    """The turning ball with its late tracks matched 10 degrees too far round at their anchor
    frame (a wrong match, then found right in frame 2): the relay attaches them 10 degrees
    off, and in frame 2 they pull their wrong material points to the right places, turning
    the surface back. Without their spread (``TrackTerms.spread_relayed`` 0) the old tracks'
    material points end nearer their tracked positions; at 1 the fit is the default's to
    the bit; with the spread off the option changes nothing."""
    model, field, tracks = _turning_ball()
    wrong = tracks.positions.copy()
    turn = _rotation(np.array([0.0, 0, 1]), 10.0)
    wrong[1, 40:] = wrong[1, 40:] @ turn.T
    tracks = _tracks(wrong)

    def old_error(fit) -> float:
        spacing = float(np.mean(model.volumes) ** (1 / 3))
        attachments = TrackAttachments.build(tracks, 0, model.neighbors.shape[1],
                                             TrackTerms(relay=5, ahead=0, relay_memory=0), spacing)
        attachments.attach(0, fit.fits[0].positions)
        at = np.einsum("tk,tkd->td", attachments.phi[:40], fit.fits[2].positions[attachments.neighbours[:40]])
        return float(np.linalg.norm(at - wrong[2, :40], axis=1).mean())

    def fit(**terms) -> SequenceFit:
        return fit_sequence(model, [field] * 3, tracks=tracks, track_terms=TrackTerms(ahead=0, **terms))

    default = fit()
    same = fit(spread_relayed=1.0)
    for f in range(3):
        np.testing.assert_array_equal(same.fits[f].positions, default.fits[f].positions)
    without = fit(spread_relayed=0.0)
    assert old_error(without) < 0.5 * old_error(default)  # 2.9 cm -> 0.9 cm
    off = fit(spread=0.0)
    off_relayed = fit(spread=0.0, spread_relayed=0.0)
    for f in range(3):
        np.testing.assert_array_equal(off.fits[f].positions, off_relayed.fits[f].positions)
    for value in (-0.5, np.nan, np.inf):
        with pytest.raises(InvalidInputError, match="TrackTerms.spread_relayed"):
            TrackTerms(spread_relayed=value)


def test_relayed_tracks_among_many_older_ones_keep_their_spread() -> None:
    """``TrackTerms.spread_relayed_dense``: on the turning ball each late track has older tracks
    within the relay radius at its anchor frame (counted as a k-d tree would), so a
    threshold of 1 leaves every relayed track its spread (the default's fit to the bit) and
    one above any count takes it from all of them (``spread_relayed``'s fit to the
    bit); between, the fit is neither. Bad values refused."""
    model, field, tracks = _turning_ball()
    spacing = float(np.mean(model.volumes) ** (1 / 3))
    attachments = TrackAttachments.build(tracks, 0, model.neighbors.shape[1], TrackTerms(relay=5, ahead=0, relay_memory=0),
                                         spacing)
    attachments.attach(0, model.nodes)
    attachments.count_older(1)
    late = tracks.positions[1, 40:]
    expected = (np.linalg.norm(late[:, None] - tracks.positions[1, None, :40], axis=2) <= 4 * spacing).sum(axis=1)
    np.testing.assert_array_equal(attachments.older_near[40:], expected)
    assert expected.min() >= 1 and expected.max() < 40
    np.testing.assert_array_equal(attachments.older_near[:40], 0)
    def fit(**terms) -> SequenceFit:
        return fit_sequence(model, [field] * 3, tracks=tracks, track_terms=TrackTerms(ahead=0, **terms))

    default = fit()
    without = fit(spread_relayed=0.0)
    kept = fit(spread_relayed=0.0, spread_relayed_dense=1)
    dropped = fit(spread_relayed=0.0, spread_relayed_dense=40)
    middle = fit(spread_relayed=0.0, spread_relayed_dense=int(np.median(expected)))
    for f in range(3):
        np.testing.assert_array_equal(kept.fits[f].positions, default.fits[f].positions)
        np.testing.assert_array_equal(dropped.fits[f].positions, without.fits[f].positions)
    assert not np.allclose(middle.fits[2].positions, default.fits[2].positions)
    assert not np.allclose(middle.fits[2].positions, without.fits[2].positions)
    for value in (-1, 1.5, True):
        with pytest.raises(InvalidInputError, match="TrackTerms.spread_relayed_dense"):
            TrackTerms(spread_relayed_dense=value)
