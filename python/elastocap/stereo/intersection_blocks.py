"""Forward intersection with one 2x2 covariance per view (SPEC 7; the tracker's case):
:func:`elastocap.stereo.intersect` given ``covariance`` of shape ``(N, C, 2, 2)``.

The same weighted least squares as the joint-covariance path of
:mod:`elastocap.stereo.intersection` (Gauss-Newton from the rays' midpoint through the full
camera model, covariance from the normal matrix, blunders rejected by normalised residuals),
with the weight matrix kept as its C diagonal blocks: the normal matrix is a sum over views
of ``J_c^T W_c J_c`` (3x2 @ 2x2 @ 2x3) instead of a product through a dense ``2C x 2C``
matrix that is zero off its blocks, and each rejection round solves again only the points
that dropped a view. On the tracker's frame (2,500 points, 8 cameras, ~1.7 views each)
this is ~7x fewer CPU seconds than the dense path (benches/README.md, "speed1"); the
results agree with it to rounding (tests/test_intersection.py).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from elastocap.cameras import Camera

if TYPE_CHECKING:
    from elastocap.stereo.intersection import Intersection

__all__ = ["intersect_blocks"]


def intersect_blocks(cams: list[Camera], obs: NDArray[np.float64], cov: NDArray[np.float64], *, reject: bool,
                     critical: float, iterations: int, step_tolerance: float) -> Intersection:
    """The :class:`~elastocap.stereo.Intersection` of ``obs`` (N, C, 2, pixels; NaN where
    not observed) with per-view covariances ``cov`` (N, C, 2, 2, pixels squared; ignored
    where not observed), checked by the caller; ``critical``, ``iterations`` as in
    :func:`~elastocap.stereo.intersect`, ``step_tolerance`` in world units."""
    from elastocap.stereo.intersection import _inverse, _result

    n, c = obs.shape[:2]
    used: NDArray[np.bool_] = np.asarray(np.isfinite(obs).all(axis=2) & np.isfinite(cov).all(axis=(2, 3)))
    normalised = np.full((n, c), np.nan)
    x = np.full((n, 3), np.nan)
    point_cov = np.full((n, 3, 3), np.nan)
    weight = np.zeros((n, c, 2, 2))
    resid = np.zeros((n, c, 2))
    converged = np.zeros(n, bool)
    todo = np.arange(n)
    while todo.size:
        xs, ws, jac, rs, conv = _solve(cams, obs[todo], cov[todo], used[todo], iterations, step_tolerance)
        x[todo], weight[todo], resid[todo], converged[todo] = xs, ws, rs, conv
        pc = _inverse(_normal(jac, ws))
        point_cov[todo] = pc
        w = _normalised_residuals(cov[todo], jac, pc, rs, used[todo])
        normalised[todo] = np.where(np.isfinite(w), w, normalised[todo])
        worst = np.where(used[todo] & np.isfinite(w), w, -np.inf)
        drop = reject & (used[todo].sum(axis=1) >= 3) & (worst.max(axis=1) > critical)
        if not drop.any():
            break
        used[todo[drop], np.argmax(worst[drop], axis=1)] = False
        todo = todo[drop]

    quad = np.einsum("nca,ncab,ncb->n", resid, weight, resid)
    return _result(cams, x, point_cov, resid, normalised, used, quad, converged)


def _solve(cams: list[Camera], obs: NDArray[np.float64], cov: NDArray[np.float64], used: NDArray[np.bool_],
           iterations: int, step_tolerance: float) -> tuple[NDArray[Any], ...]:
    """Gauss-Newton from the linear midpoint over the used views; returns the point (M, 3),
    the weights (M, C, 2, 2; zero for views not used), the Jacobian (M, C, 2, 3) and the
    residual (M, C, 2) at the solution (zero for views not used), and which converged."""
    from elastocap.stereo.intersection import _solve3

    m, c = used.shape
    weight = np.zeros((m, c, 2, 2))
    if used.any():
        weight[used] = np.linalg.inv(cov[used])
    x = _midpoint(cams, obs, used)
    converged = np.zeros(m, bool)
    flat = np.nan_to_num(obs)
    two = used.sum(axis=1) >= 2
    for _ in range(iterations):
        jac, resid = _linearised(cams, x, flat, used)
        jtw = np.swapaxes(jac, 2, 3) @ weight  # (M, C, 3, 2)
        info = (jtw @ jac).sum(axis=1)
        gradient = (jtw @ resid[..., None]).sum(axis=1)[..., 0]
        step = _solve3(info, gradient)
        x = x + step
        converged = np.linalg.norm(step, axis=1) <= step_tolerance
        if converged[two].all():
            break
    jac, resid = _linearised(cams, x, flat, used)
    return x, weight, jac, resid, converged


def _midpoint(cams: list[Camera], obs: NDArray[np.float64], used: NDArray[np.bool_]) -> NDArray[np.float64]:
    """The point nearest to the used rays (as :func:`elastocap.stereo.intersection._midpoint`),
    each camera's rays cast only through the views it holds."""
    from elastocap.stereo.intersection import _solve3

    m = obs.shape[0]
    lhs = np.zeros((m, 3, 3))
    rhs = np.zeros((m, 3))
    for k, cam in enumerate(cams):
        rows = np.flatnonzero(used[:, k])
        if rows.size == 0:
            continue
        origin, direction = cam.rays(obs[rows, k])
        ok: NDArray[np.bool_] = np.asarray(np.isfinite(direction).all(axis=1))
        direction = np.where(ok[:, None], direction, 0.0)
        proj = np.eye(3) - direction[:, :, None] * direction[:, None, :]
        proj[~ok] = 0.0
        lhs[rows] += proj
        rhs[rows] += np.einsum("nij,nj->ni", proj, origin)
    return _solve3(lhs, rhs)


def _linearised(cams: list[Camera], x: NDArray[np.float64], flat: NDArray[np.float64],
                used: NDArray[np.bool_]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The Jacobian (M, C, 2, 3) and residual (M, C, 2) at ``x``, zero for views not used:
    each camera projects only the points whose view it holds (a tracked point is seen by
    two or three of eight)."""
    from elastocap.stereo.intersection import _project

    m, c = used.shape
    jac = np.zeros((m, c, 2, 3))
    resid = np.zeros((m, c, 2))
    for k, cam in enumerate(cams):
        rows = np.flatnonzero(used[:, k])
        if rows.size == 0:
            continue
        projected, j = _project([cam], x[rows])
        resid[rows, k] = flat[rows, k] - projected
        jac[rows, k] = j
    return jac, resid


def _normal(jac: NDArray[np.float64], weight: NDArray[np.float64]) -> NDArray[np.float64]:
    """``sum_c J_c^T W_c J_c`` (M, 3, 3)."""
    return (np.swapaxes(jac, 2, 3) @ weight @ jac).sum(axis=1)


def _normalised_residuals(cov: NDArray[np.float64], jac: NDArray[np.float64], point_cov: NDArray[np.float64],
                          resid: NDArray[np.float64], used: NDArray[np.bool_]) -> NDArray[np.float64]:
    """As :func:`elastocap.stereo.intersection._normalised_residuals` with the covariance's
    diagonal read from its blocks."""
    m, c = used.shape
    cov_diag = np.stack([cov[..., 0, 0], cov[..., 1, 1]], axis=2)  # (M, C, 2)
    fitted = np.einsum("ncai,nij,ncaj->nca", jac, point_cov, jac)
    q = cov_diag - fitted
    scale = np.sqrt(np.abs(cov_diag))
    determined = q > 1e-9 * scale**2
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(used[..., None] & determined, np.abs(resid) / np.sqrt(np.where(determined, q, 1.0)), np.nan)
    redundant = (used.sum(axis=1) >= 3)[:, None]
    both_nan = np.isnan(w).all(axis=2)
    best = np.where(both_nan, np.nan, np.nanmax(np.where(np.isnan(w), -np.inf, w), axis=2))
    return np.where(redundant & used, best, np.nan)
