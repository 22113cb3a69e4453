"""How tracks pull the elastic fit (SPEC 5.1; issue 15): the options of
:func:`elastocap.fit_sequence`'s track term, its attachment of late tracks (the relay and the
carry ahead, :mod:`elastocap.elastic.tracks`) and its spread along the surface
(:mod:`elastocap.elastic.track_spread`), in one object.

Lengths left at None are fractions of the model's mean node spacing, known only once the
model is: :meth:`TrackTerms.lengths` gives them in world units.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from elastocap._core import InvalidInputError
from elastocap.elastic.option_checks import checked

__all__ = ["TrackLengths", "TrackTerms"]

# Older tracks whose median offset says where a track anchored after the rest frame is
# attached (elastic/tracks.py). Textured fast capture, tuning seed 1 (benches/README.md,
# trackfit2): mean drift 7.01% of the diagonal at 0, 6.87% at 3, 7.05% at 5 (weight 1);
# at weight 4: 7.28% at 0, 6.66% at 5. No frame lost at 5, weight 1.
TRACK_RELAY = 5
# The tracks' corrections carried along the surface (elastic/track_spread.py): the most a
# node is pulled, in tracks, and the frames over which a track's trust falls by e. Textured
# fast capture, tuning seed 1 (benches/README.md, trackfit3; drift without tracks 9.71%,
# with tracks and no spread 7.20%): before the guard against tracks gone astray, 6.29% at
# 1 / 5 frames (one frame lost), 6.38% at 2 / 5 (one lost), 6.27% at 4 / 10, 6.03% at
# 1 / 15, 6.36% at 1 / 30; with the final guard 6.33% at 1 / 15, none lost (held out:
# seeds 2 and 3 5.58 -> 4.66%, 4.91 -> 4.49%).
TRACK_SPREAD = 1.0
# 30 frames rather than 15 once late tracks are carried ahead (below): alone, 30 is worse
# than 15 (benches/README.md, trackfit8: the relayed tracks' errors spread longer).
TRACK_SPREAD_AGE = 30.0
# Late tracks carried to the rest frame ahead of their anchor frame's fit (elastic/tracks.py):
# how many older tracks carry one, the largest RMS residual of their rigid motion and the
# farthest a carry may land from the relay's place (both in mean node spacings), and the
# frames a lost track still relays. Textured fast capture (benches/README.md, trackfit8 and
# session 20's lead section), drift ratio with / without tracks against the carry off and
# spread age 15: tuning seeds 1 / 10 / 14 / 15 0.492 / 0.547 / 0.571 / 0.328 -> 0.464 /
# 0.501 / 0.504 / 0.325, held out 18 / 19 0.500 / 0.429 -> 0.441 / 0.423; no frame lost. A
# check of 1 spacing throws good carries away; beyond 4 the carries are 20% of the diagonal off.
TRACK_AHEAD = 6
TRACK_AHEAD_TOLERANCE = 0.5
TRACK_AHEAD_CHECK = 3.0
TRACK_RELAY_MEMORY = 2
# The defaults of the other lengths, in mean node spacings (fit_sequence's before they were
# grouped here): a track's sigma floor, the relay's radius (also the carry's) and the
# spread's geodesic reach.
TRACK_SIGMA = 0.25
TRACK_RELAY_RADIUS = 4.0
TRACK_SPREAD_RADIUS = 4.0


@dataclass(frozen=True)
class TrackLengths:
    """The lengths of :class:`TrackTerms` in world units, at a model's mean node spacing
    (:meth:`TrackTerms.lengths`): ``sigma``, ``relay_radius``, ``ahead_tolerance``,
    ``ahead_check``, ``spread_radius``."""

    sigma: float
    relay_radius: float
    ahead_tolerance: float
    ahead_check: float
    spread_radius: float


@dataclass(frozen=True, kw_only=True)
class TrackTerms:
    """How tracks pull the fit (:func:`elastocap.fit_sequence`'s ``track_terms``); the
    defaults are the fit's. Keyword-only and frozen (``dataclasses.replace`` makes a
    variant); validated on construction (:class:`InvalidInputError` naming the field and
    its value); ints, floats and bools are stored as Python's own.

    Parameters
    ----------
    weight : float
        Weight of one track relative to a fully confident surface node (0 turns the tracks
        off).
    sigma : float, optional
        Floor of a track's standard deviation, world units: a track's metric is
        ``(Sigma + sigma^2 I)^-1`` scaled by ``sigma^2``, so none pulls harder than
        ``weight``. Default: a quarter of the mean node spacing.
    scale : float
        Scale of the Cauchy loss in standard deviations: a track whose material point is
        ``scale`` deviations away pulls with half its weight, farther ones less (a track 1 m
        off at the default sigma pulls with about 1/70 of it). Chosen on the fast-motion
        capture (seed 1, 14 frames, 1,000 nodes, ground-truth tracks with 5 mm noise): worst
        lost-limb frame 7.4% of the diagonal without tracks, 17.8% at 3 (fast limbs' tracks
        start too far away to pull), 2.6% at 10.
    relay : int
        A track anchored at a frame other than the rest frame is attached where the
        ``relay`` older tracks nearest to it (median) say the fit is off, instead of where
        that frame's (drifted) fit puts it (:mod:`elastocap.elastic.tracks`; 0: the fit's
        place; default 5, ``TRACK_RELAY``).
    relay_radius : float, optional
        Those older tracks must lie within this distance, world units (default 4 mean node
        spacings).
    ahead : int
        A track anchored at a frame other than the rest frame is attached before that frame
        is fitted, through the rigid motion back to the rest frame of the ``ahead`` older
        tracks tracked nearest to it there (within ``relay_radius``), and pulls that frame
        too; where they do not move rigidly, after the fit as ``relay`` says
        (:mod:`elastocap.elastic.tracks`; 0: off; default 6, ``TRACK_AHEAD``).
    ahead_tolerance : float, optional
        The largest RMS residual of those older tracks' rigid motion, world units (default
        half a mean node spacing, ``TRACK_AHEAD_TOLERANCE``).
    ahead_check : float, optional
        A track carried ahead whose material point at rest lies farther than this (world
        units) from where the relay's offsets, measured on the frame's start, put it is left
        to the relay after the fit (a neighbourhood attached wrong that moves rigidly carries
        its tracks far off; 0: no check; default 3 mean node spacings, ``TRACK_AHEAD_CHECK``).
    ahead_chain : int
        Passes after the first in which the tracks just attached ahead carry the other
        tracks anchored at the same frame (0, the default: only older tracks carry).
    ahead_age : bool
        A track attached ahead is aged in the spread (``spread_age``) from the mean anchor
        frame of the tracks that carried it, not from its own (default False).
    relayed_weight : float
        Weight, relative to the others, of the tracks attached after their late anchor
        frame's fit (by the relay alone; default 1).
    relay_memory : int
        Tracks lost in up to this many frames before (on the rest frame's side) relay too,
        with the offset from the fit they had in their last tracked frame (0: only tracks
        tracked in the frame relay; default 2, ``TRACK_RELAY_MEMORY``).
    ahead_memory : bool
        Those tracks lost in the last ``relay_memory`` frames carry late tracks ahead too,
        placed where the frame's start and their last offset put them (default False).
    spread : float
        The tracks' corrections (tracked position minus where the frame's start puts the
        material point) carried along the surface to the nodes around them, each pulled
        along the surface to its start moved by them, at most this share of one track's
        weight (:mod:`elastocap.elastic.track_spread`; 0 turns it off; default 1,
        ``TRACK_SPREAD``). Textured fast capture: mean drift 7.20% -> 6.33% of the diagonal
        (tuning seed 1), 5.58% -> 4.66% and 4.91% -> 4.49% (held-out seeds 2 and 3).
    spread_age : float
        Frames from its anchor over which a track's trust in the spread falls by e (default
        30, ``TRACK_SPREAD_AGE``). Textured fast capture (benches/README.md, trackfit8): 30
        alone is worse than 15 (the relayed tracks' errors spread longer); 30 with the
        defaults of ``ahead``, ``ahead_tolerance``, ``ahead_check`` and ``relay_memory``
        lowers the drift ratio on all six seeds measured (e.g. 0.571 -> 0.504, held out
        0.500 -> 0.441).
    spread_radius : float, optional
        A track's reach in the spread, geodesic on the surface at the start, world units
        (default 4 mean node spacings).
    spread_relayed : float
        A factor on the spread's trust in the tracks attached by the relay alone (anchored
        away from the rest frame and not carried ahead; 0: they pull their own material
        point but do not spread; default 1). On a fast limb the relay attaches new tracks
        where the drifted fit puts them, and the spread carries that error to every node
        around them (benches/README.md, trackfit9).
    spread_relayed_dense : int
        With ``spread_relayed``: a relayed track that had at least this many older tracks
        tracked within the relay radius at its anchor frame (the trunk, where the relay is
        accurate) keeps its full spread; only the others (a fast limb whose tracks all
        ended) get the factor (0, the default: every relayed track gets it).

    Notes
    -----
    Until session 26 these were ``fit_sequence``'s keywords ``track_<field>``
    (``track_weight`` ... ``track_spread_relayed_dense``); :meth:`from_flat` reads such a
    mapping.
    """

    weight: float = 1.0
    sigma: float | None = None
    scale: float = 10.0
    relay: int = TRACK_RELAY
    relay_radius: float | None = None
    ahead: int = TRACK_AHEAD
    ahead_tolerance: float | None = None
    ahead_check: float | None = None
    ahead_chain: int = 0
    ahead_age: bool = False
    relayed_weight: float = 1.0
    relay_memory: int = TRACK_RELAY_MEMORY
    ahead_memory: bool = False
    spread: float = TRACK_SPREAD
    spread_age: float = TRACK_SPREAD_AGE
    spread_radius: float | None = None
    spread_relayed: float = 1.0
    spread_relayed_dense: int = 0

    def __post_init__(self) -> None:
        # (name, kind, least value, whether the least value itself is allowed).
        checks: tuple[tuple[str, str, float, bool], ...] = (
            ("weight", "float", 0.0, True), ("sigma", "length", 0.0, False), ("scale", "float", 0.0, False),
            ("relay", "int", 0, True), ("relay_radius", "length", 0.0, False), ("ahead", "int", 0, True),
            ("ahead_tolerance", "length", 0.0, False), ("ahead_check", "length", 0.0, True),
            ("ahead_chain", "int", 0, True), ("ahead_age", "bool", 0, True), ("relayed_weight", "float", 0.0, True),
            ("relay_memory", "int", 0, True), ("ahead_memory", "bool", 0, True), ("spread", "float", 0.0, True),
            ("spread_age", "float", 0.0, False), ("spread_radius", "length", 0.0, False),
            ("spread_relayed", "float", 0.0, True), ("spread_relayed_dense", "int", 0, True),
        )
        for name, kind, least, closed in checks:
            value = getattr(self, name)
            if kind == "length" and value is None:
                continue
            object.__setattr__(self, name, checked("TrackTerms", name, kind, value, least, closed))

    @classmethod
    def from_flat(cls, options: Mapping[str, Any]) -> TrackTerms:
        """The terms of ``fit_sequence``'s former flat keywords, e.g. ``{"track_ahead": 2}``
        (every key ``track_<field>``; the others at their defaults).

        Raises
        ------
        InvalidInputError
            A key that is not ``track_`` and a field's name, or a bad value.
        """
        names = {f.name for f in fields(cls)}
        unknown = sorted(key for key in options if not (key.startswith("track_") and key[len("track_"):] in names))
        if unknown:
            raise InvalidInputError(f"TrackTerms.from_flat: unknown option(s) {unknown}; "
                                    f"known: {sorted('track_' + name for name in names)}")
        return cls(**{key[len("track_"):]: value for key, value in options.items()})

    def lengths(self, node_spacing: float) -> TrackLengths:
        """The lengths in world units for a model of mean node spacing ``node_spacing``
        (world units, > 0): those given as they are, the others at their defaults."""
        if not (np.isfinite(node_spacing) and node_spacing > 0):
            raise InvalidInputError(f"node_spacing must be a finite positive number, got {node_spacing}")

        def length(given: float | None, default: float) -> float:
            return default * node_spacing if given is None else given

        return TrackLengths(
            sigma=length(self.sigma, TRACK_SIGMA),
            relay_radius=length(self.relay_radius, TRACK_RELAY_RADIUS),
            ahead_tolerance=length(self.ahead_tolerance, TRACK_AHEAD_TOLERANCE),
            ahead_check=length(self.ahead_check, TRACK_AHEAD_CHECK),
            spread_radius=length(self.spread_radius, TRACK_SPREAD_RADIUS),
        )

