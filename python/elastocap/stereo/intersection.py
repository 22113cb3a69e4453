"""Forward intersection (SPEC 7): the world point that 2..N image observations of it (rays
of calibrated cameras) determine, with its covariance, by weighted least squares through
elastocap's full camera model (distortion and skew), and blunder rejection by normalised
residuals (Baarda's data snooping).

Every step is vectorised over points; the only Python loops run over cameras, iterations and
rejection rounds.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_float_array, as_positive
from elastocap.cameras import Camera
from elastocap.cameras.distortion import distort

__all__ = ["Intersection", "intersect", "match_observations"]

# Complex-step differentiation of the (rational, polynomial) lens model: derivatives to
# rounding level, with no cancellation whatever the step.
_COMPLEX_STEP = 1e-30


class Intersection(NamedTuple):
    """Result of :func:`intersect` for N points seen by C cameras.

    Attributes
    ----------
    points : (N, 3) float64
        World coordinates (world units). NaN where fewer than two views were usable.
    covariance : (N, 3, 3) float64
        Covariance of ``points`` propagated from the observations' covariance (world units
        squared): ``(J^T Sigma^-1 J)^-1`` with ``J`` the Jacobian of the projections at the
        solution. With no observation covariance given, ``Sigma = sigma^2 I``.
    residuals : (N, C, 2) float64
        Observation minus projection of ``points``, pixels; NaN for views not used.
    normalised : (N, C) float64
        Per view the larger of its two normalised residuals ``|r_i| / sqrt(Q_rr,ii)`` (``Q_rr``
        the residuals' covariance), at the last solution the view took part in; NaN for views
        that were never observed or where the redundancy is zero (two views: both
        coordinates of the residual are then fixed by one number, so a blunder cannot be
        located).
    used : (N, C) bool
        The views that entered the final solution (observed and not rejected).
    sigma0 : (N,) float64
        A posteriori standard deviation of unit weight, ``sqrt(r^T Sigma^-1 r / (2 n - 3))``
        over the ``n`` used views; NaN with redundancy 0. Near 1 when the given covariance
        is right.
    valid : (N,) bool
        At least two views used, in front of every used camera, Gauss-Newton converged.
    """

    points: NDArray[np.float64]
    covariance: NDArray[np.float64]
    residuals: NDArray[np.float64]
    normalised: NDArray[np.float64]
    used: NDArray[np.bool_]
    sigma0: NDArray[np.float64]
    valid: NDArray[np.bool_]


def intersect(
    cameras: Sequence[Camera],
    uv: Any,
    *,
    covariance: Any = None,
    sigma: float = 1.0,
    reject: bool = True,
    critical: float = 4.0,
    max_iterations: int = 20,
    tolerance: float = 1e-12,
) -> Intersection:
    """Intersect the rays of 2..C views of N points by weighted least squares.

    Parameters
    ----------
    cameras : sequence of C :class:`~elastocap.cameras.Camera`
        The calibrated cameras (distortion and skew are used as modelled).
    uv : (N, C, 2) array_like of float
        Observed pixels ``(u, v)`` of each point in each camera; NaN rows for views without
        an observation.
    covariance : array_like of float, optional, keyword-only
        Covariance of the observations, pixels squared: ``(N, 2C, 2C)`` joint (view ``c`` at
        rows ``2c, 2c + 1``; the cross terms between views, e.g. from
        :meth:`~elastocap.stereo.Matches.position_covariance` via
        :func:`match_observations`, are used), or ``(N, C, 2, 2)`` per view. Entries of
        unobserved views are ignored. Default: ``sigma^2 I``.
    sigma : float, optional, keyword-only
        Standard deviation of every coordinate when ``covariance`` is not given, pixels.
        Default 1.
    reject : bool, optional, keyword-only
        Reject blunders: while a point keeps three or more views and its largest normalised
        residual exceeds ``critical``, drop the view that holds it and solve again.
        Default True.
    critical : float, optional, keyword-only
        Critical value of the normalised residual (a standard normal under no blunder).
        Default 4 (a false rejection in about 6e-5 of the coordinates).
    max_iterations : int, optional, keyword-only
        Gauss-Newton iterations per solve. Default 20.
    tolerance : float, optional, keyword-only
        Stop when every update is shorter than this times the distance to the farthest
        camera centre. Default 1e-12.

    Returns
    -------
    Intersection

    Raises
    ------
    InvalidInputError
        Fewer than two cameras, ``uv`` or ``covariance`` of the wrong shape, an infinite
        observation, a covariance that is not finite, or options out of range.

    Notes
    -----
    The start is the point closest to all rays in the least-squares sense (the linear
    midpoint of the undistorted rays). Gauss-Newton then minimises ``r^T Sigma^-1 r`` with
    ``r = uv - project(X)``, the projection being the camera model of SPEC 1 (distortion,
    skew); its Jacobian is analytic apart from the lens model's, taken by complex step
    (exact to rounding). Without noise the rays meet and the result is that meeting point,
    whatever the weights. The residuals' covariance is ``Q_rr = Sigma - J Sigma_X J^T``.
    Given one covariance per view (``(N, C, 2, 2)``) the weights are block diagonal and
    are solved as such, point by point in the core (:mod:`elastocap.stereo.intersection_blocks`:
    the same solution to rounding, ~80x fewer CPU seconds than this dense path on the
    tracker's frames; the projection's Jacobian there is analytic).
    """
    cams = _cameras(cameras)
    c = len(cams)
    obs = as_float_array("uv", uv)
    if obs.ndim != 3 or obs.shape[1:] != (c, 2):
        raise InvalidInputError(f"uv must have shape (N, {c}, 2) for {c} cameras, got {obs.shape}")
    if np.isinf(obs).any():
        raise InvalidInputError("uv holds infinity (use NaN for a missing view)")
    n = obs.shape[0]
    sigma_ = as_positive("sigma", sigma)
    critical_ = as_positive("critical", critical)
    iterations = as_count("max_iterations", max_iterations)
    tol = as_positive("tolerance", tolerance)
    scale = max(float(np.max(np.linalg.norm(np.array([cam.center for cam in cams]), axis=1))), 1.0)
    if covariance is not None and np.shape(covariance) == (n, c, 2, 2):
        # One covariance per view: the weights are block diagonal, solved as such.
        from elastocap.stereo.intersection_blocks import intersect_blocks

        return intersect_blocks(cams, obs, as_float_array("covariance", covariance), reject=reject, critical=critical_,
                                iterations=iterations, step_tolerance=tol * scale)
    cov = _covariance(covariance, n, c, sigma_)

    blocks = cov.reshape(n, c, 2, c, 2)[:, np.arange(c), :, np.arange(c), :]  # (C, N, 2, 2)
    observed: NDArray[np.bool_] = np.asarray(np.isfinite(obs).all(axis=2) & np.isfinite(blocks).all(axis=(2, 3)).T)
    used = observed.copy()
    normalised = np.full((n, c), np.nan)
    while True:
        x, weight, jac, resid, converged = _solve(cams, obs, cov, used, iterations, tol * scale)
        info = _normal(jac, weight)
        point_cov = _inverse(info)
        w = _normalised_residuals(cov, jac, point_cov, resid, used)
        normalised = np.where(np.isfinite(w), w, normalised)
        worst = np.where(used & np.isfinite(w), w, -np.inf)
        drop = reject & (used.sum(axis=1) >= 3) & (worst.max(axis=1) > critical_)
        if not drop.any():
            break
        used[np.flatnonzero(drop), np.argmax(worst[drop], axis=1)] = False

    quad = np.einsum("ni,nij,nj->n", resid, weight, resid)
    return _result(cams, x, point_cov, resid.reshape(n, c, 2), normalised, used, quad, converged)


def _result(cams: list[Camera], x: NDArray[np.float64], point_cov: NDArray[np.float64], resid: NDArray[np.float64],
            normalised: NDArray[np.float64], used: NDArray[np.bool_], quad: NDArray[np.float64],
            converged: NDArray[np.bool_]) -> Intersection:
    """The :class:`Intersection` of the solved points ``x`` (N, 3) with their covariance, the
    residuals (N, C, 2) and weighted squared residual sums ``quad`` (N,) at the solution:
    sigma0 from the redundancy, validity (two views, converged, in front of every used
    camera), NaN where fewer than two views were used."""
    count = used.sum(axis=1)
    redundancy = 2 * count - 3
    with np.errstate(invalid="ignore", divide="ignore"):
        sigma0 = np.where(redundancy > 0, np.sqrt(quad / np.maximum(redundancy, 1)), np.nan)
    depth_ok = np.ones(len(x), bool)
    for k, cam in enumerate(cams):
        depth = cam.to_camera(np.nan_to_num(x))[:, 2]
        depth_ok &= ~used[:, k] | (depth > 0)
    valid = (count >= 2) & converged & depth_ok & np.isfinite(x).all(axis=1)
    x[count < 2] = np.nan
    point_cov[count < 2] = np.nan
    residuals = np.where(used[..., None], resid, np.nan)
    return Intersection(
        points=x,
        covariance=point_cov,
        residuals=residuals,
        normalised=normalised,
        used=used,
        sigma0=sigma0,
        valid=valid,
    )


def match_observations(
    template_points: Any, positions: Any, position_covariance: Any, *, template_sigma: float | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Observations for :func:`intersect` from least-squares matches: the template camera
    first, then the S search cameras.

    Parameters
    ----------
    template_points : (N, 2) array_like of float
        The points matched, in the template image (pixels).
    positions : (N, S, 2) array_like of float
        :attr:`~elastocap.stereo.Matches.positions`; NaN them (or pass them as NaN) where
        the match failed.
    position_covariance : (N, 2S, 2S) array_like of float
        :meth:`~elastocap.stereo.Matches.position_covariance`.
    template_sigma : float, optional, keyword-only
        Standard deviation given to the template points, pixels. LSM estimates the search
        positions relative to a fixed template patch, so the matches' covariance already
        holds both images' noise and the template point is exact; it gets a small variance
        so that the weight matrix stays finite. Default: 1e-3 times the smallest matched
        standard deviation of the point.

    Returns
    -------
    uv : (N, 1 + S, 2) float64
    covariance : (N, 2 + 2S, 2 + 2S) float64
    """
    tp = as_float_array("template_points", template_points)
    pos = as_float_array("positions", positions)
    pc = as_float_array("position_covariance", position_covariance)
    if tp.ndim != 2 or tp.shape[1] != 2:
        raise InvalidInputError(f"template_points must have shape (N, 2), got {tp.shape}")
    n = tp.shape[0]
    if pos.ndim != 3 or pos.shape[0] != n or pos.shape[2] != 2:
        raise InvalidInputError(f"positions must have shape ({n}, S, 2), got {pos.shape}")
    s = pos.shape[1]
    if pc.shape != (n, 2 * s, 2 * s):
        raise InvalidInputError(f"position_covariance must have shape ({n}, {2 * s}, {2 * s}), got {pc.shape}")
    uv = np.concatenate([tp[:, None, :], pos], axis=1)
    cov = np.zeros((n, 2 + 2 * s, 2 + 2 * s))
    cov[:, 2:, 2:] = pc
    if template_sigma is None:
        diag = np.diagonal(pc, axis1=1, axis2=2)
        with np.errstate(invalid="ignore"):
            smallest = np.sqrt(np.nanmin(np.where(diag > 0, diag, np.nan), axis=1, initial=np.inf))
        variance = np.where(np.isfinite(smallest), (1e-3 * smallest) ** 2, 1e-6)
    else:
        variance = np.full(n, as_positive("template_sigma", template_sigma) ** 2)
    cov[:, 0, 0] = cov[:, 1, 1] = variance
    return uv, cov


# ------------------------------------------------------------------------------------------
# least squares
# ------------------------------------------------------------------------------------------


def _solve(
    cams: list[Camera],
    obs: NDArray[np.float64],
    cov: NDArray[np.float64],
    used: NDArray[np.bool_],
    iterations: int,
    step_tolerance: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Gauss-Newton from the linear midpoint; returns the point, the weight matrix, the
    Jacobian (N, 2C, 3) and the residual (N, 2C) at the solution (zero rows for views not
    used), and which points converged."""
    n, c, _ = obs.shape
    weight = _weights(cov, used)
    x = _midpoint(cams, obs, used)
    converged = np.zeros(n, bool)
    mask = np.repeat(used, 2, axis=1)
    flat = np.nan_to_num(obs.reshape(n, 2 * c))
    for _ in range(iterations):
        projected, jac = _project(cams, x)
        resid = np.where(mask, flat - projected, 0.0)
        jac = np.where(mask[..., None], jac, 0.0)
        info = _normal(jac, weight)
        gradient = np.einsum("nki,nkl,nl->ni", jac, weight, resid)
        step = _solve3(info, gradient)
        x = x + step
        converged = np.linalg.norm(step, axis=1) <= step_tolerance
        if converged[used.sum(axis=1) >= 2].all():
            break
    projected, jac = _project(cams, x)
    resid = np.where(mask, flat - projected, 0.0)
    jac = np.where(mask[..., None], jac, 0.0)
    return x, weight, jac, resid, converged


def _midpoint(cams: list[Camera], obs: NDArray[np.float64], used: NDArray[np.bool_]) -> NDArray[np.float64]:
    """The point nearest to the used rays: ``sum_v (I - d d^T) X = sum_v (I - d d^T) C``."""
    n = obs.shape[0]
    lhs = np.zeros((n, 3, 3))
    rhs = np.zeros((n, 3))
    for k, cam in enumerate(cams):
        origin, direction = cam.rays(np.nan_to_num(obs[:, k]))
        ok = used[:, k] & np.isfinite(direction).all(axis=1)
        direction = np.where(ok[:, None], direction, 0.0)
        proj = np.eye(3) - direction[:, :, None] * direction[:, None, :]
        proj[~ok] = 0.0
        lhs += proj
        rhs += np.einsum("nij,nj->ni", proj, origin)
    return _solve3(lhs, rhs)


def _project(cams: list[Camera], x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixels (N, 2C) of ``x`` in every camera and their Jacobian (N, 2C, 3) w.r.t. ``x``."""
    n = x.shape[0]
    uv = np.empty((n, 2 * len(cams)))
    jac = np.empty((n, 2 * len(cams), 3))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for k, cam in enumerate(cams):
            xc = x @ cam.R.T + cam.t
            z = xc[:, 2]
            ab = xc[:, :2] / z[:, None]
            # d(a, b) / d(x_cam)
            dab = np.zeros((n, 2, 3))
            dab[:, 0, 0] = dab[:, 1, 1] = 1.0 / z
            dab[:, :, 2] = -ab / z[:, None]
            lens = np.empty((n, 2, 2))
            for j in range(2):
                probe = ab.astype(complex)
                probe[:, j] += 1j * _COMPLEX_STEP
                lens[:, :, j] = distort(probe, cam.dist).imag / _COMPLEX_STEP
            k2 = cam.K[:2, :2]
            distorted = distort(ab, cam.dist)
            uv[:, 2 * k : 2 * k + 2] = distorted @ k2.T + cam.K[:2, 2]
            jac[:, 2 * k : 2 * k + 2] = k2 @ lens @ dab @ cam.R
    return uv, jac


def _weights(cov: NDArray[np.float64], used: NDArray[np.bool_]) -> NDArray[np.float64]:
    """``Sigma^-1`` over the used views (the marginal covariance of those views inverted),
    zero for the others."""
    n, m, _ = cov.shape
    mask = np.repeat(used, 2, axis=1)
    both = mask[:, :, None] & mask[:, None, :]
    sub = np.where(both, cov, 0.0)
    idx = np.arange(m)
    sub[:, idx, idx] = np.where(mask, sub[:, idx, idx], 1.0)
    with np.errstate(invalid="ignore"):
        inv = np.linalg.inv(sub)
    return np.where(both, inv, 0.0)


def _normal(jac: NDArray[np.float64], weight: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.einsum("nki,nkl,nlj->nij", jac, weight, jac)


def _solve3(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Batched 3x3 solves; NaN for singular systems (fewer than two rays)."""
    ok = _regular(a)
    out = np.full(b.shape, np.nan)
    if ok.any():
        out[ok] = np.linalg.solve(a[ok], b[ok][..., None])[..., 0]
    return out


def _regular(a: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which of the batched 3x3 matrices are finite and non-singular."""
    ok: NDArray[np.bool_] = np.asarray(np.isfinite(a).all(axis=(1, 2)))
    ok[ok] = np.abs(np.linalg.det(a[ok])) > 0
    return ok


# Smallest eigenvalue of a normal matrix kept, relative to its largest, when it is inverted
# into a covariance: rays near parallel leave one direction almost unconstrained, and the
# plain inverse of such a matrix is not symmetric positive definite in floating point (the
# tracker wrote one with an eigenvalue of -2.8e-3 m^2: branch trackfit4, seed 4). Clamped,
# that direction's variance is 1e12 times the best one's: no weight, but a covariance.
_CONDITION = 1e-12


def _inverse(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Batched inverses (N, 3, 3) of symmetric positive semi-definite normal matrices ``a``,
    symmetric positive definite by construction: ``V diag(1 / max(w, c w_max)) V^T`` from
    the eigen decomposition of the symmetric part, ``c`` = ``_CONDITION``; NaN where ``a``
    is not finite or singular (fewer than two rays)."""
    ok = _regular(a)
    out = np.full(a.shape, np.nan)
    if ok.any():
        sym = 0.5 * (a[ok] + a[ok].transpose(0, 2, 1))
        w, v = np.linalg.eigh(sym)
        top = w[:, -1:]
        ok[np.flatnonzero(ok)[top[:, 0] <= 0]] = False
        keep = top[:, 0] > 0
        w, v, top = w[keep], v[keep], top[keep]
        w = np.maximum(w, _CONDITION * top)
        inv = np.einsum("nik,nk,njk->nij", v, 1.0 / w, v)
        out[ok] = 0.5 * (inv + inv.transpose(0, 2, 1))  # exactly symmetric
    return out


def _normalised_residuals(
    cov: NDArray[np.float64],
    jac: NDArray[np.float64],
    point_cov: NDArray[np.float64],
    resid: NDArray[np.float64],
    used: NDArray[np.bool_],
) -> NDArray[np.float64]:
    """Per view, the larger of ``|r_i| / sqrt(Q_rr,ii)`` over its two coordinates; NaN for
    views not used and where the redundancy is zero."""
    n, c = used.shape
    cov_diag = np.diagonal(cov, axis1=1, axis2=2)
    fitted = np.einsum("nki,nij,nkj->nk", jac, point_cov, jac)
    q = cov_diag - fitted
    mask = np.repeat(used, 2, axis=1)
    scale = np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))
    # Q_rr,ii vanishes (to rounding) where the view's residual is fixed by the geometry.
    determined = q > 1e-9 * scale**2
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(mask & determined, np.abs(resid) / np.sqrt(np.where(determined, q, 1.0)), np.nan)
    w = w.reshape(n, c, 2)
    redundant = (used.sum(axis=1) >= 3)[:, None]
    both_nan = np.isnan(w).all(axis=2)
    best = np.where(both_nan, np.nan, np.nanmax(np.where(np.isnan(w), -np.inf, w), axis=2))
    return np.where(redundant & used, best, np.nan)


# ------------------------------------------------------------------------------------------
# validation
# ------------------------------------------------------------------------------------------


def _cameras(cameras: Any) -> list[Camera]:
    if not isinstance(cameras, Sequence) or isinstance(cameras, (str, bytes)):
        raise InvalidInputError(f"cameras must be a sequence of Camera, got {type(cameras).__name__}")
    cams = list(cameras)
    if len(cams) < 2:
        raise InvalidInputError(f"cameras must hold at least 2 cameras, got {len(cams)}")
    for i, cam in enumerate(cams):
        if not isinstance(cam, Camera):
            raise InvalidInputError(f"cameras[{i}] must be a Camera, got {type(cam).__name__}")
    return cams


def _covariance(covariance: Any, n: int, c: int, sigma: float) -> NDArray[np.float64]:
    if covariance is None:
        return np.broadcast_to(np.eye(2 * c) * sigma**2, (n, 2 * c, 2 * c)).copy()
    cov = as_float_array("covariance", covariance)
    if cov.shape == (n, c, 2, 2):
        full = np.zeros((n, 2 * c, 2 * c))
        for k in range(c):
            full[:, 2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = cov[:, k]
        cov = full
    elif cov.shape != (n, 2 * c, 2 * c):
        raise InvalidInputError(
            f"covariance must have shape ({n}, {2 * c}, {2 * c}) or ({n}, {c}, 2, 2), got {cov.shape}"
        )
    return cov
