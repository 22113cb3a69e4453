"""Fitting the body model to observations (SPEC 6): :func:`fit_body`, :class:`BodyFit`,
:class:`BodyObservations`; the silhouette rays it reads are in :mod:`elastocap.body.rays`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_float_array, as_positive
from elastocap.body.model import BodyModel, BodyState
from elastocap.body.rays import silhouette_rays, silhouette_samples
from elastocap.body.tracks import anchored_arrays, append_tracks, attach_tracks
from elastocap.cameras.camera import Camera

__all__ = ["BodyFit", "BodyObservations", "fit_body", "silhouette_rays", "silhouette_samples"]


@dataclass(frozen=True)
class BodyObservations:
    """What one frame shows of the body.

    Attributes
    ----------
    points : (N, 3) array_like or None
        3-D points on the skin (world, metres), e.g. from stereo.
    origins, directions : (R, 3) array_like or None
        Silhouette rays (world): each should graze the skin (SPEC 6).
    masks : sequence of (H, W) array_like or None
        Silhouette masks, one per camera of ``fit_body(cameras=...)``; turned into rays by
        :func:`silhouette_rays`.
    joints : mapping of part name to (3,) array_like, optional
        Observed joint positions (the origin of the named part's frame), metres.
    ray_side : (R,) array_like of int or None
        Kind of each given ray (``origins``): 0 an outline ray (tangent to the skin), +1
        through a pixel inside the silhouette (must meet the skin), -1 outside it (must
        miss it); see :func:`silhouette_samples`. Default: all outline rays. Rays drawn
        from ``masks`` are outline rays.
    anchored : tuple or None
        Tracked points attached to body parts (:mod:`elastocap.body.tracks`): ``(points
        (T, 3) world metres, part (T,) int, offset (T, 3) metres in the part's frame, sigma
        (T,) metres)``; each pulls its part's point ``offset`` to ``points`` with weight
        ``1 / sigma_joint^2`` times ``(0.01 / sigma)^2``.
    point_sigma : (N,) array_like or None
        Standard deviation of each point (metres), e.g. from stereo's or a track's
        covariance: a point's weight is ``(POINT_SIGMA_REFERENCE / point_sigma)^2`` times
        that of ``fit_body(sigma_point=...)``. Default: all points equally precise.
    """

    points: Any = None
    origins: Any = None
    directions: Any = None
    masks: Any = None
    joints: Mapping[str, Any] = field(default_factory=dict)
    point_sigma: Any = None
    ray_side: Any = None
    anchored: Any = None


#: The point standard deviation (metres) that ``fit_body(sigma_point=...)`` (field units)
#: stands for when points carry their own ``point_sigma``: about what 0.05 field units are
#: across the skin of a limb (``|grad F|`` ~ 10 per metre there).
POINT_SIGMA_REFERENCE = 0.005


@dataclass(frozen=True)
class BodyFit:
    """The result of :func:`fit_body`.

    Attributes
    ----------
    states : list of BodyState
        One per frame, sharing ``shape``.
    shape : (4 P,) float64
    motion : (F, n_motion) float64
    status : str
        "cost converged", "step converged", "gradient converged", "maximum iterations" or
        "no descent" (reported, not raised).
    iterations : int
    initial_cost, final_cost : float
        ``1/2 sum p_i r_i^2`` over the kept observations.
    point_part, ray_part : (N,) int64
        Part assigned to each point / ray (largest field contribution), all frames
        concatenated in frame order.
    point_inlier, ray_inlier : (N,) bool
        Observations kept by the last outlier test.
    unobserved_parts : list of str
        Parts that no kept observation is assigned to: their shape coefficients keep their
        initial values (up to the pull of the far tails of their balls on other parts'
        observations, ~1e-10 for a part 0.3 m from any).
    """

    states: list[BodyState]
    shape: NDArray[np.float64]
    motion: NDArray[np.float64]
    status: str
    iterations: int
    initial_cost: float
    final_cost: float
    point_part: NDArray[np.int64]
    point_inlier: NDArray[np.bool_]
    ray_part: NDArray[np.int64]
    ray_inlier: NDArray[np.bool_]
    unobserved_parts: list[str]


def _rows3(name: str, value: Any) -> NDArray[np.float64]:
    if value is None:
        return np.zeros((0, 3))
    array = as_float_array(name, value)
    if array.ndim != 2 or array.shape[1] != 3:
        raise InvalidInputError(f"{name} must have shape (N, 3), got {array.shape}")
    return array


def _frame(model: BodyModel, obs: Any, f: int, cameras: Sequence[Camera] | None, max_rays: int | None) -> tuple[NDArray[Any], ...]:
    if isinstance(obs, Mapping):
        obs = BodyObservations(**obs)
    if not isinstance(obs, BodyObservations):
        raise InvalidInputError(f"frames[{f}] must be a BodyObservations or a dict, got {type(obs).__name__}")
    points = _rows3(f"frames[{f}].points", obs.points)
    origins = _rows3(f"frames[{f}].origins", obs.origins)
    directions = _rows3(f"frames[{f}].directions", obs.directions)
    if len(origins) != len(directions):
        raise InvalidInputError(f"frames[{f}]: origins and directions must have as many rows, got {len(origins)} and {len(directions)}")
    if obs.ray_side is None:
        sides = np.zeros(len(origins), dtype=np.int8)
    else:
        sides = np.asarray(obs.ray_side).reshape(-1)
        if sides.shape != (len(origins),) or not np.isin(sides, (-1, 0, 1)).all():
            raise InvalidInputError(f"frames[{f}].ray_side must hold -1, 0 or 1 per ray ({len(origins)}), got shape {sides.shape}")
        sides = sides.astype(np.int8)
    if obs.point_sigma is None:
        point_scale = np.ones(len(points))
    else:
        point_scale = as_float_array(f"frames[{f}].point_sigma", obs.point_sigma).reshape(-1) / POINT_SIGMA_REFERENCE
        if point_scale.shape != (len(points),) or not (np.isfinite(point_scale).all() and (point_scale > 0).all()):
            raise InvalidInputError(f"frames[{f}].point_sigma must hold one positive finite value per point ({len(points)}), got shape {point_scale.shape}")
    if obs.masks is not None:
        if cameras is None or len(cameras) != len(obs.masks):
            raise InvalidInputError(f"frames[{f}].masks needs one camera per mask in fit_body(cameras=...)")
        # A camera without a mask (None) gives no rays.
        rays = [silhouette_rays(mask, cam, max_rays=max_rays, seed=f) for mask, cam in zip(obs.masks, cameras) if mask is not None]
        origins = np.concatenate([origins] + [o for o, _ in rays])
        directions = np.concatenate([directions] + [d for _, d in rays])
        sides = np.concatenate([sides, np.zeros(len(origins) - len(sides), dtype=np.int8)])
    names = {n: i for i, n in enumerate(model.part_names)}
    unknown = [n for n in obs.joints if n not in names]
    if unknown:
        raise InvalidInputError(f"frames[{f}].joints names unknown parts {unknown}; parts are {model.part_names}")
    joints = _rows3(f"frames[{f}].joints", [obs.joints[n] for n in obs.joints] if obs.joints else None)
    joint_part = np.array([names[n] for n in obs.joints], dtype=np.int64)
    offsets, scales = np.zeros((len(joints), 3)), np.ones(len(joints))
    if obs.anchored is not None:
        at, part, offset, scale = anchored_arrays(obs.anchored, f"frames[{f}].anchored", len(names))
        joints, joint_part = np.concatenate([joints, at]), np.concatenate([joint_part, part])
        offsets, scales = np.concatenate([offsets, offset]), np.concatenate([scales, scale])
    return points, origins, directions, joints, joint_part, point_scale, sides, offsets, scales


def fit_body(
    model: BodyModel,
    frames: Sequence[Any],
    *,
    cameras: Sequence[Camera] | None = None,
    shape: Any = None,
    init: BodyState | Sequence[BodyState] | None = None,
    sigma_point: float = 0.05,
    sigma_ray: float = 0.05,
    sigma_joint: float = 0.01,
    max_iterations: int = 100,
    refresh_every: int = 5,
    outlier_distance: float | None = None,
    max_rays_per_mask: int | None = None,
    residual: str = "log",
    log_epsilon: float = 0.01,
    tracks: Any = None,
    frame_numbers: Sequence[int] | None = None,
    rest_frame: int | None = None,
    track_outlier: float = 0.1,
    shape_groups: Any = None,
    shape_bounds: Any = None,
    sigma_shape: float | None = None,
) -> BodyFit:
    """Fits shape (shared by all frames) and motion (per frame) of ``model`` to 3-D points,
    silhouette rays and joint positions by sparse Levenberg-Marquardt (SPEC 6).

    Parameters
    ----------
    model : BodyModel
    frames : sequence of BodyObservations (or dicts of its fields)
        One per frame.
    cameras : sequence of Camera, optional, keyword-only
        The cameras of the frames' ``masks``.
    shape : (4 P,) array_like, optional, keyword-only
        A known shape, held fixed; default: estimate it, starting from ``init``'s shape.
    init : BodyState or sequence of BodyState, optional, keyword-only
        Starting state(s); default ``model.rest_state()``. The fit is local: start within
        tens of degrees and centimetres of the answer (e.g. from the previous frame).
    sigma_point, sigma_ray : float, keyword-only
        A-priori standard deviations of the point and ray residuals ``F - 0.5`` (field
        units); weights are ``1 / sigma^2`` (SPEC 6: ``p_i / p_j = sigma_j^2 / sigma_i^2``).
    sigma_joint : float, keyword-only
        Standard deviation of joint positions, metres.
    max_iterations, refresh_every : int, keyword-only
        Iteration cap; part assignment and outlier rejection are redone every
        ``refresh_every`` iterations.
    outlier_distance : float, optional, keyword-only
        Reject points and rays farther than this (metres, approximated by
        ``|F - 0.5| / |grad F|``) from the skin; default: three robust standard deviations
        of the current distances, at least 5 mm. Points where the field vanishes are
        always rejected (they carry no information).
    max_rays_per_mask : int, optional, keyword-only
        Subsample each mask's outline rays.
    residual : {"log", "field"}, keyword-only
        "field": SPEC 6's ``F - 0.5``. "log" (default): ``(0.5 + eps) ln((F + eps) / (0.5 +
        eps))``, equal to first order on the skin, but it keeps pulling parts that start a
        few centimetres off where ``F - 0.5`` is flat (``benches/README.md``: from a 10%
        wrong shape "field" lets feet swell and diverges, "log" recovers the truth).
    log_epsilon : float, keyword-only
        ``eps`` of the "log" residual: below ``F ~ eps`` it flattens again, so far
        outliers do not pull.
    tracks : Tracks, optional, keyword-only
        Tracked surface points (:func:`elastocap.track_points`; world metres, the frames'
        world). Each is attached to the part it lies on at its frame nearest
        ``rest_frame``, at a fixed place in that part's frame, and pulled to its tracked
        position in the other frames with weight ``1 / sigma_joint^2`` times
        ``(0.01 m / its sigma)^2`` (:mod:`elastocap.body.tracks`). The fit then runs twice:
        without tracks (to attach them), and with them from that result. An empty set
        changes nothing.
    frame_numbers : sequence of int, optional, keyword-only
        The frame number of each entry of ``frames`` (the tracks' frames); default
        ``0 .. len(frames) - 1``.
    rest_frame : int, optional, keyword-only
        The frame the tracks are anchored about (default the first).
    track_outlier : float, keyword-only
        A track farther than this (metres) from where the fit without tracks puts its
        point is left out of that frame.
    shape_groups : (4 P,) array_like of int, optional, keyword-only
        Ties shape coefficients: those with the same number (groups ``0 .. G - 1``, none
        empty) are fitted as one, from the mean of their starting values; e.g.
        :meth:`BodyModel.mirrored_shape_groups` gives a left and a right limb one shape.
        Default: each coefficient free.
    shape_bounds : ((4 P,), (4 P,)) array_like, optional, keyword-only
        Lower and upper bound of each shape coefficient (default 0.5 and 2 for all); a
        tied group keeps within the tightest of its members' bounds. A group whose bounds
        meet is held exactly at that value (left out of the solve, not clamped after each
        step; :func:`elastocap.body.shape_family.narrow_shape_family` holds the tapers so).
    sigma_shape : float, optional, keyword-only
        A Gaussian prior on each shape coefficient about 1 (the part as described) with
        this standard deviation; default none. Where a limb does not bend in the fitted
        frames, the skin alone does not say where one part ends and the next begins, and
        free coefficients slide the joint along the bone (``benches/README.md``, branch
        body6: the capsule figure's wrists 4-7 cm towards the elbow under a hand grown
        1.6 times wider).

    Returns
    -------
    BodyFit

    Raises
    ------
    InvalidInputError
        For malformed observations (wrong shapes, NaN, zero ray directions, unknown joint
        names), no observations at all, a state of the wrong length, non-positive sigmas.
        Rays that miss the model are kept with residual ``-0.5`` and zero Jacobian until
        the outlier test drops them; non-convergence is reported in ``status``.
    """
    if not isinstance(model, BodyModel):
        raise InvalidInputError(f"model must be a BodyModel, got {type(model).__name__}")
    if isinstance(frames, (BodyObservations, Mapping)) or not isinstance(frames, Sequence) or len(frames) == 0:
        raise InvalidInputError("frames must be a non-empty sequence of BodyObservations, one per frame")
    n = len(frames)
    if init is None:
        inits = [model.rest_state()] * n
    elif isinstance(init, BodyState):
        inits = [init] * n
    else:
        inits = list(init)
        if len(inits) != n:
            raise InvalidInputError(f"init must hold one state per frame ({n}), got {len(inits)}")
    checked = [model.check_state(s) for s in inits]
    motion = np.ascontiguousarray(np.stack([m for _, m in checked]))
    start_shape = checked[0][0] if shape is None else model.check_state(BodyState(as_float_array("shape", shape), checked[0][1]))[0]
    per_frame = [_frame(model, obs, f, cameras, max_rays_per_mask) for f, obs in enumerate(frames)]
    attached = None
    if tracks is not None:
        numbers = list(range(n)) if frame_numbers is None else [int(v) for v in frame_numbers]
        if len(numbers) != n:
            raise InvalidInputError(f"frame_numbers must hold one number per frame ({n}), got {len(numbers)}")
        options = dict(cameras=cameras, shape=shape, sigma_point=sigma_point, sigma_ray=sigma_ray, sigma_joint=sigma_joint,
                       max_iterations=max_iterations, refresh_every=refresh_every, outlier_distance=outlier_distance,
                       max_rays_per_mask=max_rays_per_mask, residual=residual, log_epsilon=log_epsilon,
                       shape_groups=shape_groups, shape_bounds=shape_bounds, sigma_shape=sigma_shape)
        first = fit_body(model, frames, init=init, **options)  # type: ignore[arg-type]
        attached = attach_tracks(model, first.states, tracks, numbers,
                                 rest_frame=numbers[0] if rest_frame is None else int(rest_frame),
                                 outlier=as_positive("track_outlier", track_outlier))
        if attached.count == 0:
            return first
        motion = np.ascontiguousarray(first.motion)
        start_shape = first.shape if shape is None else start_shape

    def stack(k: int) -> NDArray[np.float64]:
        return np.ascontiguousarray(np.concatenate([p[k] for p in per_frame]).reshape(-1, 3))

    def frame_of(k: int) -> NDArray[np.int64]:
        return np.concatenate([np.full(len(p[k]), f, dtype=np.int64) for f, p in enumerate(per_frame)])

    if residual not in ("log", "field"):
        raise InvalidInputError(f"residual must be 'log' or 'field', got {residual!r}")
    observations = {
        "points": stack(0),
        "point_frame": frame_of(0),
        "origins": stack(1),
        "directions": stack(2),
        "ray_frame": frame_of(1),
        "joints": stack(3),
        "joint_part": np.concatenate([p[4] for p in per_frame]).astype(np.int64),
        "joint_frame": frame_of(3),
        "log_epsilon": as_positive("log_epsilon", log_epsilon) if residual == "log" else None,
        "point_scale": np.ascontiguousarray(np.concatenate([p[5] for p in per_frame])),
        "ray_side": np.ascontiguousarray(np.concatenate([p[6] for p in per_frame])),
        "joint_offset": stack(7),
        "joint_scale": np.ascontiguousarray(np.concatenate([p[8] for p in per_frame])),
        "sigma": [as_positive("sigma_point", sigma_point), as_positive("sigma_ray", sigma_ray), as_positive("sigma_joint", sigma_joint)],
    }
    if shape_groups is not None:
        groups = np.asarray(shape_groups).reshape(-1)
        if groups.shape != (model.n_shape,) or not np.issubdtype(groups.dtype, np.integer) or groups.min() < 0 \
                or not np.array_equal(np.unique(groups), np.arange(groups.max() + 1)):
            raise InvalidInputError(f"shape_groups must hold {model.n_shape} integers numbering groups 0..G-1 with none empty, got {shape_groups!r}")
        observations["shape_group"] = np.ascontiguousarray(groups, dtype=np.int64)
    if shape_bounds is not None:
        try:
            lower, upper = (as_float_array("shape_bounds", b).reshape(-1) for b in shape_bounds)
        except (TypeError, ValueError):
            raise InvalidInputError("shape_bounds must be a pair (lower, upper) of arrays") from None
        if lower.shape != (model.n_shape,) or upper.shape != (model.n_shape,) or not ((lower > 0) & (lower <= upper)).all():
            raise InvalidInputError(f"shape_bounds must be two arrays of {model.n_shape} values with 0 < lower <= upper")
        observations["shape_lower"], observations["shape_upper"] = np.ascontiguousarray(lower), np.ascontiguousarray(upper)
    if sigma_shape is not None:
        observations["shape_sigma"] = as_positive("sigma_shape", sigma_shape)
    if attached is not None:
        append_tracks(observations, attached)
    result = model._core.fit(
        observations,
        np.ascontiguousarray(start_shape),
        motion,
        np.ascontiguousarray(model.lower),
        np.ascontiguousarray(model.upper),
        fit_shape=shape is None,
        max_iterations=as_count("max_iterations", max_iterations),
        refresh_every=as_count("refresh_every", refresh_every, minimum=0),
        outlier_distance=None if outlier_distance is None else as_positive("outlier_distance", outlier_distance),
    )
    seen = np.zeros(len(model.part_names), dtype=bool)
    seen[np.asarray(result["point_part"])[np.asarray(result["point_inlier"])]] = True
    seen[np.asarray(result["ray_part"])[np.asarray(result["ray_inlier"])]] = True
    seen[np.asarray(observations["joint_part"], dtype=np.int64)] = True
    return BodyFit(
        states=[BodyState(result["shape"], m) for m in result["motion"]],
        shape=result["shape"],
        motion=result["motion"],
        status=result["status"],
        iterations=int(result["iterations"]),
        initial_cost=float(result["initial_cost"]),
        final_cost=float(result["final_cost"]),
        point_part=result["point_part"],
        point_inlier=result["point_inlier"],
        ray_part=result["ray_part"],
        ray_inlier=result["ray_inlier"],
        unobserved_parts=[name for name, s in zip(model.part_names, seen) if not s],
    )
