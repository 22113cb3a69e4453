"""Every analytic derivative of the body model against central finite differences (SPEC 6):
the field's gradient and Hessian in x, dF/d(state) at fixed points for every motion and
shape parameter, and the silhouette ray residual F(x*(theta), theta) including its ray
search (envelope theorem); plus the ray maximum's stationarity and optimality."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from body_scenes import random_state as scene_state
from elastocap.body import BodyModel, BodyState
from tolerances import BODY_FD_RTOL, BODY_FD_STEP, BODY_RAY_STATIONARY_ATOL

MODEL = BodyModel.default_human()
SEEDS = st.integers(min_value=0, max_value=2**32 - 1)


def random_state(rng: np.random.Generator) -> BodyState:
    """A random state whose every shape coefficient is drawn on its own (length, width,
    depth and taper apart; the scenes' states tie depth to width and hold the taper)."""
    state = scene_state(MODEL, rng)
    return state.replace(shape=rng.uniform(0.85, 1.15, MODEL.n_shape))


def assert_rows_close(analytic: np.ndarray, numeric: np.ndarray) -> None:
    """Entry-wise |a - n| <= rtol * (|n| + row scale): relative, with entries far below
    their row's largest compared at the row's scale (central differences err by rounding
    of F / h, not of the entry)."""
    scale = np.abs(numeric).max(axis=1, keepdims=True)
    bad = np.abs(analytic - numeric) > BODY_FD_RTOL * (np.abs(numeric) + scale)
    assert not bad.any(), (
        f"{bad.sum()} entries differ; worst relative "
        f"{(np.abs(analytic - numeric) / (np.abs(numeric) + scale + 1e-300)).max():.2e}"
    )


def points_near_body(state: BodyState, n: int, rng: np.random.Generator) -> np.ndarray:
    """Points around the joints, inside and outside the skin."""
    _, origins = MODEL.pose(state)
    return origins[rng.integers(0, len(origins), n)] + rng.normal(0, 0.08, (n, 3))


def state_columns(state: BodyState) -> np.ndarray:
    return np.concatenate([state.motion, state.shape])


def split(x: np.ndarray) -> BodyState:
    return BodyState(x[MODEL.n_motion :].copy(), x[: MODEL.n_motion].copy())


@settings(max_examples=8)
@given(seed=SEEDS)
def test_field_gradient_and_hessian_match_central_differences(seed: int) -> None:
    rng = np.random.default_rng(seed)
    state = random_state(rng)
    points = points_near_body(state, 200, rng)
    f, grad, hess = MODEL.field(points, state)
    h = BODY_FD_STEP
    grad_fd = np.stack(
        [(MODEL.field(points + h * e, state)[0] - MODEL.field(points - h * e, state)[0]) / (2 * h) for e in np.eye(3)],
        axis=1,
    )
    hess_fd = np.stack(
        [(MODEL.field(points + h * e, state)[1] - MODEL.field(points - h * e, state)[1]) / (2 * h) for e in np.eye(3)],
        axis=2,
    )
    keep = f > 1e-6  # far from every ball both sides are ~0
    assert_rows_close(grad[keep], grad_fd[keep])
    assert_rows_close(hess[keep].reshape(-1, 9), hess_fd[keep].reshape(-1, 9))
    np.testing.assert_allclose(hess, np.swapaxes(hess, 1, 2), rtol=0, atol=1e-9 * np.abs(hess).max())


@settings(max_examples=6)
@given(seed=SEEDS)
def test_state_jacobian_matches_central_differences(seed: int) -> None:
    rng = np.random.default_rng(seed)
    state = random_state(rng)
    points = points_near_body(state, 150, rng)
    f, jac = MODEL.jacobian(points, state)
    x = state_columns(state)
    h = BODY_FD_STEP
    numeric = np.empty_like(jac)
    for k in range(len(x)):
        step = np.zeros_like(x)
        step[k] = h
        numeric[:, k] = (MODEL.field(points, split(x + step))[0] - MODEL.field(points, split(x - step))[0]) / (2 * h)
    keep = f > 1e-6
    assert_rows_close(jac[keep], numeric[keep])
    # every parameter is exercised: each column has a non-zero entry somewhere
    assert (np.abs(jac).max(axis=0) > 0).all()


def grazing_rays(state: BodyState, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Rays from 3 m away through points around the body, in random directions."""
    targets = points_near_body(state, n, rng)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.ascontiguousarray(targets - 3.0 * d), d


@settings(max_examples=6)
@given(seed=SEEDS)
def test_ray_maximum_is_stationary_and_global(seed: int) -> None:
    rng = np.random.default_rng(seed)
    state = random_state(rng)
    origins, directions = grazing_rays(state, 120, rng)
    found = MODEL.ray_maxima(origins, directions, state)
    hit = found["hit"] & (found["values"] > 1e-3)
    _, grad, _ = MODEL.field(found["points"][hit], state)
    slope = (grad * directions[hit]).sum(axis=1)
    assert np.abs(slope).max() <= BODY_RAY_STATIONARY_ATOL
    # brute force along each ray: nothing beats the maximum found
    s = np.linspace(0.0, 6.0, 6001)
    for i in np.flatnonzero(hit)[:30]:
        samples = MODEL.field(origins[i] + s[:, None] * directions[i], state)[0]
        assert samples.max() <= found["values"][i] * (1 + 1e-12) + 1e-15


@settings(max_examples=6)
@given(seed=SEEDS)
def test_ray_residual_jacobian_matches_differences_of_the_full_search(seed: int) -> None:
    rng = np.random.default_rng(seed)
    state = random_state(rng)
    origins, directions = grazing_rays(state, 120, rng)
    found = MODEL.ray_maxima(origins, directions, state)
    # Near misses (F(x*) < 1e-3) are left out: their value sums balls within |q| <= 3.4
    # only, so dropped terms (< 1.4e-10 each) are not small relative to the value.
    keep = found["values"] > 1e-3
    x = state_columns(state)
    h = BODY_FD_STEP
    numeric = np.empty_like(found["jacobian"])
    for k in range(len(x)):
        step = np.zeros_like(x)
        step[k] = h
        plus = MODEL.ray_maxima(origins, directions, split(x + step))["values"]
        minus = MODEL.ray_maxima(origins, directions, split(x - step))["values"]
        numeric[:, k] = (plus - minus) / (2 * h)
    assert keep.sum() > 20
    assert_rows_close(found["jacobian"][keep], numeric[keep])


def test_rays_that_miss_report_no_hit_and_zero_jacobian() -> None:
    state = MODEL.rest_state()
    origins = np.array([[10.0, 10.0, 10.0], [0.0, 0.0, 0.0]])
    directions = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    found = MODEL.ray_maxima(origins, directions, state)
    assert not found["hit"][0] and found["values"][0] == 0.0
    assert (found["jacobian"][0] == 0).all()
    assert found["hit"][1] and found["values"][1] > 0.5  # straight up through the body
