"""Issue 15, session 26: ``fit_sequence``'s track options as one object
(:class:`elastocap.TrackTerms`): its defaults are the fit's, its lengths default to node
spacings, its values are checked on construction, and the former flat keywords map onto it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_fit_tracks_ahead import _turning_ball

from elastocap import InvalidInputError, TrackTerms, fit_sequence
from elastocap.elastic.track_terms import TrackLengths

FIELDS = [f.name for f in dataclasses.fields(TrackTerms)]


def test_the_terms_left_out_the_default_terms_and_their_lengths_spelled_out_are_one_fit() -> None:
    """On the turning ball (late tracks carried ahead, relayed and spread): no terms, the
    default terms, and the defaults with every length given in world units at the model's
    node spacing fit to the bit alike; a change of one term changes the fit."""
    model, field, tracks = _turning_ball()
    spacing = float(np.mean(model.volumes) ** (1 / 3))
    lengths = TrackTerms().lengths(spacing)
    spelled = TrackTerms(**dataclasses.asdict(lengths))
    fits = [fit_sequence(model, [field] * 3, tracks=tracks, track_terms=terms) for terms in (None, TrackTerms(), spelled)]
    assert fits[0].fits[1].metrics["tracks_attached_ahead"] >= 30
    for other in fits[1:]:
        for f in range(3):
            np.testing.assert_array_equal(other.fits[f].positions, fits[0].fits[f].positions)
    moved = fit_sequence(model, [field] * 3, tracks=tracks, track_terms=TrackTerms(spread_radius=2 * lengths.spread_radius))
    assert not np.allclose(moved.fits[2].positions, fits[0].fits[2].positions)


def test_lengths_default_to_node_spacings_and_keep_given_values() -> None:
    assert TrackTerms().lengths(0.2) == TrackLengths(sigma=0.05, relay_radius=0.8, ahead_tolerance=0.1,
                                                      ahead_check=0.6000000000000001, spread_radius=0.8)
    given = TrackTerms(sigma=0.01, relay_radius=0.3, ahead_tolerance=0.02, ahead_check=0.0, spread_radius=0.5)
    assert given.lengths(0.2) == TrackLengths(0.01, 0.3, 0.02, 0.0, 0.5)
    for spacing in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(InvalidInputError, match="node_spacing"):
            TrackTerms().lengths(spacing)


@pytest.mark.parametrize("name, bad", [
    ("weight", -1.0), ("weight", np.nan), ("sigma", 0.0), ("scale", 0.0), ("scale", np.inf), ("relay", -1),
    ("relay", 2.5), ("relay", True), ("relay_radius", 0.0), ("ahead", 1.5), ("ahead_tolerance", -0.1),
    ("ahead_check", -1.0), ("ahead_chain", -1), ("ahead_age", 1), ("relayed_weight", -0.5), ("relay_memory", True),
    ("ahead_memory", "yes"), ("spread", -0.5), ("spread_age", 0.0), ("spread_radius", np.nan),
    ("spread_relayed", np.inf), ("spread_relayed_dense", 1.5), ("weight", "1"),
])
def test_a_bad_value_is_refused_by_name_and_value(name: str, bad: object) -> None:
    with pytest.raises(InvalidInputError, match=f"TrackTerms.{name} must .*got {bad!r}|TrackTerms.{name} must .*got {bad}"):
        TrackTerms(**{name: bad})


def test_values_are_stored_as_python_numbers_and_the_terms_are_frozen() -> None:
    terms = TrackTerms(weight=np.float32(2), relay=np.int64(3), ahead_age=np.bool_(True), spread_age=np.int32(10))
    assert (type(terms.weight), type(terms.relay), type(terms.ahead_age), type(terms.spread_age)) == (float, int, bool, float)
    assert terms == TrackTerms(weight=2.0, relay=3, ahead_age=True, spread_age=10.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        terms.relay = 4  # type: ignore[misc]
    # Zero lengths where zero means "off" and zero weights are allowed.
    TrackTerms(weight=0.0, ahead_check=0.0, spread=0.0, relay=0, ahead=0, spread_relayed=0.0, relayed_weight=0.0)


def test_the_former_flat_keywords_map_onto_the_fields() -> None:
    flat = {f"track_{name}": getattr(TrackTerms(), name) for name in FIELDS}
    assert TrackTerms.from_flat(flat) == TrackTerms()
    assert TrackTerms.from_flat({"track_ahead": 2, "track_spread_age": 15.0}) == TrackTerms(ahead=2, spread_age=15.0)
    assert TrackTerms.from_flat({}) == TrackTerms()
    for unknown in ({"track_settle": 2}, {"ahead": 2}, {"stiffness": 1.0}):
        with pytest.raises(InvalidInputError, match="unknown option"):
            TrackTerms.from_flat(unknown)
    with pytest.raises(InvalidInputError, match="TrackTerms.ahead"):
        TrackTerms.from_flat({"track_ahead": -2})


def test_fit_sequence_refuses_anything_but_terms_and_the_former_keywords() -> None:
    model, field, tracks = _turning_ball()
    with pytest.raises(InvalidInputError, match="track_terms must be"):
        fit_sequence(model, [field] * 3, tracks=tracks, track_terms={"ahead": 2})  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="track_ahead"):
        fit_sequence(model, [field] * 3, tracks=tracks, track_ahead=2)  # type: ignore[call-arg]
