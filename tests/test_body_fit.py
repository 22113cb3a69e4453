"""Ground-truth recovery by fit_body (issue 6): a synthetic body in a random pose observed
through points on its skin and 8 silhouettes; the papers' one-sided stereo experiment;
shared shape over 10 frames; bad input."""

from __future__ import annotations

import numpy as np
import pytest

from body_scenes import angle_rms_degrees, perturbed, scene, shape_error
from elastocap import InvalidInputError
from elastocap.body import BodyModel, BodyObservations, fit_body
from elastocap.body.track import narrow_shape_family
from tolerances import (
    BODY_ANGLE_RMS_DEG,
    BODY_NOISY_ANGLE_RMS_DEG,
    BODY_NOISY_SHAPE_4P_RTOL,
    BODY_NOISY_SHAPE_RTOL,
    BODY_ONE_SIDED_WIDTH_RTOL,
    BODY_SHAPE_RTOL,
    BODY_STEREO_INFLATION_MIN,
)

MODEL = BodyModel.default_human()
LIMBS = [i for i, n in enumerate(MODEL.part_names) if any(k in n for k in ("arm", "thigh", "shin"))]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_noise_free_recovery(seed: int) -> None:
    sc = scene(MODEL, seed, n_cameras=6)
    init = perturbed(MODEL, sc.truth, np.random.default_rng(100 + seed))
    # Silhouette outlines are quantised to half a pixel (~3 mm here): sigma_ray says so.
    fit = fit_body(MODEL, [BodyObservations(points=sc.points, masks=sc.masks)], cameras=sc.cameras, init=init, sigma_ray=0.3)
    assert fit.status in ("cost converged", "step converged", "gradient converged")
    assert angle_rms_degrees(MODEL, fit.motion[0], sc.truth.motion) <= BODY_ANGLE_RMS_DEG
    assert shape_error(fit.shape, sc.truth.shape) <= BODY_SHAPE_RTOL
    assert fit.final_cost < 1e-3 * fit.initial_cost
    assert fit.unobserved_parts == []


@pytest.mark.parametrize("family", ["narrow", "full"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_recovery_with_noise_and_outliers(seed: int, family: str) -> None:
    """"narrow": the generator's own family (depth tied to width, taper held at 1 by
    bounds lower = upper), which the fit must hold exactly; "full": all four coefficients
    per part free, which one noisy frame pins less well."""
    sc = scene(MODEL, seed, n_cameras=8)
    rng = np.random.default_rng(100 + seed)
    points = sc.points + rng.normal(0, 0.01, sc.points.shape)
    lower, upper = MODEL.bounds(sc.truth)
    outliers = rng.uniform(lower - 0.2, upper + 0.2, (len(points) // 9, 3))  # 10% of all
    init = perturbed(MODEL, sc.truth, rng)
    frame = BodyObservations(points=np.concatenate([points, outliers]), masks=sc.masks)
    groups, bounds = narrow_shape_family(MODEL, np.arange(MODEL.n_shape)) if family == "narrow" else (None, None)
    fit = fit_body(MODEL, [frame], cameras=sc.cameras, init=init, sigma_point=0.2, sigma_ray=0.1, shape_groups=groups, shape_bounds=bounds)
    assert angle_rms_degrees(MODEL, fit.motion[0], sc.truth.motion) <= BODY_NOISY_ANGLE_RMS_DEG
    if family == "narrow":
        per_part = fit.shape.reshape(-1, 4)
        assert np.array_equal(per_part[:, 3], np.ones(len(per_part)))  # held exactly, not clamped near
        assert np.array_equal(per_part[:, 2], per_part[:, 1])
        assert shape_error(fit.shape, sc.truth.shape) <= BODY_NOISY_SHAPE_RTOL
    else:
        assert shape_error(fit.shape, sc.truth.shape) <= BODY_NOISY_SHAPE_4P_RTOL
    # most outliers rejected, most inliers kept
    assert fit.point_inlier[len(points) :].mean() < 0.1
    assert fit.point_inlier[: len(points)].mean() > 0.95


def one_sided_stereo(sc, rng: np.random.Generator, depth_sigma: float = 0.02) -> np.ndarray:
    """Skin points facing camera 0, with stereo's error: 2 cm along the line of sight,
    2 mm across it."""
    camera = sc.cameras[0]
    _, grad, _ = MODEL.field(sc.points, sc.truth)
    normals = -grad / np.linalg.norm(grad, axis=1, keepdims=True)
    view = sc.points - camera.center
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    front = (normals * view).sum(axis=1) < -0.2
    n = int(front.sum())
    return sc.points[front] + rng.normal(0, depth_sigma, (n, 1)) * view[front] + rng.normal(0, 0.002, (n, 3))


def test_one_sided_stereo_inflates_limbs_and_silhouettes_correct_them() -> None:
    """Papers 002/003: shallow, noisy stereo from one side alone makes limbs too wide;
    silhouettes bring the widths back."""
    sc = scene(MODEL, 2, n_points=6000, n_cameras=8)
    rng = np.random.default_rng(102)
    points = one_sided_stereo(sc, rng)
    init = perturbed(MODEL, sc.truth, rng, degrees=5)
    alone = fit_body(MODEL, [BodyObservations(points=points)], init=init, sigma_point=0.2)
    both = fit_body(MODEL, [BodyObservations(points=points, masks=sc.masks)], cameras=sc.cameras, init=init, sigma_point=0.2, sigma_ray=0.1)
    true_widths = sc.truth.shape[1::4][LIMBS]
    inflation_alone = float(np.mean(alone.shape[1::4][LIMBS] / true_widths - 1))
    error_both = float(np.mean(np.abs(both.shape[1::4][LIMBS] / true_widths - 1)))
    assert inflation_alone > BODY_STEREO_INFLATION_MIN
    assert error_both <= BODY_ONE_SIDED_WIDTH_RTOL


def test_shape_shared_over_ten_frames_beats_every_single_frame() -> None:
    """Sparse, noisy frames (300 points with 5 mm noise, 4 silhouettes of 300 rays): each
    frame alone pins the shape loosely; together they pin it better than any one."""
    rng = np.random.default_rng(7)
    shape = MODEL.as_shape(rng.uniform(0.9, 1.1, 2 * len(MODEL.part_names)))
    frames, inits, truths = [], [], []
    options = {"sigma_point": 0.1, "sigma_ray": 0.1, "max_rays_per_mask": 300}
    for f in range(10):
        sc = scene(MODEL, 50 + f, n_points=10, n_cameras=4)
        truth = sc.truth.replace(shape=shape)
        points = MODEL.skin_points(truth, 300, seed=f, spacing=0.015) + rng.normal(0, 0.005, (300, 3))
        frames.append(BodyObservations(points=points, masks=[MODEL.silhouette(truth, c) for c in sc.cameras]))
        inits.append(perturbed(MODEL, truth, rng, degrees=3))
        truths.append(truth)
        cameras = sc.cameras

    def rms(fitted: np.ndarray) -> float:
        return float(np.sqrt(np.mean((fitted / shape - 1) ** 2)))

    single = [fit_body(MODEL, [frames[f]], cameras=cameras, init=inits[f], **options).shape for f in range(10)]
    joint = fit_body(MODEL, frames, cameras=cameras, init=inits, **options)
    assert shape_error(joint.shape, shape) < min(shape_error(s, shape) for s in single)
    assert rms(joint.shape) < min(rms(s) for s in single)
    # One pose (frame 6) sits in a local minimum from this start; the others are recovered.
    errors = [angle_rms_degrees(MODEL, joint.motion[f], truths[f].motion) for f in range(10)]
    assert np.median(errors) <= BODY_NOISY_ANGLE_RMS_DEG


# -- bad input ------------------------------------------------------------------------------


def test_nan_points_are_rejected_with_the_argument_named() -> None:
    points = np.zeros((5, 3))
    points[2, 1] = np.nan
    with pytest.raises(InvalidInputError, match="points"):
        fit_body(MODEL, [BodyObservations(points=points)])


@pytest.mark.parametrize(
    "frames, match",
    [
        ([], "frames"),
        ([BodyObservations()], "observations"),
        ([BodyObservations(points=np.zeros((4, 2)))], r"points must have shape \(N, 3\)"),
        ([BodyObservations(origins=np.zeros((2, 3)), directions=np.zeros((2, 3)))], "direction"),
        ([BodyObservations(origins=np.zeros((2, 3)), directions=np.ones((3, 3)))], "as many rows"),
        ([BodyObservations(points=np.zeros((1, 3)), joints={"tail": [0, 0, 0]})], "tail"),
        ([BodyObservations(masks=[np.zeros((4, 4))])], "camera"),
    ],
)
def test_malformed_observations_raise(frames, match: str) -> None:
    with pytest.raises(InvalidInputError, match=match):
        fit_body(MODEL, frames)


def test_bad_options_raise() -> None:
    frame = [BodyObservations(points=np.zeros((3, 3)))]
    with pytest.raises(InvalidInputError, match="sigma_point"):
        fit_body(MODEL, frame, sigma_point=0.0)
    with pytest.raises(InvalidInputError, match="residual"):
        fit_body(MODEL, frame, residual="distance")
    with pytest.raises(InvalidInputError, match="init"):
        fit_body(MODEL, frame, init=[MODEL.rest_state()] * 2)


def test_missing_rays_and_unobserved_parts_are_reported_not_raised() -> None:
    """Rays that miss the model are dropped as outliers; parts without observations keep
    their initial shape and are listed."""
    state = MODEL.rest_state(position=(0, 0, 0.95))
    points = MODEL.skin_points(state, 1500, seed=3, spacing=0.015)
    _, origins = MODEL.pose(state)
    head = MODEL.part_names.index("head")
    keep = np.linalg.norm(points - origins[head], axis=1) > 0.3  # nothing on the head
    far = np.tile([[5.0, 5.0, 5.0]], (20, 1))
    directions = np.tile([[1.0, 0.0, 0.0]], (20, 1))
    fit = fit_body(MODEL, [BodyObservations(points=points[keep], origins=far, directions=directions)], init=state)
    assert not fit.ray_inlier.any()
    assert "head" in fit.unobserved_parts
    # only the far tails of the head's balls reach other parts' points
    np.testing.assert_allclose(fit.shape[4 * head : 4 * head + 4], [1.0, 1.0, 1.0, 1.0], atol=1e-6)
    assert np.isfinite(fit.motion).all()


def test_tied_shape_groups_fit_one_coefficient_per_group() -> None:
    """Mirrored groups give a left part and its right twin one shape, within the bounds."""
    sc = scene(MODEL, 2, n_cameras=6)
    groups = MODEL.mirrored_shape_groups()
    assert groups.max() + 1 == MODEL.n_shape - 24  # six limb parts per side, four coefficients each
    lower, upper = np.full(MODEL.n_shape, 0.9), np.full(MODEL.n_shape, 1.2)
    init = perturbed(MODEL, sc.truth, np.random.default_rng(7))
    fit = fit_body(MODEL, [BodyObservations(points=sc.points)], init=init, shape_groups=groups, shape_bounds=(lower, upper), max_iterations=30)
    for g in range(groups.max() + 1):
        assert np.ptp(fit.shape[groups == g]) == 0.0
    assert ((fit.shape >= 0.9) & (fit.shape <= 1.2)).all()
    names = MODEL.part_names
    left, right = names.index("l_shin"), names.index("r_shin")
    assert np.array_equal(fit.shape[4 * left : 4 * left + 4], fit.shape[4 * right : 4 * right + 4])
    # tied coefficients that sit in the data's reach: near the mean of the twins' truths
    mean = 0.5 * (sc.truth.shape[4 * left] + sc.truth.shape[4 * right])
    assert abs(fit.shape[4 * left] - mean) < 0.06


@pytest.mark.parametrize(
    "groups, bounds, match",
    [
        (np.arange(MODEL.n_shape) + 1, None, "shape_groups"),
        (np.zeros(MODEL.n_shape - 1, dtype=int), None, "shape_groups"),
        (None, (np.full(MODEL.n_shape, 1.2), np.full(MODEL.n_shape, 1.0)), "shape_bounds"),
        (None, (np.zeros(MODEL.n_shape), np.ones(MODEL.n_shape)), "shape_bounds"),
    ],
)
def test_bad_shape_groups_and_bounds_raise(groups, bounds, match: str) -> None:
    sc = scene(MODEL, 1, n_points=200)
    with pytest.raises(InvalidInputError, match=match):
        fit_body(MODEL, [BodyObservations(points=sc.points)], shape_groups=groups, shape_bounds=bounds, max_iterations=2)


def test_elliptic_and_tapered_parts_recovered_with_width_depth_and_taper_apart() -> None:
    """A body whose limbs' sections are wider than deep (or deeper than wide) and taper
    more or less than described: length, width, depth and taper come back apart (a single
    width for both cross axes, or no taper, cannot express it)."""
    rng = np.random.default_rng(5)
    base = scene(MODEL, 4, n_points=10, n_cameras=8)
    shape = np.ones(MODEL.n_shape)
    for name, (width, depth, taper) in {"l_shin": (1.12, 0.9, 0.75), "r_thigh": (0.9, 1.1, 1.3), "chest": (1.05, 0.92, 1.15)}.items():
        b = MODEL.part_names.index(name)
        shape[4 * b + 1 : 4 * b + 4] = width, depth, taper
    truth = base.truth.replace(shape=shape)
    points = MODEL.skin_points(truth, 2500, seed=5, spacing=0.015)
    masks = [MODEL.silhouette(truth, c) for c in base.cameras]
    init = perturbed(MODEL, truth, rng)
    fit = fit_body(MODEL, [BodyObservations(points=points, masks=masks)], cameras=base.cameras, init=init, sigma_ray=0.3)
    assert angle_rms_degrees(MODEL, fit.motion[0], truth.motion) <= BODY_ANGLE_RMS_DEG
    assert shape_error(fit.shape, truth.shape) <= BODY_SHAPE_RTOL


def test_shape_prior_shrinks_towards_the_described_part_and_vanishes_when_wide() -> None:
    """``sigma_shape``: a Gaussian prior about 1 on each shape coefficient. Tiny, it holds
    the shape at the described part; wide, the fit is the fit without it; in between,
    every coefficient the data moved lies between 1 and where the data alone put it."""
    base = scene(MODEL, 3, n_points=10, n_cameras=8)
    shape = np.ones(MODEL.n_shape)
    for name, length, width in (("l_shin", 1.12, 1.1), ("r_forearm", 0.9, 1.08), ("chest", 1.06, 0.94)):
        b = MODEL.part_names.index(name)
        shape[4 * b : 4 * b + 2] = length, width
    truth = base.truth.replace(shape=shape)
    points = MODEL.skin_points(truth, 2500, seed=3, spacing=0.015)
    frames = [BodyObservations(points=points)]
    init = truth.replace(shape=np.ones(MODEL.n_shape))
    free = fit_body(MODEL, frames, init=init, max_iterations=60)
    assert shape_error(free.shape, truth.shape) <= BODY_SHAPE_RTOL
    wide = fit_body(MODEL, frames, init=init, max_iterations=60, sigma_shape=1e4)
    np.testing.assert_allclose(wide.shape, free.shape, atol=1e-4)
    held = fit_body(MODEL, frames, init=init, max_iterations=60, sigma_shape=1e-5)
    np.testing.assert_allclose(held.shape, 1.0, atol=1e-3)
    mid = fit_body(MODEL, frames, init=init, max_iterations=60, sigma_shape=0.03)
    moved = np.abs(free.shape - 1.0) > 0.03
    assert moved.sum() >= 6
    assert (np.abs(mid.shape[moved] - 1.0) < np.abs(free.shape[moved] - 1.0)).all()
    assert (np.sign(mid.shape[moved] - 1.0) == np.sign(free.shape[moved] - 1.0)).all()
    with pytest.raises(InvalidInputError, match="sigma_shape"):
        fit_body(MODEL, frames, sigma_shape=0.0)
