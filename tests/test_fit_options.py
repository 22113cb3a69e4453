"""Session 27: ``fit_sequence``'s options grouped by what they govern
(:mod:`elastocap.elastic.fit_options`: ``SelfIntersection``, ``SilhouetteTerm``, ``StiffStage``,
``StoppingRules``): their defaults are the fit's, their values are checked on construction
(by field name, never a NaN through), the fit refuses anything else, each object reaches the
fit, and the former flat keywords map onto them (``grouped_keywords``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_fit import _two_legs, two_blocks

from elastocap import (
    ElasticModel,
    InvalidInputError,
    SelfIntersection,
    SilhouetteTerm,
    StiffStage,
    StoppingRules,
    TrackTerms,
    fit_sequence,
)
from elastocap.elastic.fit_options import grouped_keywords

GROUPS = (SelfIntersection, SilhouetteTerm, StiffStage, StoppingRules)


@pytest.fixture(scope="module")
def legs() -> tuple[ElasticModel, list]:
    """Two legs swinging apart (rest frame 0 and two more frames): a few seconds a fit."""
    model = ElasticModel.from_mesh(_two_legs(0.0).mesh(), n_nodes=300, rotation="warped", seed=0)
    return model, [_two_legs(a) for a in (0.0, 15.0, 30.0)]


def test_the_default_objects_and_their_values_spelled_out_are_the_default_fit(legs: tuple) -> None:
    model, targets = legs
    plain = fit_sequence(model, targets)
    defaults = fit_sequence(model, targets, self_intersection=SelfIntersection(), silhouette=SilhouetteTerm(),
                            stiff_stage=StiffStage(), stopping=StoppingRules(), track_terms=TrackTerms())
    spelled = fit_sequence(
        model, targets, self_intersection=SelfIntersection(weight=1.0, hold=False),
        silhouette=SilhouetteTerm(weight=None, stage="chain"), stiff_stage=StiffStage(stiffness=10.0, frames="first"),
        stopping=StoppingRules(max_iterations=10, stop_fraction=0.01, staged_stop_fraction=0.002,
                               solver_tolerance=1e-6, staged_tolerance=1e-5))
    for other in (defaults, spelled):
        for f in plain.frames:
            np.testing.assert_array_equal(other.fits[f].positions, plain.fits[f].positions)


def test_each_object_reaches_the_fit(legs: tuple) -> None:
    model, targets = legs
    plain = fit_sequence(model, targets)
    # The stopping rules: at most two iterations a frame.
    short = fit_sequence(model, targets, stopping=StoppingRules(max_iterations=2))
    assert all(short.fits[f].metrics["iterations"] <= 2 for f in short.frames)
    assert max(plain.fits[f].metrics["iterations"] for f in plain.frames) > 2
    # The stiff stage: a stiffer first stage moves frame 1 (the first from rest), not the rest frame.
    stiffer = fit_sequence(model, targets, stiff_stage=StiffStage(stiffness=100.0))
    np.testing.assert_array_equal(stiffer.fits[0].positions, plain.fits[0].positions)
    assert np.abs(stiffer.fits[1].positions - plain.fits[1].positions).max() > 1e-6
    every = fit_sequence(model, targets, stiff_stage=StiffStage(frames="all"))
    assert ["stiff_stage_iterations" in every.fits[f].metrics for f in every.frames] == [False, True, True]
    off = fit_sequence(model, targets, stiff_stage=None)
    assert not any("stiff_stage_iterations" in off.fits[f].metrics for f in off.frames)


def test_the_self_intersection_term_at_weight_zero_is_the_term_off_to_the_bit() -> None:
    """Two blocks pressed into each other (the targets' gap down to -0.2): off (None) and at
    weight 0 fit alike; on, the term moves the last frame's fit (4.5 mm at most)."""
    model = ElasticModel.from_mesh(two_blocks(0.3), n_nodes=600, rotation="warped", seed=0)
    targets = [two_blocks(gap) for gap in (0.3, 0.1, -0.1, -0.2)]
    off = fit_sequence(model, targets, self_intersection=None)
    zero = fit_sequence(model, targets, self_intersection=SelfIntersection(weight=0.0))
    on = fit_sequence(model, targets)
    for f in off.frames:
        np.testing.assert_array_equal(zero.fits[f].positions, off.fits[f].positions)
    assert np.abs(on.fits[3].positions - off.fits[3].positions).max() > 1e-3


@pytest.mark.parametrize("kind, name, bad", [
    (SelfIntersection, "weight", -1.0), (SelfIntersection, "weight", np.nan), (SelfIntersection, "weight", "1"),
    (SelfIntersection, "hold", 1), (SilhouetteTerm, "weight", -0.5), (SilhouetteTerm, "weight", np.inf),
    (SilhouetteTerm, "stage", "after"), (SilhouetteTerm, "stage", None), (StiffStage, "stiffness", 0.0),
    (StiffStage, "stiffness", np.nan), (StiffStage, "stiffness", True), (StiffStage, "frames", "some"),
    (StoppingRules, "max_iterations", 0), (StoppingRules, "max_iterations", 2.5), (StoppingRules, "max_iterations", True),
    (StoppingRules, "stop_fraction", 1.0), (StoppingRules, "stop_fraction", -0.01), (StoppingRules, "stop_fraction", np.nan),
    (StoppingRules, "staged_stop_fraction", 1.5), (StoppingRules, "solver_tolerance", -1e-6),
    (StoppingRules, "staged_tolerance", np.inf),
])
def test_a_bad_value_is_refused_by_name_and_value(kind: type, name: str, bad: object) -> None:
    with pytest.raises(InvalidInputError, match=rf"{kind.__name__}\.{name} must .*got {bad!r}|"
                                                rf"{kind.__name__}\.{name} must .*got {bad}"):
        kind(**{name: bad})


def test_values_are_stored_as_python_numbers_and_the_objects_are_frozen() -> None:
    rules = StoppingRules(max_iterations=np.int64(5), stop_fraction=np.float32(0.5), solver_tolerance=0)
    assert (type(rules.max_iterations), type(rules.stop_fraction), type(rules.solver_tolerance)) == (int, float, float)
    assert rules == StoppingRules(max_iterations=5, stop_fraction=0.5, solver_tolerance=0.0)
    assert type(SelfIntersection(hold=np.bool_(True)).hold) is bool
    assert type(StiffStage(stiffness=np.int32(20)).stiffness) is float
    for group in GROUPS:
        made = group()
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(made, dataclasses.fields(group)[0].name, 1.0)
        with pytest.raises(TypeError):
            group(1.0)  # keyword-only
    # Zero where zero means "off" or "no stop" is allowed.
    SilhouetteTerm(weight=0.0)
    SelfIntersection(weight=0.0)
    StoppingRules(stop_fraction=0.0, staged_stop_fraction=0.0, solver_tolerance=0.0, staged_tolerance=0.0)


def test_the_silhouette_weight_by_default_follows_the_data() -> None:
    assert SilhouetteTerm().weight_for(3, True) == 1.0
    assert SilhouetteTerm().weight_for(3, False) == 0.0
    assert SilhouetteTerm().weight_for(2, True) == 0.0
    assert SilhouetteTerm(weight=2.5).weight_for(2, False) == 2.5


def test_fit_sequence_refuses_anything_but_the_objects_and_the_former_keywords(legs: tuple) -> None:
    model, targets = legs
    for keyword, value in (("self_intersection", False), ("silhouette", 1.0), ("stiff_stage", 10.0),
                           ("stopping", {"max_iterations": 5}), ("silhouette", StiffStage())):
        with pytest.raises(InvalidInputError, match=f"{keyword} must be an elastocap.* or None, got"):
            fit_sequence(model, targets, **{keyword: value})
    for former in ("contact", "hold_contacts", "silhouette_stage", "stiff_stage_frames", "max_iterations",
                   "stop_fraction", "staged_stop_fraction", "solver_tolerance", "staged_tolerance"):
        with pytest.raises(TypeError, match=former):
            fit_sequence(model, targets, **{former: 1})


def test_the_former_flat_keywords_map_onto_the_objects() -> None:
    assert grouped_keywords({}) == {}
    assert grouped_keywords({"stiffness": 2.0, "coverage": 0.0, "invalidate": False}) == {
        "stiffness": 2.0, "coverage": 0.0, "invalidate": False}
    assert grouped_keywords({"contact": 2.0, "hold_contacts": True}) == {
        "self_intersection": SelfIntersection(weight=2.0, hold=True)}
    assert grouped_keywords({"self_intersection": False}) == {"self_intersection": None}
    assert grouped_keywords({"self_intersection": True}) == {}
    assert grouped_keywords({"silhouette": 0}) == {"silhouette": SilhouetteTerm(weight=0.0)}
    assert grouped_keywords({"silhouette": None, "silhouette_stage": "refine"}) == {
        "silhouette": SilhouetteTerm(stage="refine")}
    assert grouped_keywords({"stiff_stage": 10.0, "stiff_stage_frames": "all"}) == {
        "stiff_stage": StiffStage(stiffness=10.0, frames="all")}
    assert grouped_keywords({"stiff_stage": None}) == {"stiff_stage": None}
    assert grouped_keywords({"solver_tolerance": 1e-5, "max_iterations": 4}) == {
        "stopping": StoppingRules(solver_tolerance=1e-5, max_iterations=4)}
    assert grouped_keywords({"track_ahead": 2, "track_terms": {"spread_age": 15.0}}) == {
        "track_terms": TrackTerms(ahead=2, spread_age=15.0)}
    # The objects' own spelling: a mapping of fields, or the object.
    assert grouped_keywords({"stopping": {"max_iterations": 4}, "stiff_stage": StiffStage(frames="all")}) == {
        "stopping": StoppingRules(max_iterations=4), "stiff_stage": StiffStage(frames="all")}
    for bad, message in (({"max_iterations": 4, "stopping": {"max_iterations": 5}}, "stopping.max_iterations given twice"),
                         ({"stiff_stage": None, "stiff_stage_frames": "all"}, "stiff_stage is turned off"),
                         ({"self_intersection": False, "contact": 2.0}, "self_intersection is turned off"),
                         ({"stopping": StoppingRules(), "max_iterations": 4}, "stopping given as an object and as"),
                         ({"self_intersection": 1}, "self_intersection must be a bool"),
                         ({"stop_fraction": 2.0}, "StoppingRules.stop_fraction"),
                         ({"track_settle": 2}, "unknown option")):
        with pytest.raises(InvalidInputError, match=message):
            grouped_keywords(bad)
