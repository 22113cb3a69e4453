"""The body fit (sparse Levenberg-Marquardt) against scipy.optimize.least_squares."""

from __future__ import annotations

from typing import Any

import numpy as np

from peer_cases._common import _compare


def _body_problem(n_points: int = 5000, rays_per_view: int = 250):
    """The default human in a random pose: skin points, 8 silhouettes' outline rays, and a
    start 8 degrees / 3 cm / unit shape away (as tests/test_body_fit.py)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
    from body_scenes import perturbed, random_state, z_up_cameras

    from elastocap.body import BodyModel, silhouette_rays

    model = BodyModel.default_human()
    rng = np.random.default_rng(4)
    truth = random_state(model, rng)
    points = model.skin_points(truth, n_points, seed=4, spacing=0.015)
    cameras = z_up_cameras(8)
    rays = [silhouette_rays(model.silhouette(truth, c), c, max_rays=rays_per_view, seed=k) for k, c in enumerate(cameras)]
    origins = np.ascontiguousarray(np.concatenate([o for o, _ in rays]))
    directions = np.ascontiguousarray(np.concatenate([d for _, d in rays]))
    return model, truth, perturbed(model, truth, rng), points, origins, directions


def body_cases(repeats: int) -> list[dict[str, Any]]:
    """Fit of the body model (one frame, shape and motion) to 5,000 skin points and 8 x 250
    silhouette rays, to convergence: elastocap.fit_body (sparse LM, analytic Jacobian) vs
    scipy.optimize.least_squares(method="trf", jac_sparsity=...) on the same weighted log
    residuals, evaluated by elastocap's field and ray search (numpy arrays in and out) with
    scipy's finite-difference Jacobian. Both final costs are measured with the same numpy
    cost function; `ratio` = scipy time / ours."""
    from scipy.optimize import least_squares
    from scipy.sparse import csr_matrix

    from elastocap.body import BodyObservations, BodyState, fit_body

    model, truth, init, points, origins, directions = _body_problem()
    eps, level, sigma = 0.01, 0.5, 0.05
    n_motion = model.n_motion

    def residuals(x: np.ndarray) -> np.ndarray:
        state = BodyState(x[n_motion:], x[:n_motion])
        f_points = model.field(points, state)[0]
        f_rays = model.ray_maxima(origins, directions, state)["values"]
        f = np.concatenate([f_points, f_rays])
        return (level + eps) * np.log((f + eps) / (level + eps)) / sigma

    x0 = np.concatenate([init.motion, init.shape])
    pattern = np.concatenate(
        [model._core.jacobian(init.shape, init.motion, points, False)[1], model.ray_maxima(origins, directions, init)["jacobian"]]
    ) != 0
    lower = np.concatenate([model.lower, np.full(model.n_shape, 0.5)])
    upper = np.concatenate([model.upper, np.full(model.n_shape, 2.0)])

    def ours() -> np.ndarray:
        fit = fit_body(model, [BodyObservations(points=points, origins=origins, directions=directions)], init=init, outlier_distance=1.0)
        return np.concatenate([fit.motion[0], fit.shape])

    def peer() -> np.ndarray:
        return least_squares(residuals, x0, method="trf", jac_sparsity=csr_matrix(pattern), bounds=(lower, upper), x_scale="jac").x

    row = _compare("body_fit_5k_points_8x250_rays", len(points) + len(origins), ours, "scipy least_squares trf + jac_sparsity", peer, max(1, repeats // 3))
    x_ours, x_peer = ours(), peer()
    row["ours_cost"] = float(0.5 * np.sum(residuals(x_ours) ** 2))
    row["peer_cost"] = float(0.5 * np.sum(residuals(x_peer) ** 2))
    row["ours_angle_rms_deg"] = float(np.degrees(np.sqrt(np.mean((x_ours[6:n_motion] - truth.motion[6:]) ** 2))))
    row["peer_angle_rms_deg"] = float(np.degrees(np.sqrt(np.mean((x_peer[6:n_motion] - truth.motion[6:]) ** 2))))
    return [row]
