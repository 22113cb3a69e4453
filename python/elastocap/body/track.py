"""The body fit as a tracker (issue 16): :class:`BodyTracker`, :func:`track_body`.

The first frame is found by a global pose search (the root placed at the centre of the
data, several headings fitted briefly, the best refined); every later frame starts from
its predecessor moved on at constant velocity and is fitted with the shape held; the shape
is fitted once, jointly over the first ``window`` frames, and then shared by the whole take
(BVH bones have fixed lengths). A frame the prediction loses (its observations far from
the fitted skin) is searched for again, from the global starts and from the last frame the
track held. A subject the model cannot explain (an animal, an
object) is refused on the first frame.
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
from elastocap.body.model import SHAPE_NAMES, SKIN_LEVEL, BodyModel, BodyState
from elastocap.body.search import search_pose
from elastocap.body.starts import body_volume
from elastocap.cameras.camera import Camera

__all__ = ["BodyTrack", "BodyTracker", "FrameQuality", "limb_length_groups", "lost_threshold", "narrow_shape_family", "observation_distances", "track_body"]

#: Observations within this distance of the fitted skin (metres) count as explained.
EXPLAINED_DISTANCE = 0.02
#: The first frame is refused when less than this share of its observations is explained
#: after the search: the body figure is explained at 0.9 or more (synth seeds 1-7, even
#: where the search ended with the legs swapped), the capsule figure in clutter (its
#: contours, 5% outlying points) at 0.73-0.77 (seeds 0, 1), a four-legged animal at 0.50
#: (0.46 before the arms' restarts kept the raise: they now fit two of its legs).
REFUSE_EXPLAINED = 0.6
#: Default ``sigma_shape`` of :class:`BodyTracker`: the shape prior's standard deviation
#: (``fit_body(sigma_shape=)``) when the fitted frames carry stereo points. Chosen on the
#: capsule figure's tuning seeds 0-2 (3 frames): alone, 0.05-0.2 changed nothing
#: measurable and 0.005 was worse than 0.01 (seed 0); with the limb lengths tied, 0.01
#: took the skin from 8.6-11.4 mm (tie alone) to 5.9-7.8 mm and the joints from 21-29 to
#: 16-27 mm RMS (neither: 38-43 mm, 8.3-8.7 mm; ``benches/README.md``, branch body6).
SHAPE_PRIOR_SIGMA = 0.01
#: Default bounds of every shape coefficient (the core's ``SHAPE_RANGE``, ``fit_body``'s
#: default ``shape_bounds``).
SHAPE_RANGE = (0.5, 2.0)
#: A tracked frame is lost when its explained share falls below the upper quartile of the
#: recent frames' (what the track explained while it held: a slow drift pulls their median
#: down with it, tuning seed 2's frames 17-21) by more than this many times their spread
#: (``1.4826`` times the median absolute deviation, so a Gaussian's standard deviation) ...
LOST_SPREADS = 3.0
#: ... and by at least this much. Masks alone, the share of a well-tracked frame moves by
#: up to ~0.02 from frame to frame (spread ~0.005-0.01) and the median ray distance stays
#: at 2-4 mm even when a limb has drifted 10 cm (the capsule figure, tuning seed 2: frame
#: 10 fell 0.849 -> 0.809 with the skin from 16 to 23 mm, frame 11 to 0.67 and 36 mm; the
#: fixed drop of 0.1 used before waited for frame 11; ``benches/README.md``, branch body7).
LOST_DROP = 0.03
#: Frames whose quality sets the reference of the lost test, and how many it needs before
#: it trusts their spread (fewer: the spread is :data:`LOST_PRIOR_SPREAD`).
LOST_RECENT = 10
LOST_MIN_RECENT = 4
#: The spread assumed for the first tracked frames, whose few predecessors do not measure
#: one: the largest spread of a held masks-only track (1.4826 MAD of the explained share,
#: 0.004-0.010 on the capsule figure's tuning seeds 2 and 12, ``benches/README.md``,
#: branch body7). Before, these frames were lost only 0.1 below their predecessors' median,
#: which let a drift of 5 mm skin pass for three frames (branch body8).
LOST_PRIOR_SPREAD = 0.01
#: Observation distances are clipped at this (metres) in the search's score
#: (:meth:`BodyTracker.score`): a limb far off its data costs as much as one just off it.
SCORE_CLIP = 0.05
#: A lost frame's search result replaces the tracked fit only when its score is lower by
#: at least this share. The score does not resolve smaller differences: among the frame-0
#: search's candidates on the capsule figure (tuning seeds 2 and 12, masks alone), of two
#: states whose scores differ by less than 2%, the better-scored one had its joints more
#: than 2 cm worse in 32-34% of pairs; 2-5%: 14-19%; 5-10%: 6-12% (branch body9). Before,
#: the search's result replaced the tracked fit whenever it explained a larger share, a
#: different measure than the one the search ranked by (seed 16, frame 18: the search's
#: result, kept, was 33 mm from the true skin, the frames around it 20-23 mm; branch body8).
REPLACE_MARGIN = 0.05


@dataclass(frozen=True)
class FrameQuality:
    """How well a state explains one frame's observations.

    Attributes
    ----------
    median_distance : float
        Median approximate distance ``|F - T| / |grad F|`` of the points and silhouette rays
        from the skin, metres (rays: at their field maximum).
    explained : float
        Share of them within :data:`EXPLAINED_DISTANCE`.
    observations : int
    """

    median_distance: float
    explained: float
    observations: int


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


def observation_distances(
    model: BodyModel, state: BodyState, points: Any, origins: Any, directions: Any, side: Any = None
) -> NDArray[np.float64]:
    """Approximate distances (metres) of points and silhouette rays from the skin of
    ``state``: ``|F - T| / |grad F|`` at each point, and at each ray's field maximum (a ray
    that misses the model: infinity; a one-sided ray, ``side`` +1 / -1, that is satisfied:
    0). Points first, then rays."""
    out = []
    if len(points):
        f, g, _ = model.field(points, state)
        out.append(_distance(f, g))
    if len(origins):
        found = model.ray_maxima(origins, directions, state)
        f, g, _ = model.field(found["points"], state)
        d = _distance(f, g)
        d[~found["hit"]] = np.inf
        if side is not None:
            side = np.asarray(side)
            value = np.where(found["hit"], found["values"], 0.0)
            d[((side > 0) & (value >= SKIN_LEVEL)) | ((side < 0) & (value <= SKIN_LEVEL))] = 0.0
        out.append(d)
    return np.concatenate(out) if out else np.zeros(0)


def _distance(f: NDArray[np.float64], g: NDArray[np.float64]) -> NDArray[np.float64]:
    norm = np.linalg.norm(g, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.abs(f - SKIN_LEVEL) / norm
    d[(f < 1e-8) | ~np.isfinite(d)] = np.inf
    return np.asarray(d)


def narrow_shape_family(model: BodyModel, groups: Any) -> tuple[NDArray[np.int64], tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """The shape family for thin data: each part's depth tied to its width and its taper
    held at 1 (SPEC 6's length and width), on top of ``groups`` (``fit_body``'s
    ``shape_groups``). Returns ``(shape_groups, shape_bounds)`` for :func:`fit_body`; the
    held tapers leave the normal equations (bounds lower = upper), so they stay exactly 1."""
    groups = np.asarray(groups, dtype=np.int64).reshape(-1, len(SHAPE_NAMES)).copy()
    width, depth, taper = (SHAPE_NAMES.index(k) for k in ("width", "depth", "taper"))
    # depth joins width's group (the same merge for a mirrored twin's depth)
    merged = {int(d): int(w) for d, w in zip(groups[:, depth], groups[:, width])}
    groups[:, depth] = [merged[int(d)] for d in groups[:, depth]]
    _, renumbered = np.unique(groups.reshape(-1), return_inverse=True)
    lower = np.full(model.n_shape, SHAPE_RANGE[0])
    upper = np.full(model.n_shape, SHAPE_RANGE[1])
    lower.reshape(-1, len(SHAPE_NAMES))[:, taper] = 1.0
    upper.reshape(-1, len(SHAPE_NAMES))[:, taper] = 1.0
    return renumbered.astype(np.int64), (lower, upper)


def limb_length_groups(model: BodyModel, groups: Any) -> NDArray[np.int64]:
    """``groups`` (``fit_body``'s ``shape_groups``) with the length coefficients of each
    limb's segments tied: a left or right part (``l_`` / ``r_``, as
    :meth:`BodyModel.mirrored_shape_groups`) that continues its parent's bone (a left or
    right part too, the child's offset along the parent's z axis, no rest turn: the
    forearm and hand under the upper arm, the shin under the thigh, not the foot) shares
    its parent's length, so a limb keeps the described proportions of its segments and
    only its overall length is fitted.

    Why: along a limb that does not bend in the fitted frames (the capsule figure's wrist
    never does; its knees are straight for most of a 5-frame window) the skin does not
    say where one segment ends and the next begins, and free lengths slide the joint along
    the bone to wherever the model's flesh best matches the subject's profile: the capsule
    figure's wrists 4-7 cm towards the elbow under a 1.6 times wider hand, its knees 13 cm
    down a 1.28 times longer thigh (``benches/README.md``, branch body6)."""
    table = np.asarray(groups, dtype=np.int64).reshape(-1, len(SHAPE_NAMES)).copy()
    description = model.to_dict()["parts"]
    length = SHAPE_NAMES.index("length")
    limb = [p["name"][:2] in ("l_", "r_") for p in description]
    index = {p["name"]: i for i, p in enumerate(description)}
    for i, part in enumerate(description):
        parent = index.get(part["parent"]) if part["parent"] is not None else None
        if parent is None or not (limb[i] and limb[parent]):
            continue
        along = part["offset"][0] == 0.0 and part["offset"][1] == 0.0 and part["offset"][2] > 0.0
        if along and np.array_equal(np.asarray(part["rest"]), np.eye(3)):
            # parents come first, so the parent's group already holds its own parent's
            old = table[i, length]
            table[table == old] = table[parent, length]
    _, renumbered = np.unique(table.reshape(-1), return_inverse=True)
    return renumbered.astype(np.int64)


def lost_threshold(recent: Sequence[float]) -> float:
    """The explained share under which a tracked frame counts as lost, given the shares of
    the recent observed frames (oldest first): their upper quartile less
    :data:`LOST_SPREADS` times their spread (``1.4826`` times the median absolute deviation
    from their median), and at least :data:`LOST_DROP` less; with fewer than
    :data:`LOST_MIN_RECENT` frames, whose spread says little, the spread is
    :data:`LOST_PRIOR_SPREAD`; with none, 0.9."""
    shares = np.asarray(recent, dtype=np.float64)[-LOST_RECENT:]
    if len(shares) == 0:
        return 0.9
    median = float(np.median(shares))
    if len(shares) < LOST_MIN_RECENT:
        spread = LOST_PRIOR_SPREAD
    else:
        spread = 1.4826 * float(np.median(np.abs(shares - median)))
    return float(np.percentile(shares, 75)) - max(LOST_SPREADS * spread, LOST_DROP)


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
        (:data:`LOST_SPREADS` times their spread, at least :data:`LOST_DROP`; for the
        first tracked frames :data:`LOST_PRIOR_SPREAD` stands for the spread), is searched
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
        Silhouettes alone fit the narrow family, without it. With thousands of points
        the prior must be this tight to matter at all: the data pull the trunk's tapers
        and widths to their bounds and the hands 1.6 times wider, into a fit both farther
        from the skin and with the joints farther off than with the prior.
    tie_limb_lengths : bool, optional, keyword-only
        Fit one length coefficient per limb (:func:`limb_length_groups`: upper arm,
        forearm and hand; thigh and shin) instead of one per segment. Default (None): tied
        when the fitted frames carry stereo points (the full family), free with
        silhouettes alone (the narrow family). On the capsule figure with points, free
        segment lengths put the wrists 4-7 cm and the knees up to 13 cm off along the
        bone while the skin fitted within 8 mm (``benches/README.md``, branch body6).
        Pass False for subjects whose segments do not keep one proportion (the synthetic
        body figure, :mod:`elastocap.synth.body`, draws each segment's length apart).
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
        tie_limb_lengths: bool | None = None,
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
        self.tie_limb_lengths = None if tie_limb_lengths is None else bool(tie_limb_lengths)
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
        if shape is None:
            groups = self.model.mirrored_shape_groups() if self.symmetric else np.arange(self.model.n_shape)
            thin = all(len(f.points) == 0 for f in frames)
            if thin:
                groups, bounds = narrow_shape_family(self.model, groups)
            if self.tie_limb_lengths or (self.tie_limb_lengths is None and not thin):
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
            sigma_shape=self.sigma_shape if shape is None and not all(len(f.points) == 0 for f in frames) else None,
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

        volume = body_volume(centre, points=frame.points, masks=frame.masks, cameras=self.cameras)
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
        frames' own spread (:data:`LOST_SPREADS`, :data:`LOST_DROP`), not a fixed share:
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
