"""The body fit as a tracker (issue 16): :class:`BodyTracker`, :func:`track_body`.

The first frame is found by a global pose search (the root placed at the centre of the
data, several headings fitted briefly, the best refined); every later frame starts from
its predecessor moved on at constant velocity and is fitted with the shape held; the shape
is fitted once, jointly over the first ``window`` frames, and then shared by the whole take
(BVH bones have fixed lengths). A frame the prediction loses (its observations far from
the fitted skin) is searched for again, from the global starts and from the last frame the
track held. A subject the model cannot explain (an animal, an
object) is refused on the first frame.

The lost test's measures are in :mod:`elastocap.body.lost`, the shape families fitted in
:mod:`elastocap.body.shape_family` (both re-exported here).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_positive
from elastocap.body.fit import BodyFit, BodyObservations, fit_body, silhouette_samples
from elastocap.body.lost import EXPLAINED_DISTANCE, LOST_RECENT, FrameQuality, lost_threshold, observation_distances
from elastocap.body.model import BodyModel, BodyState
from elastocap.body.search import search_pose
from elastocap.body.shape_family import SHAPE_PRIOR_SIGMA, SHAPE_PRIOR_SIGMA_MASKS, limb_length_groups, narrow_shape_family
from elastocap.body.starts import body_volume
from elastocap.cameras.camera import Camera

__all__ = ["BodyTrack", "BodyTracker", "FrameQuality", "limb_length_groups", "lost_threshold", "narrow_shape_family", "observation_distances", "track_body"]

#: The first frame is refused when less than this share of its observations is explained
#: after the search: the body figure is explained at 0.9 or more (synth seeds 1-7, even
#: where the search ended with the legs swapped), the capsule figure in clutter (its
#: contours, 5% outlying points) at 0.73-0.77 (seeds 0, 1), a four-legged animal at 0.50
#: (0.46 before the arms' restarts kept the raise: they now fit two of its legs).
REFUSE_EXPLAINED = 0.6
#: A lost frame's search result replaces the tracked fit only when its score is lower by
#: at least this share. The score does not resolve smaller differences: among the frame-0
#: search's candidates on the capsule figure (tuning seeds 2 and 12, masks alone), of two
#: states whose scores differ by less than 2%, the better-scored one had its joints more
#: than 2 cm worse in 32-34% of pairs; 2-5%: 14-19%; 5-10%: 6-12% (branch body9). Before,
#: the search's result replaced the tracked fit whenever it explained a larger share, a
#: different measure than the one the search ranked by (seed 16, frame 18: the search's
#: result, kept, was 33 mm from the true skin, the frames around it 20-23 mm; branch body8).
REPLACE_MARGIN = 0.05
#: Observation distances are clipped at this (metres) in the search's score
#: (:meth:`BodyTracker.score`): a limb far off its data costs as much as one just off it.
SCORE_CLIP = 0.05


@dataclass(frozen=True)
class BodyTrack:
    """The result of :func:`track_body` / :meth:`BodyTracker.result`.

    Attributes
    ----------
    states : list of BodyState
        One per frame, all with ``shape``.
    shape : (4 P,) float64
        The take's one shape.
    motion : (F, n_motion) float64
    quality : list of FrameQuality
    searched : list of bool
        Frames found by the global pose search (the first, and any the prediction lost).
    observed : list of bool
        False for frames with no observations (their state is the prediction).
    """

    states: list[BodyState]
    shape: NDArray[np.float64]
    motion: NDArray[np.float64]
    quality: list[FrameQuality]
    searched: list[bool]
    observed: list[bool]


@dataclass(frozen=True)
class _Frame:
    """One frame's observations with the silhouette rays drawn once."""

    points: NDArray[np.float64]
    point_sigma: NDArray[np.float64] | None
    origins: NDArray[np.float64]
    directions: NDArray[np.float64]
    side: NDArray[np.int8]
    joints: Mapping[str, Any]
    anchored: Any = None
    #: The masks, kept only while the frame is fitted (the search's volume is carved
    #: from them); dropped when the frame is stored.
    masks: tuple[Any, ...] | None = None

    @property
    def empty(self) -> bool:
        return len(self.points) + len(self.origins) + len(self.joints) == 0

    def observations(self, rays: int | None = None) -> BodyObservations:
        o, d, s = self.origins, self.directions, self.side
        if rays is not None and len(o) > rays:
            keep = np.linspace(0, len(o) - 1, rays).round().astype(int)
            o, d, s = o[keep], d[keep], s[keep]
        return BodyObservations(points=self.points, point_sigma=self.point_sigma, origins=o, directions=d, ray_side=s, joints=self.joints,
                                anchored=self.anchored)

    def centre(self) -> NDArray[np.float64] | None:
        """Where the body is: the points' median, else the point nearest to all rays."""
        if len(self.points) >= 10:
            return np.asarray(np.median(self.points, axis=0))
        if (self.side >= 0).sum() >= 3:
            keep = self.side >= 0
            d = self.directions[keep] / np.linalg.norm(self.directions[keep], axis=1, keepdims=True)
            projector = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
            a = projector.sum(axis=0)
            if np.linalg.cond(a) < 1e8:
                return np.asarray(np.linalg.solve(a, np.einsum("nij,nj->i", projector, self.origins[keep])))
        if self.joints:
            return np.mean([np.asarray(v, dtype=float) for v in self.joints.values()], axis=0)
        return None


class BodyTracker:
    """Fits a body model frame by frame (see the module docstring).

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera, optional, keyword-only
        The cameras of the frames' masks (body frame: ``R`` composed with
        ``Z_UP_TO_WORLD``, as the body stage does).
    window : int, default 5, keyword-only
        Frames over which the shape is fitted jointly; then it is held for the take.
    rays_per_mask : int, default 300, keyword-only
        Silhouette outline rays drawn per mask.
    inside_per_mask : int, default 100, keyword-only
        One-sided rays drawn per mask inside the silhouette, and as many outside it
        (:func:`silhouette_samples`): they keep limbs from hiding inside the silhouette of
        the torso, which outline rays alone allow.
    sigma_point, sigma_ray, sigma_joint : float, keyword-only
        A-priori standard deviations (see :func:`fit_body`); points may carry their own
        ``point_sigma`` (metres) on top.
    headings : int, default 8, keyword-only
        Headings tried by the global pose search.
    max_iterations : int, default 40, keyword-only
        Levenberg-Marquardt iterations per tracked frame.
    lost_distance : float, default 0.015, keyword-only
        A tracked frame whose observations lie farther than this (median, metres) from the
        fitted skin, or of which clearly less are explained than in the recent frames
        (:func:`~elastocap.body.lost.lost_threshold`), is searched
        for again, from the global starts, the last frame the track held and the tracked
        fit itself; the search's result replaces the tracked fit when it scores clearly
        better (:data:`REPLACE_MARGIN`).
    refuse_distance : float, default 0.03, keyword-only
        The first frame is refused (``InvalidInputError``) when, after the search, the
        median distance exceeds this or less than half the observations are explained: the
        body model cannot explain the subject.
    sigma_shape : float or None, default :data:`SHAPE_PRIOR_SIGMA`, keyword-only
        A Gaussian prior about 1 on each shape coefficient (``fit_body(sigma_shape=)``)
        in the fits of the full family (frames with stereo points); None: no prior.
        With thousands of points the prior must be this tight to matter at all: the data
        pull the trunk's tapers and widths to their bounds and the hands 1.6 times wider,
        into a fit both farther from the skin and with the joints farther off than with
        the prior.
    sigma_shape_masks : float or None, default :data:`SHAPE_PRIOR_SIGMA_MASKS`, keyword-only
        The same prior in the fits of silhouettes alone (the narrow family); None: no
        prior. Looser than with points: masks pin a shape less, and 0.02 already cost
        seed 12's frame 0 2 mm of skin where 0.05 gained a little on both tuning seeds.
    tie_limb_lengths : bool, default True, keyword-only
        Fit one length coefficient per limb (:func:`limb_length_groups`: upper arm,
        forearm and hand; thigh and shin) instead of one per segment, with points or
        silhouettes alone (None means the default). Along a limb that does not bend,
        neither the skin nor an outline says where one segment ends and the next begins:
        on the capsule figure with points, free segment lengths put the wrists 4-7 cm and
        the knees up to 13 cm off along the bone while the skin fitted within 8 mm (branch
        body6); with masks alone, the frame-0 shape fit slid the knees 13-21 cm down the
        thighs (tuning seed 20: joints 51 mm RMS before the shape fit, 101 mm after it
        with free lengths, 27 mm tied; ``benches/README.md``, branch body11). Pass False
        for subjects whose segments do not keep one proportion (the synthetic body figure,
        :mod:`elastocap.synth.body`, draws each segment's length apart).
    data_starts : bool, default False, keyword-only
        Start the global search also from the body's volume (the frame's visual hull, or
        its points' voxels; :func:`~elastocap.body.starts.data_starts`: the heading from
        the trunk, the limbs from the volume's far points). Off by default: it found the
        wrong starts of three tuning seeds of the capsule figure (frame-0 joints 92-155 ->
        39-70 mm with masks alone) and the demo's arms (14.6 -> 0.6 degrees RMS), but on
        held-out seeds it made frame 0 worse more often than better (seed 5 with points
        18.7 -> 80.0 mm, seed 10 masks alone 13.6 -> 36.0 mm, seed 16 skin 26 -> 39 mm;
        seed 8 200 -> 179 mm): the score ranks a wrong pose the data starts reach above the
        right one (``benches/README.md``, branch body10 and session 15's lead).
    symmetric : bool, default False, keyword-only
        Fit one shape for each left part and its right twin
        (:meth:`BodyModel.mirrored_shape_groups`): a shape free on each side lets one
        limb's length or width explain its pose's error (the capsule figure,
        ``benches/README.md``). Off by default because the synthetic body figure draws
        each side's shape on its own (``elastocap.synth.body``, 4% apart).

    The shape family follows the data. Where the fitted frames carry stereo points, each
    part has all four coefficients (length, width, depth, taper); silhouettes alone fit
    the narrow family (:func:`narrow_shape_family`: depth tied to width, taper held at 1),
    since masks pin 64 coefficients less well than 32: on the synthetic body capture (2
    frames of masks) the legs' angles came within 0.8 degrees with the narrow family and
    3.25 with the full one, and on the capsule figure the full family's masks-only tracks
    drifted further (``benches/README.md``, branches body4 and body5).
    """

    def __init__(
        self,
        model: BodyModel,
        *,
        cameras: Sequence[Camera] | None = None,
        window: int = 5,
        rays_per_mask: int = 300,
        inside_per_mask: int = 100,
        sigma_point: float = 0.05,
        sigma_ray: float = 0.1,
        sigma_joint: float = 0.01,
        headings: int = 8,
        max_iterations: int = 40,
        lost_distance: float = 0.015,
        refuse_distance: float = 0.03,
        symmetric: bool = False,
        sigma_shape: float | None = SHAPE_PRIOR_SIGMA,
        sigma_shape_masks: float | None = SHAPE_PRIOR_SIGMA_MASKS,
        tie_limb_lengths: bool | None = True,
        data_starts: bool = False,
    ) -> None:
        if not isinstance(model, BodyModel):
            raise InvalidInputError(f"model must be a BodyModel, got {type(model).__name__}")
        self.model = model
        self.cameras = None if cameras is None else list(cameras)
        self.window = as_count("window", window)
        self.rays_per_mask = as_count("rays_per_mask", rays_per_mask)
        self.inside_per_mask = as_count("inside_per_mask", inside_per_mask, minimum=0)
        self.headings = as_count("headings", headings)
        self.max_iterations = as_count("max_iterations", max_iterations)
        self.lost_distance = as_positive("lost_distance", lost_distance)
        self.refuse_distance = as_positive("refuse_distance", refuse_distance)
        self.symmetric = bool(symmetric)
        self.sigma_shape = None if sigma_shape is None else as_positive("sigma_shape", sigma_shape)
        self.sigma_shape_masks = None if sigma_shape_masks is None else as_positive("sigma_shape_masks", sigma_shape_masks)
        self.tie_limb_lengths = True if tie_limb_lengths is None else bool(tie_limb_lengths)
        self.data_starts = bool(data_starts)
        self._sigmas = {
            "sigma_point": as_positive("sigma_point", sigma_point),
            "sigma_ray": as_positive("sigma_ray", sigma_ray),
            "sigma_joint": as_positive("sigma_joint", sigma_joint),
        }
        self._frames: list[_Frame] = []
        self._states: list[BodyState] = []
        self._quality: list[FrameQuality] = []
        self._searched: list[bool] = []
        self._observed: list[bool] = []
        self._held: list[bool] = []
        self._shape_fixed = False

    # -- observations ---------------------------------------------------------------------

    def _prepare(self, obs: Any, index: int) -> _Frame:
        if isinstance(obs, Mapping):
            obs = BodyObservations(**obs)
        if not isinstance(obs, BodyObservations):
            raise InvalidInputError(f"frame {index} must be a BodyObservations or a dict, got {type(obs).__name__}")
        points = np.zeros((0, 3)) if obs.points is None else np.asarray(obs.points, dtype=np.float64).reshape(-1, 3)
        sigma = None if obs.point_sigma is None else np.asarray(obs.point_sigma, dtype=np.float64).reshape(-1)
        origins = [np.zeros((0, 3)) if obs.origins is None else np.asarray(obs.origins, dtype=np.float64).reshape(-1, 3)]
        directions = [np.zeros((0, 3)) if obs.directions is None else np.asarray(obs.directions, dtype=np.float64).reshape(-1, 3)]
        sides = [np.zeros(len(origins[0]), dtype=np.int8) if obs.ray_side is None else np.asarray(obs.ray_side, dtype=np.int8).reshape(-1)]
        if obs.masks is not None:
            if self.cameras is None or len(self.cameras) != len(obs.masks):
                raise InvalidInputError(f"frame {index}: masks need one camera per mask in BodyTracker(cameras=...)")
            for k, (mask, camera) in enumerate(zip(obs.masks, self.cameras)):
                if mask is None:
                    continue
                o, d, s = silhouette_samples(
                    mask, camera, outline=self.rays_per_mask, inside=self.inside_per_mask, outside=self.inside_per_mask, seed=index * 1009 + k
                )
                origins.append(o)
                directions.append(d)
                sides.append(s)
        return _Frame(points, sigma, np.concatenate(origins), np.concatenate(directions), np.concatenate(sides), dict(obs.joints),
                      obs.anchored, None if obs.masks is None else tuple(obs.masks))

    def quality(self, state: BodyState, frame: _Frame) -> FrameQuality:
        d = observation_distances(self.model, state, frame.points, frame.origins, frame.directions, frame.side)
        if len(d) == 0:
            return FrameQuality(0.0, 1.0, 0)
        return FrameQuality(float(np.median(d)), float(np.mean(d <= EXPLAINED_DISTANCE)), len(d))

    # -- fitting --------------------------------------------------------------------------

    def _fit(self, frames: list[_Frame], init: list[BodyState], *, shape: Any, iterations: int, rays: int | None = None) -> BodyFit:
        groups, bounds = None, None
        thin = all(len(f.points) == 0 for f in frames)
        if shape is None:
            groups = self.model.mirrored_shape_groups() if self.symmetric else np.arange(self.model.n_shape)
            if thin:
                groups, bounds = narrow_shape_family(self.model, groups)
            if self.tie_limb_lengths:
                groups = limb_length_groups(self.model, groups)
            if bounds is None and np.array_equal(groups, np.arange(self.model.n_shape)):
                groups = None
        return fit_body(
            self.model,
            [f.observations(rays) for f in frames],
            init=init,
            shape=shape,
            max_iterations=iterations,
            sigma_point=self._sigmas["sigma_point"],
            sigma_ray=self._sigmas["sigma_ray"],
            sigma_joint=self._sigmas["sigma_joint"],
            shape_groups=groups,
            shape_bounds=bounds,
            sigma_shape=None if shape is not None else self.sigma_shape_masks if thin else self.sigma_shape,
        )

    def search(
        self, frame: _Frame, shape: NDArray[np.float64], *, fit_shape: bool, starts: Sequence[BodyState] = ()
    ) -> tuple[BodyState, FrameQuality]:
        """The global pose search on one frame (:func:`~elastocap.body.search.search_pose`):
        the root at the centre of the data, ``headings`` headings, and ``starts``."""
        centre = frame.centre()
        if centre is None:
            raise InvalidInputError("the frame's observations do not locate the body")

        def fit(init: BodyState, fixed: Any, iterations: int, rays: int | None) -> BodyState:
            return self._fit([frame], [init], shape=fixed, iterations=iterations, rays=rays).states[0]

        volume = body_volume(centre, points=frame.points, masks=frame.masks, cameras=self.cameras) if self.data_starts else None
        state = search_pose(
            self.model, centre, shape, fit, lambda state: self.score(state, frame), fit_shape=fit_shape, headings=self.headings, starts=starts,
            volume=volume,
        )
        return state, self.quality(state, frame)

    def score(self, state: BodyState, frame: _Frame) -> tuple[float, float]:
        """The search's ranking of ``state`` on ``frame``: the mean distance of the
        observations from the skin, each clipped at :data:`SCORE_CLIP` (lower is better),
        and the explained share."""
        d = observation_distances(self.model, state, frame.points, frame.origins, frame.directions, frame.side)
        if len(d) == 0:
            return 0.0, 1.0
        return float(np.mean(np.minimum(d, SCORE_CLIP))), float(np.mean(d <= EXPLAINED_DISTANCE))

    def _held_start(self, frame: _Frame) -> list[BodyState]:
        """The last frame the track held (not lost), its root moved with the data's centre:
        a start for the search of a lost frame. The global starts alone did not find the
        capsule figure on its seed 3's frames 10-17 (``benches/README.md``, branch body7),
        while its pose had changed little since the last held frame."""
        held = [i for i, ok in enumerate(self._held) if ok]
        if not held:
            return []
        last = held[-1]
        motion = self._states[last].motion.copy()
        now, then = frame.centre(), self._frames[last].centre()
        if now is not None and then is not None:
            motion[:3] += now - then
        return [BodyState(self._states[last].shape, np.clip(motion, self.model.lower, self.model.upper))]

    def _predict(self) -> BodyState:
        last = self._states[-1]
        if len(self._states) >= 2 and not self._searched[-1]:
            motion = 2 * last.motion - self._states[-2].motion
        else:
            motion = last.motion.copy()
        return BodyState(last.shape, np.clip(motion, self.model.lower, self.model.upper))

    def _lost(self, quality: FrameQuality) -> bool:
        """Farther than ``lost_distance`` (median), or explaining clearly less than the
        frames before did: a subject the model fits only roughly explains less every
        frame, and a lost track falls from there. "Clearly" is measured against the recent
        frames' own spread (:func:`~elastocap.body.lost.lost_threshold`), not a fixed share:
        with silhouettes alone a limb that drifts off its data costs only a few percent of
        the rays, and the median distance does not move at all."""
        if quality.median_distance > self.lost_distance:
            return True
        recent = [q.explained for q, seen in zip(self._quality[-LOST_RECENT:], self._observed[-LOST_RECENT:]) if seen]
        return quality.explained < lost_threshold(recent)

    def update(self, observations: BodyObservations | Mapping[str, Any]) -> BodyState:
        """Fits the next frame and returns its state (shape may still change until
        ``window`` frames have been seen; :meth:`result` has the final states).

        Raises
        ------
        InvalidInputError
            Malformed observations; on the first frame, no observations or a subject the
            model cannot explain (see ``refuse_distance``).
        """
        index = len(self._states)
        frame = self._prepare(observations, index)
        if index == 0:
            if frame.empty:
                raise InvalidInputError("the first frame has no observations (no points, masks, rays or joints): nothing to start from")
            state, quality = self.search(frame, np.ones(self.model.n_shape), fit_shape=True)
            if quality.median_distance > self.refuse_distance or quality.explained < REFUSE_EXPLAINED:
                raise InvalidInputError(
                    f"the body model cannot explain this subject: after the pose search, the observations lie "
                    f"{100 * quality.median_distance:.1f} cm (median) from the fitted skin and {100 * quality.explained:.0f}% "
                    f"within {100 * EXPLAINED_DISTANCE:.0f} cm (a person: within {100 * self.refuse_distance:.0f} cm, most "
                    "explained); is the subject a person, and are the masks and calibration right?"
                )
            self._append(frame, state, quality, searched=True, observed=True)
            return state
        predicted = self._predict()
        if frame.empty:
            self._append(frame, predicted, FrameQuality(0.0, 1.0, 0), searched=False, observed=False)
            return predicted
        fit = self._fit([frame], [predicted], shape=predicted.shape, iterations=self.max_iterations)
        state, quality, searched = fit.states[0], self.quality(fit.states[0], frame), False
        held = True
        if self._lost(quality):
            # The tracked fit is a start of the search too (its limb restarts may mend the
            # one limb that drifted), and the search's result replaces it only when it
            # scores clearly better by the search's own score: like with like, and not on
            # a difference the score cannot resolve (:data:`REPLACE_MARGIN`).
            found, found_quality = self.search(frame, predicted.shape, fit_shape=False, starts=[*self._held_start(frame), state])
            if self.score(found, frame)[0] < (1 - REPLACE_MARGIN) * self.score(state, frame)[0]:
                state, quality, searched = found, found_quality, True
            held = not self._lost(quality)
        self._append(frame, state, quality, searched=searched, observed=True, held=held)
        if not self._shape_fixed and len(self._states) >= self.window:
            self._fit_shape()
        return self._states[-1]

    def resume(self, observations: BodyObservations | Mapping[str, Any], state: BodyState, *, searched: bool = False) -> None:
        """Appends a frame whose state is already known (a resumed run): no fit, but the
        frame counts for the prediction and the shape window."""
        self.model.check_state(state)
        frame = self._prepare(observations, len(self._states))
        self._append(frame, state, self.quality(state, frame), searched=searched, observed=not frame.empty)
        if not self._shape_fixed and len(self._states) >= self.window:
            self._fit_shape()

    def _append(self, frame: _Frame, state: BodyState, quality: FrameQuality, *, searched: bool, observed: bool, held: bool | None = None) -> None:
        # held: the frame passed the lost test (its own fit, or the search's); by default
        # every observed frame (the first, a resumed one)
        self._held.append(observed if held is None else held)
        # the masks are not kept past the frame's fit (8 x 800x800 a frame over a take)
        self._frames.append(frame if getattr(frame, "masks", None) is None else replace(frame, masks=None))
        self._states.append(state)
        self._quality.append(quality)
        self._searched.append(searched)
        self._observed.append(observed)

    def _fit_shape(self) -> None:
        """One shape, fitted jointly with the motion of the observed frames seen so far."""
        use = [i for i, seen in enumerate(self._observed) if seen]
        fit = self._fit([self._frames[i] for i in use], [self._states[i] for i in use], shape=None, iterations=self.max_iterations)
        for i, state in zip(use, fit.states):
            self._states[i] = state
            self._quality[i] = self.quality(state, self._frames[i])
        self._states = [BodyState(fit.shape, s.motion) for s in self._states]
        self._shape_fixed = True

    def result(self) -> BodyTrack:
        """The track so far, with one shape (fitted now over the frames seen if fewer than
        ``window``)."""
        if not self._states:
            raise InvalidInputError("no frame has been tracked")
        if not self._shape_fixed:
            self._fit_shape()
        return BodyTrack(
            states=list(self._states),
            shape=self._states[0].shape.copy(),
            motion=np.stack([s.motion for s in self._states]),
            quality=list(self._quality),
            searched=list(self._searched),
            observed=list(self._observed),
        )


def track_body(model: BodyModel, frames: Sequence[BodyObservations | Mapping[str, Any]], **options: Any) -> BodyTrack:
    """Tracks ``model`` through ``frames`` (one BodyObservations per frame) with a
    :class:`BodyTracker` built from ``options``; see there."""
    if isinstance(frames, (BodyObservations, Mapping)) or not isinstance(frames, Sequence) or len(frames) == 0:
        raise InvalidInputError("frames must be a non-empty sequence of BodyObservations, one per frame")
    tracker = BodyTracker(model, **options)
    for obs in frames:
        tracker.update(obs)
    return tracker.result()
