"""The options of :func:`elastocap.fit_sequence` grouped by what they govern (session 27; the
track term's are :class:`~elastocap.elastic.track_terms.TrackTerms`, session 26):

- :class:`SelfIntersection`: the self-intersection term (SPEC 5, step 3): its weight and
  whether a contact is held;
- :class:`SilhouetteTerm`: the silhouette term (SPEC 5.1): its weight and how it enters a
  frame (the cameras and masks it reads stay ``fit_sequence``'s data arguments);
- :class:`StiffStage`: a stiff first fit of a frame: its stiffness and which frames;
- :class:`StoppingRules`: when a frame's iteration and each linear solve stop.

The weights a user sets on their own (``stiffness``, ``coverage``, ``volume``) and the
switches ``invalidate`` and ``predict`` stay ``fit_sequence``'s keywords: each is one value,
and an object around it would only lengthen the common call.

Each object is frozen and keyword-only (``dataclasses.replace`` makes a variant) and checks
its values on construction (:class:`InvalidInputError` naming the field and the value);
numbers are stored as Python's own. :func:`grouped_keywords` reads a mapping of
``fit_sequence``'s keywords as they were before they were grouped (the commands of
benches/README.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from elastocap._core import InvalidInputError
from elastocap.elastic.option_checks import checked, checked_choice
from elastocap.elastic.track_terms import TrackTerms

__all__ = ["SelfIntersection", "SilhouetteTerm", "StiffStage", "StoppingRules", "grouped_keywords"]

# The silhouette term's weight when cameras and masks are given (benches/README.md, issue 17:
# horse gallop fit/hull 0.961 -> 0.802, drift 1.81% -> 1.66% of the diagonal).
SILHOUETTE = 1.0
# The linear solve's relative residual per iteration.
SOLVER_TOLERANCE = 1e-6
# ... and in the fit to the hull that the silhouette term's refinement starts from (a
# fifth of a frame's PCG iterations at 2,465 nodes; horse gallop fit/hull 0.802 -> 0.803,
# drift 1.657% -> 1.682%; 1e-4 saved more but moved the refinement's result on the pitted
# block of tests/test_fit_silhouette.py: benches/README.md, session 10).
STAGED_TOLERANCE = 1e-5
# A frame's iteration stops when its last decrease of the objective is below this fraction
# of its total decrease so far (SPEC 5: 1%) ...
STOP_FRACTION = 0.01
# ... and the fit to the hull alone that the silhouette term's refinement starts from
# goes further to its minimum: along the surface is where it stops short. Horse gallop
# (benches/eval_horse.py, 5,873 nodes): mean drift 1.717% -> 1.679% of the diagonal for 7%
# more iterations (0.002 in both stages: 1.660% for 27% more, and the refinement then swells
# past the volume bound on coarse masks; in the refinement alone: 1.714%); benches/README.md,
# session 13.
STAGED_STOP_FRACTION = 0.002
# Iterations per frame (SPEC 5: 10).
MAX_ITERATIONS = 10
# A stiff first stage (``fit_sequence(stiff_stage=)``) on the frames fitted without a
# motion prediction: the stiffness of a first fit of the frame, from which the frame is then
# fitted at its own stiffness. At stiffness 1 a limb that moved a limb's width or more is
# met by the surface term locally (each node to its nearest target surface) and slides its
# material along the limb instead of turning it; much stiffer, the limb turns as a whole
# (benches/README.md, trackfit10: seed 25's frame 1, the left leg's first step from rest,
# shin and foot material 8.5 / 10.6% of the diagonal off -> 1.9 / 1.4% at 10 then 1; 5-100
# alike, 3 not enough). Textured fast capture with tracks, ten tuning seeds: mean drift
# ratio 0.419 -> 0.416, no frame lost (seed 25's frame 1 5.59% -> 3.6%); held out seeds 28
# / 29: 0.483 / 0.386 (3 frames lost, the first steps) -> 0.435 / 0.425, none lost.
STIFF_STAGE = 10.0

SILHOUETTE_STAGES = ("chain", "refine", "joint")
STIFF_STAGE_FRAMES = ("first", "all")


@dataclass(frozen=True, kw_only=True)
class SelfIntersection:
    """The self-intersection term (SPEC 5, step 3; :func:`elastocap.fit_sequence`'s
    ``self_intersection``, on by default, None: off): a surface node found inside a part of
    the model far from it at rest is pushed out of it.

    Parameters
    ----------
    weight : float
        gamma / beta, the term's weight relative to the surface term (SPEC 5: 1; >= 0).
        Before session 27: ``fit_sequence(contact=)``.
    hold : bool
        Keep a node pushed out of another part in contact for the rest of its frame while
        it stays near that part. Limbs pressed together (an arm on the chest) then end
        with far fewer penetrating nodes (two blocks squeezed by 25%: 57 -> 20 of 606
        surface nodes), but limbs that swing past each other are held back (horse gallop
        at 2,500 nodes: mean drift 2.1% -> 2.7%), so it is off by default. Before session 27:
        ``fit_sequence(hold_contacts=)``.
    """

    weight: float = 1.0
    hold: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "weight", checked("SelfIntersection", "weight", "float", self.weight, 0.0, True))
        object.__setattr__(self, "hold", checked("SelfIntersection", "hold", "bool", self.hold, 0, True))


@dataclass(frozen=True, kw_only=True)
class SilhouetteTerm:
    """The silhouette term (SPEC 5.1; :func:`elastocap.fit_sequence`'s ``silhouette``, None:
    off). It reads ``fit_sequence``'s ``cameras`` and ``masks``: surface nodes projecting
    outside a camera's mask are pushed in, and rim nodes (normal across the camera's ray)
    whose outline lies inside the mask are drawn out to the mask's outline, each across the
    outline in the plane normal to the ray. The masks are exact to a pixel where a carved
    hull is exact to a voxel. Horse gallop (benches/eval_horse.py): fitted/hull mean distance
    0.96 -> 0.80.

    Parameters
    ----------
    weight : float, optional
        Weight per surface node and camera, relative to a fully confident surface node (>= 0;
        0 turns the term off). None (the default): 1 (``SILHOUETTE``) when ``cameras`` and
        ``masks`` are given for a 3-D model, else 0. A positive weight needs them.
        Before session 27: ``fit_sequence(silhouette=<weight>)``.
    stage : {"chain", "refine", "joint"}
        How the term enters. "chain" (default): each frame is fitted to the hull first (whose
        terms have their invalidation), the fit is then refined against the masks from
        there, and the next frame starts from the refined fit. "refine": the same, but the
        next frame starts from the hull-only fit. "joint": every term at once from the
        frame's start. A mask's pull goes to the nearest outline, a neighbouring limb's when
        the frame starts far from its pose; after the hull-only fit the nearest outline is the
        limb's own. Horse gallop (benches/eval_horse.py, 5,873 nodes): joint drift 3.85% of
        the diagonal with a worst frame 1.66x the hull's error (legs drawn into each other's
        silhouettes), refine 1.74% and 0.87x, chain 1.66% and 0.87x. A refinement that takes
        the volume more than 5% of rest farther from it than the hull-only fit is dropped
        (metric ``silhouette_kept``). The hull-only stage stops by
        :class:`StoppingRules`' ``staged_*`` rules. Before session 27:
        ``fit_sequence(silhouette_stage=)``.
    """

    weight: float | None = None
    stage: str = "chain"

    def __post_init__(self) -> None:
        if self.weight is not None:
            object.__setattr__(self, "weight", checked("SilhouetteTerm", "weight", "float", self.weight, 0.0, True))
        object.__setattr__(self, "stage", checked_choice("SilhouetteTerm", "stage", self.stage, SILHOUETTE_STAGES))

    def weight_for(self, dim: int, has_views: bool) -> float:
        """The weight in a fit of a ``dim``-D model, with (``has_views``) or without cameras and
        masks: the given weight, or the default's (1 with both for a 3-D model, else 0)."""
        if self.weight is not None:
            return self.weight
        return SILHOUETTE if has_views and dim == 3 else 0.0


@dataclass(frozen=True, kw_only=True)
class StiffStage:
    """A stiff first stage (:func:`elastocap.fit_sequence`'s ``stiff_stage``, on by default,
    None: off): the frame is first fitted at ``stiffness`` from its start and then at the
    fit's own stiffness from there (with tracks, their spread measured again from the stiff
    stage's result). A fast limb then turns as a whole towards its part of the target before
    the softer fit places its surface, instead of sliding its material along the limb
    (benches/README.md, trackfit10: textured fast capture with tracks, mean drift ratio over
    ten seeds 0.419 -> 0.416, seed 25's lost frame kept; held out 0.483 / 0.386 -> 0.435 /
    0.425 and 3 lost frames -> 0).

    Parameters
    ----------
    stiffness : float
        The first stage's stiffness, in ``fit_sequence``'s ``stiffness`` units (finite, > 0;
        default 10, ``STIFF_STAGE``; 5-100 alike on seed 25's first step, 3 not enough).
        Before session 27: ``fit_sequence(stiff_stage=<stiffness>)``.
    frames : {"first", "all"}
        Where the stage runs: "first" (default) the frames fitted without a motion prediction
        (the first frame on each side of the rest frame: a limb's first step from rest, where
        the start is the rest pose), "all" every frame but the rest frame (twice the fit's
        CPU; textured fast capture, ten tuning seeds, not held out: mean drift ratio 0.416 ->
        0.394; benches/README.md, trackfit10, item 6). Before session 27:
        ``fit_sequence(stiff_stage_frames=)``.
    """

    stiffness: float = STIFF_STAGE
    frames: str = "first"

    def __post_init__(self) -> None:
        object.__setattr__(self, "stiffness", checked("StiffStage", "stiffness", "float", self.stiffness, 0.0, False))
        object.__setattr__(self, "frames", checked_choice("StiffStage", "frames", self.frames, STIFF_STAGE_FRAMES))


@dataclass(frozen=True, kw_only=True)
class StoppingRules:
    """When a frame's iteration and each of its linear solves stop
    (:func:`elastocap.fit_sequence`'s ``stopping``; None: these defaults). The ``staged_*``
    rules are those of a frame's fit to the hull alone that the silhouette term's refinement
    starts from (:class:`SilhouetteTerm` stage "chain" or "refine") and of the stiff stage
    that precedes it (:class:`StiffStage`); the others are those of every other fit. Before
    session 27 each field was a ``fit_sequence`` keyword of the same name.

    Parameters
    ----------
    max_iterations : int
        Iterations per frame (SPEC 5: 10; >= 1), per stage when the silhouette term refines a
        hull-only fit or a stiff stage runs first.
    stop_fraction : float
        A frame also stops when the last decrease of its objective is below this fraction
        of its total decrease so far (SPEC 5: 0.01; in [0, 1)).
    staged_stop_fraction : float
        The same for the fit to the hull alone: 0.002 takes it the rest of the way to its
        minimum, where it otherwise stops short along the surface (horse gallop: mean drift
        1.717% -> 1.679% of the diagonal, 7% more iterations; in [0, 1)).
    solver_tolerance : float
        Relative residual at which each iteration's linear solve (PCG) stops, against the
        right-hand side's norm (default 1e-6; finite, >= 0, 0: to the solver's iteration cap).
        Each iteration re-linearises (rotations, associations), so a solve far more exact
        than the next iteration's change is wasted.
    staged_tolerance : float
        The same for the fit to the hull alone (default 1e-5): only the refinement's result
        is kept, so its start need not be exact.
    """

    max_iterations: int = MAX_ITERATIONS
    stop_fraction: float = STOP_FRACTION
    staged_stop_fraction: float = STAGED_STOP_FRACTION
    solver_tolerance: float = SOLVER_TOLERANCE
    staged_tolerance: float = STAGED_TOLERANCE

    def __post_init__(self) -> None:
        checks: tuple[tuple[str, str, float, bool], ...] = (
            ("max_iterations", "int", 1, True), ("stop_fraction", "fraction", 0.0, True),
            ("staged_stop_fraction", "fraction", 0.0, True), ("solver_tolerance", "float", 0.0, True),
            ("staged_tolerance", "float", 0.0, True),
        )
        for name, kind, least, closed in checks:
            object.__setattr__(self, name, checked("StoppingRules", name, kind, getattr(self, name), least, closed))


# The keywords of ``fit_sequence`` before session 27 that are now fields: keyword -> (the
# keyword of the object, its field).
_FORMER = {
    "contact": ("self_intersection", "weight"),
    "hold_contacts": ("self_intersection", "hold"),
    "silhouette_stage": ("silhouette", "stage"),
    "stiff_stage_frames": ("stiff_stage", "frames"),
    **{f.name: ("stopping", f.name) for f in fields(StoppingRules)},
}
_GROUPS: dict[str, type] = {"self_intersection": SelfIntersection, "silhouette": SilhouetteTerm,
                            "stiff_stage": StiffStage, "stopping": StoppingRules, "track_terms": TrackTerms}


def grouped_keywords(options: Mapping[str, Any]) -> dict[str, Any]:
    """``fit_sequence``'s keywords from a mapping that may spell them as they were before
    they were grouped (JSON-friendly: the commands of benches/README.md).

    Read: the former keywords (``contact``, ``hold_contacts``, ``silhouette_stage``,
    ``stiff_stage_frames``, the five stopping rules, every ``track_<field>``), the former
    values of the keywords kept by name (``self_intersection`` a bool, ``silhouette`` a
    weight or None, ``stiff_stage`` a stiffness or None), and each object's keyword as a
    mapping of its fields (``{"stopping": {"max_iterations": 5}}``) or as the object. Other
    keys pass through unchanged (``stiffness``, ``coverage``, ``tracks``, ...).

    Raises
    ------
    InvalidInputError
        A field given twice (flat and in its object), a field set on a term or stage the
        same mapping turns off, or a bad value.
    """
    flat = dict(options)
    fields_of: dict[str, dict[str, Any]] = {}
    off: set[str] = set()
    out: dict[str, Any] = {}
    for key, value in flat.items():
        if key in _GROUPS and isinstance(value, _GROUPS[key]):
            out[key] = value
        elif key in _GROUPS and isinstance(value, Mapping):
            fields_of.setdefault(key, {})
            for name, given in value.items():
                _put(fields_of[key], key, name, given)
        elif key == "self_intersection":
            if not isinstance(value, bool):
                raise InvalidInputError(f"self_intersection must be a bool, a mapping of SelfIntersection fields, "
                                        f"a SelfIntersection or None, got {value!r}")
            if not value:
                off.add(key)
        elif key == "silhouette" and value is None:
            fields_of.setdefault(key, {})  # the former default: the term's weight by the data
        elif key == "stiff_stage" and value is None:
            off.add(key)
        elif key == "silhouette":
            _put(fields_of.setdefault(key, {}), key, "weight", value)
        elif key == "stiff_stage":
            _put(fields_of.setdefault(key, {}), key, "stiffness", value)
        elif key in _FORMER:
            group, name = _FORMER[key]
            _put(fields_of.setdefault(group, {}), group, name, value)
        elif key.startswith("track_") and key != "track_terms":
            _put(fields_of.setdefault("track_terms", {}), "track_terms", key[len("track_"):], value)
        else:
            out[key] = value
    for group, given in fields_of.items():
        if group in off:
            # A field of a term the same options turn off: the former keywords allowed it
            # (and ignored the field); refusing it says which of the two the caller meant.
            raise InvalidInputError(f"{group} is turned off but its field(s) {sorted(given)} are given")
        if group in out:
            raise InvalidInputError(f"{group} given as an object and as field(s) {sorted(given)}")
        if group == "track_terms":
            out[group] = TrackTerms.from_flat({f"track_{name}": value for name, value in given.items()})
        else:
            out[group] = _GROUPS[group](**given)
    for group in off:
        out[group] = None
    return out


def _put(into: dict[str, Any], group: str, name: str, value: Any) -> None:
    if name in into:
        raise InvalidInputError(f"{group}.{name} given twice")
    into[name] = value
