"""Fitting an elastic model through a sequence of target shapes (SPEC 5; the paper's
section 4): forward and backward from the rest frame, each frame starting from its
neighbour's fit, one fixed surface topology throughout.

The per-frame iteration runs in Rust (``rust/fit.rs``): rotations, the anisotropic
surface-distance term with confidence weights and invalidated associations, the
self-intersection term, and a PCG solve per iteration (block Jacobi plus a coarse
correction on the rigid motions of node aggregates). 3-D models fit to signed distance
fields (hulls, meshes); 2-D models (:meth:`ElasticModel.from_mask`) fit to binary masks in
the same way, with their contour edges as the surface.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray

import elastocap._core as _core
from elastocap._core import InvalidInputError
from elastocap.elastic.fit_options import SelfIntersection, SilhouetteTerm, StiffStage, StoppingRules
from elastocap.elastic.model import ElasticModel
from elastocap.elastic.silhouette import silhouette_views, term_margins
from elastocap.elastic.targets import field_arrays, frame_numbers, mask_field, target_field
from elastocap.elastic.track_spread import frame_spread
from elastocap.elastic.track_terms import TrackTerms
from elastocap.elastic.tracks import TrackAttachments, check_tracks

__all__ = ["FrameFit", "SequenceFit", "fit_sequence", "target_field"]

# The most a frame's refinement against the masks may take its volume farther from rest
# (a fraction of the rest volume; the volume bound of issue 17).
REFINED_VOLUME_CHANGE = 0.05


@dataclass(frozen=True)
class FrameFit:
    """The fit of one frame.

    Attributes
    ----------
    frame : int
        Index of the target in the sequence.
    positions : (N, 3) float64
        Node positions, world units.
    metrics : dict
        SPEC 5's figures: ``distance_term`` (D), ``mean_distance`` / ``max_distance``
        (|signed distance| of the surface nodes to the target, world units),
        ``elastic_energy``, ``volume_ratio`` (surface volume over the rest surface's),
        ``penetrating`` (surface nodes inside another part), ``invalidated``,
        ``iterations``, ``solver_iterations``, ``solver_converged``, ``solver_seconds``
        (assembly and linear solves), ``seconds``; ``samples`` (the target surface's samples
        of the coverage term) and ``unexplained`` (those no fitted surface node explains at
        the end, a failure signal: a lost limb leaves its part of the hull unexplained);
        with ``tracks``: ``tracks`` (tracks pulling the frame), ``tracks_attached``
        (anchored at it), ``tracks_attached_ahead`` (of those, attached before the frame
        was fitted: ``TrackTerms.ahead``), ``tracks_unplaced`` (anchored at it where the
        model's nodes around the tracked point do not span space: left out) and
        ``track_mahalanobis`` (their mean Mahalanobis distance at the end, when any
        pulled).
    """

    frame: int
    positions: NDArray[np.float64]
    metrics: dict[str, Any]


@dataclass
class SequenceFit:
    """Fits of a sequence: ``fits[frame]`` for every fitted frame, one surface topology."""

    model: ElasticModel
    rest_frame: int
    fits: dict[int, FrameFit] = field(default_factory=dict)

    def surface(self, frame: int) -> trimesh.Trimesh:
        """The fitted surface of ``frame`` (rest topology, world units)."""
        return self.model.surface_at(self.fits[frame].positions)

    @property
    def frames(self) -> list[int]:
        """The fitted frames, ascending."""
        return sorted(self.fits)


def fit_sequence(
    model: ElasticModel,
    targets: Sequence[Any] | Mapping[int, Any],
    *,
    rest_frame: int = 0,
    stiffness: float = 1.0,
    coverage: float = 2.0,
    volume: float = 4.0,
    invalidate: bool = True,
    predict: bool = True,
    self_intersection: SelfIntersection | None = SelfIntersection(),
    silhouette: SilhouetteTerm | None = SilhouetteTerm(),
    cameras: Sequence[Any] | None = None,
    masks: Sequence[Sequence[Any]] | Mapping[int, Sequence[Any]] | None = None,
    stiff_stage: StiffStage | None = StiffStage(),
    stopping: StoppingRules | None = None,
    tracks: Any = None,
    track_terms: TrackTerms | None = None,
    done: Mapping[int, NDArray[np.float64]] | None = None,
    callback: Callable[[FrameFit], None] | None = None,
) -> SequenceFit:
    """Fit ``model`` (built from the rest frame's shape) to every target of a sequence.

    The options of a term or stage are objects (:mod:`elastocap.elastic.fit_options`,
    :class:`~elastocap.elastic.track_terms.TrackTerms`; frozen, checked on construction); a
    term or stage that is on by default is turned off by None. Until session 27 their fields
    were keywords of their own (``contact``, ``hold_contacts``, ``silhouette_stage``,
    ``stiff_stage_frames``, ``max_iterations``, ``stop_fraction``, ``staged_stop_fraction``,
    ``solver_tolerance``, ``staged_tolerance``; ``self_intersection`` a bool, ``silhouette``
    a weight, ``stiff_stage`` a stiffness): :func:`~elastocap.elastic.fit_options.grouped_keywords`
    reads such a mapping.

    Parameters
    ----------
    model : ElasticModel
        A model with a surface: 3-D (:meth:`ElasticModel.from_mesh`) or 2-D
        (:meth:`ElasticModel.from_mask`).
    targets : sequence, or mapping of int frame number -> target
        One target per frame. 3-D: :class:`SDF`, :class:`Hull` or closed trimesh, world
        units. 2-D: binary masks ``(H, W)`` in the model's pixel coordinates ``(x, y) =
        (column, row)``. A mapping is keyed by the capture's frame numbers (frames in
        ascending order are neighbours, gaps allowed); a sequence's frame numbers are its
        positions. Results, ``rest_frame`` and ``done`` use these frame numbers.
    rest_frame : int
        The frame the model was built from; fitting starts there (from the rest positions)
        and runs forward to the last frame and backward to the first. The model keeps its
        rest target's errors: :func:`elastocap.elastic.rest.least_volume_frame` picks the
        hull with the least phantom volume without ground truth.
    stiffness : float
        alpha / beta of SPEC 5 in units of the shear modulus times the mean node spacing:
        1 balances a node's elastic diagonal with a fully confident surface term; larger is
        stiffer (smoother, less faithful to noisy hulls).
    coverage : float
        Weight of the coverage term (SPEC 5.1; 0 turns it off): samples of the target's
        surface that no model surface node of a compatible normal lies near pull the nearest
        such node, so a limb that moved faster than the start predicted is pulled back
        into its part of the target instead of staying on the surface nearest to where it
        was. Measured on the synthetic fast-motion capture (tuned on seed 1, 14 frames,
        1,000 nodes, hulls of 64 voxels): the lost-limb measure's worst frame 17.5% of the
        diagonal without it, 5.8% at 1, 3.5% at 2, 5.0-5.9% at 3-4 with the volume up to
        1.105 at 3.
    volume : float
        Weight of the volume term (0 turns it off): the volume enclosed by the model's
        surface is held at its rest value, a volume error of ``d`` times the rest surface's
        area costing as much as moving every surface node by ``d`` under a data term of
        this weight. A carved hull gains and loses phantom volume as limbs meet and part;
        the body does not. 3-D models only (a 2-D silhouette's area changes with the pose).
        Measured on the fast-motion capture (seed 1, 30 frames, 2,500
        nodes): volume 0.886-1.000 of rest without it, 0.976-1.007 at 1, 0.991-1.008 at 4.
    invalidate : bool
        The invalidation of colliding associations (SPEC 5, step 2: two surface nodes far
        apart at rest pulled to the same place both lose their pull, so that a limb tip is
        not pulled to another limb; the coverage term's samples likewise).
    predict : bool
        Start each frame from its neighbour's fit moved on by the neighbour's own motion
        (constant velocity: ``2 x[f -/+ 1] - x[f -/+ 2]``) where both are fitted, instead
        of from the neighbour's fit. Measured on the horse gallop (fast leg swings, up to
        0.59 m per frame; benches/README.md): mean drift 2.85% -> 2.16% of the bounding-box
        diagonal over one gallop cycle.
    self_intersection : SelfIntersection or None
        The self-intersection term (SPEC 5, step 3): its weight and whether contacts are
        held (:class:`~elastocap.elastic.fit_options.SelfIntersection`; default: its
        defaults, weight 1; None: off).
    silhouette : SilhouetteTerm or None
        The silhouette term (SPEC 5.1): its weight per surface node and camera and how it
        enters a frame (:class:`~elastocap.elastic.fit_options.SilhouetteTerm`; default: weight
        1 when ``cameras`` and ``masks`` are given for a 3-D model, else off, stage "chain";
        None: off).
    cameras : sequence of Camera, optional
        The rig's cameras (``Rig.cameras``), for the silhouette term.
    masks : sequence or mapping of int frame number -> sequence of (H, W) bool, optional
        Per frame, one mask per camera (keyed as ``targets``), for the silhouette term.
    stiff_stage : StiffStage or None
        A stiff first fit of the frames fitted without a motion prediction, or of every
        frame (:class:`~elastocap.elastic.fit_options.StiffStage`; default: stiffness 10,
        the first frame on each side of the rest frame; None: off).
    stopping : StoppingRules, optional
        When a frame's iteration and each linear solve stop
        (:class:`~elastocap.elastic.fit_options.StoppingRules`; None: its defaults, SPEC 5's
        10 iterations and 1%).
    tracks : Tracks, optional
        Tracked 3-D surface points (:func:`elastocap.track_points`,
        :func:`elastocap.load_tracks`; 3-D models only), frames keyed as ``targets``. Each
        track is attached to the model at its frame nearest ``rest_frame`` (its MLS weights
        over the nodes around it in that frame's fit), and in every other frame where it
        is tracked that material point is pulled to the tracked position with its
        covariance's weight under a robust (Cauchy) loss (:mod:`elastocap.elastic.tracks`,
        SPEC 5.1). An empty set (no track or no frame) changes nothing.
    track_terms : TrackTerms, optional
        How the tracks pull the fit (:class:`~elastocap.elastic.track_terms.TrackTerms`,
        its fields documented there; None: its defaults): their weight and robust loss, how
        tracks anchored away from the rest frame are attached (the relay, the carry ahead)
        and how their corrections spread along the surface. Before session 26 these were
        the keywords ``track_weight`` ... ``track_spread_relayed_dense``
        (:meth:`TrackTerms.from_flat` reads such a mapping).
    done : mapping of int to (N, 3) array, optional
        Frames already fitted (e.g. read back after an interrupted run): they are not
        refitted, and their neighbours start from them.
    callback : callable, optional
        Called with each new :class:`FrameFit` as soon as it is done (write it, show it).

    Returns
    -------
    SequenceFit

    Raises
    ------
    InvalidInputError
        A 2-D model or one without a surface, ``rest_frame`` out of range, a bad target
        (empty hull, non-watertight mesh), bad options (an option object's own checks run
        when it is made; here: an object of the wrong type, a positive silhouette weight
        without cameras and masks).
    ConvergenceError
        A frame's system matrix is found not positive definite (it cannot be with a
        positive stiffness; reported, not hidden). A linear solve that stops at its
        iteration cap is not an error: the frame's ``solver_converged`` metric is False.
    """
    for name, value, kind in (("self_intersection", self_intersection, SelfIntersection),
                              ("silhouette", silhouette, SilhouetteTerm), ("stiff_stage", stiff_stage, StiffStage),
                              ("stopping", stopping, StoppingRules), ("track_terms", track_terms, TrackTerms)):
        if value is not None and not isinstance(value, kind):
            raise InvalidInputError(f"{name} must be an elastocap.{kind.__name__} or None, got {value!r} "
                                    f"(before session 27 some of these options were numbers or bools: "
                                    f"elastocap.elastic.fit_options.grouped_keywords reads them)")
    contacts = self_intersection
    views_given = cameras is not None and masks is not None
    silhouette_weight = 0.0 if silhouette is None else silhouette.weight_for(model.dim, views_given)
    silhouette_stage = "chain" if silhouette is None else silhouette.stage
    if silhouette_weight > 0 and not views_given:
        raise InvalidInputError("SilhouetteTerm.weight > 0 needs cameras and masks")
    stop = StoppingRules() if stopping is None else stopping
    if track_terms is None:
        track_terms = TrackTerms()
    if len(model.surface_faces) == 0:
        raise InvalidInputError(
            "fit_sequence needs a model with a surface (ElasticModel.from_mesh or ElasticModel.from_mask)"
        )
    frames = frame_numbers(targets)
    if not frames:
        raise InvalidInputError("targets is empty")
    if rest_frame not in frames:
        raise InvalidInputError(
            f"rest_frame = {rest_frame} is not a frame of the targets (frames {frames[0]}..{frames[-1]})"
        )
    tracks = check_tracks(tracks, frames)
    if tracks is not None and model.dim != 3:
        raise InvalidInputError("tracks are 3-D points: a 2-D model does not take them")
    node_spacing = float(np.mean(model.volumes) ** (1 / 3))
    sigma = track_terms.lengths(node_spacing).sigma
    attachments = None if tracks is None or track_terms.weight == 0 else TrackAttachments.build(
        tracks, rest_frame, model.neighbors.shape[1], track_terms, node_spacing)
    fitter = _core.FitCore(model._core, model.surface_nodes, model.surface_faces)
    stage_stiffness = 0.0 if stiff_stage is None else stiff_stage.stiffness
    rest_volume = model.enclosed_measure(model.nodes)
    field_of = target_field if model.dim == 3 else mask_field
    result = SequenceFit(model, rest_frame)
    previous = dict(done or {})
    # Where each fitted frame's neighbours start from: its fit, or with the silhouette
    # term as a refinement, its fit to the hull alone.
    starts: dict[int, NDArray[np.float64]] = {}
    # (frame, the neighbour it starts from, the neighbour's neighbour): outward from the rest
    # frame, in the order of the frame numbers.
    rest = frames.index(rest_frame)
    forward, backward = frames[rest:], frames[rest::-1]
    order: list[tuple[int, int | None, int | None]] = [(rest_frame, None, None)]
    for run in (forward, backward):
        order += [(run[i], run[i - 1], run[i - 2] if i >= 2 else None) for i in range(1, len(run))]
    for frame, neighbour, second in order:
        if frame in previous:
            result.fits[frame] = FrameFit(frame, np.asarray(previous[frame], dtype=np.float64), {})
            starts[frame] = result.fits[frame].positions
            if attachments is not None:
                if track_terms.spread_relayed_dense > 0:
                    attachments.count_older(frame)
                attachments.attach(frame, result.fits[frame].positions)
            continue
        predicted = False
        if neighbour is None:
            start = model.nodes
        else:
            start = starts[neighbour]
            if predict and second is not None and second in starts:
                # The elastic solve sees only the start, so a leg that swings 0.5 m per
                # frame is met half-way instead of pulled back onto the nearest limb.
                start = 2 * start - starts[second]
                predicted = True
        stiff = stiff_stage is not None and neighbour is not None and (stiff_stage.frames == "all" or not predicted)
        values, origin, spacing = field_arrays(field_of(targets[frame]))
        views = None
        if silhouette_weight > 0 and cameras is not None and masks is not None:
            # Only the band of each image the term can read is transformed exactly: a
            # person fills a few percent of a frame (8 cameras of 1024 x 768: 0.57 s per
            # frame exact everywhere).
            surface = model.surface_nodes
            margins = term_margins(cameras, start[surface], model.support[surface]) if model.dim == 3 else None
            views = silhouette_views(cameras, masks[frame], margins)
        if attachments is not None and track_terms.spread_relayed_dense > 0:
            attachments.count_older(frame)
        # Late tracks that their older neighbours place at rest pull this frame already.
        ahead = 0 if attachments is None else attachments.attach_ahead(frame, start)
        pulling = None if attachments is None else attachments.frame_arrays(frame)
        pulling_tracks = 0 if pulling is None else len(pulling[0])
        track_arrays = pulling

        def spread(at: NDArray[np.float64]) -> Any:
            # The frame's track arrays with their corrections from ``at`` spread over the surface.
            if attachments is None:
                return track_arrays
            return frame_spread(attachments, frame, track_arrays, at, model.surface_nodes, model.surface_faces)

        pulling = spread(start)
        options: dict[str, Any] = dict(stiffness=stiffness, contact=1.0 if contacts is None else contacts.weight,
                       max_iterations=stop.max_iterations, stop_fraction=stop.stop_fraction, invalidate=invalidate,
                       self_intersection=contacts is not None, hold_contacts=contacts is not None and contacts.hold,
                       coverage=coverage,
                       # A body keeps its volume; a 2-D silhouette does not keep its area.
                       volume=volume if model.dim == 3 else 0.0,
                       solver_tolerance=stop.solver_tolerance,
                       tracks=pulling, track_weight=track_terms.weight, track_sigma=sigma,
                       track_scale=track_terms.scale)
        clock = time.perf_counter()
        staged = views is not None and silhouette_stage != "joint"
        first = (dict(options, solver_tolerance=stop.staged_tolerance, stop_fraction=stop.staged_stop_fraction)
                 if staged else options)
        stiff_iterations = 0
        if stiff:
            # A first stage at ``stiff_stage`` (fit_options.STIFF_STAGE's comment): the
            # fast limbs turn as a whole; the frame's own fit then starts from there, its
            # tracks' spread measured from there.
            start, stiff_metrics = fitter.fit_frame(values, origin, spacing, np.ascontiguousarray(start),
                                                    **dict(first, stiffness=stage_stiffness), silhouette=0.0, views=None)
            stiff_iterations = int(stiff_metrics["iterations"])
            pulling = spread(start)
            options["tracks"] = pulling
            first = dict(first, tracks=pulling)
        positions, metrics = fitter.fit_frame(values, origin, spacing, np.ascontiguousarray(start), **first,
                                              silhouette=0.0 if staged else silhouette_weight,
                                              views=None if staged else views)
        # Per-step timings are for profiling the core (``_core.FitCore.fit_frame``); a
        # frame's metrics are figures that compare across runs.
        metrics.pop("step_seconds", None)
        chained = positions
        if staged:
            # The masks' pulls go to the nearest mask outline, which is a neighbouring
            # limb's when the frame starts far from its pose: the frame is first fitted
            # to the hull alone (whose terms have their invalidation), then refined
            # against the masks from there, where the nearest outline is the limb's own.
            refined_positions, refined = fitter.fit_frame(values, origin, spacing, np.ascontiguousarray(chained),
                                                          **options, silhouette=silhouette_weight, views=views)
            refined.pop("step_seconds", None)
            # A refinement that takes the volume farther from rest than the volume bound
            # (5%) is not the masks' precision but their coarseness: on images where a limb
            # is a few pixels wide (96 x 72, 160 nodes) it swelled the surface to 3x the
            # rest volume. The hull-only fit is kept then.
            before = abs(model.enclosed_measure(chained) / rest_volume - 1)
            after = abs(model.enclosed_measure(refined_positions) / rest_volume - 1)
            kept = bool(after <= before + REFINED_VOLUME_CHANGE)
            if kept:
                refined["iterations"] += metrics["iterations"]
                positions, metrics = refined_positions, refined
            metrics["silhouette_kept"] = kept
            if silhouette_stage == "chain":
                chained = positions
        if attachments is not None:
            # Tracks pulling this frame, and tracks attached at it (anchored here).
            metrics["tracks"] = pulling_tracks
            unplaced = int(attachments.unplaced.sum())
            metrics["tracks_attached"] = int(attachments.attach(frame, positions)) + ahead
            metrics["tracks_attached_ahead"] = ahead
            metrics["tracks_unplaced"] = int(attachments.unplaced.sum()) - unplaced
        if stiff:
            metrics["stiff_stage_iterations"] = stiff_iterations
        metrics["seconds"] = time.perf_counter() - clock
        metrics["volume_ratio"] = model.enclosed_measure(positions) / rest_volume
        fit = FrameFit(frame, positions, dict(metrics))
        result.fits[frame] = fit
        starts[frame] = chained
        if callback is not None:
            callback(fit)
    return result
