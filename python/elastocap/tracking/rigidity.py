"""Reported positions pinned by their neighbours' rigid motion (issue 15, branch track11).

Most tracked positions are intersected from the two views of one narrow stereo pair (5-6
degrees apart): their depth along the pair's rays is uncertain by the disparity's error
over the angle (0.1 px of disparity is about 1 px-equivalent), and as the views' anchors are
cut again the disparity drifts. On the textured capture (seed 0, branch track11, measured
against the true surface point) 96% of the kept positions beyond 5 px-equivalents are such
two-view positions, half of them on surfaces turning away (the ray grazing the surface, so
the depth error slides the point along the surface, where no plane of its neighbours can
see it), most of them old (44% beyond 30 frames), while the 8 points tracked around them
are right (their median error 1.7 px-eq): a point's drift is its own.

A surface patch moves almost rigidly over a few centimetres, so where the point is now is
also predicted by where it was when it was seeded, moved by the rigid motion (Kabsch) of
its neighbours between that frame and now. The two estimates are combined as Gaussians:
the intersection's (its reported covariance ``S``: long along the rays) and the
prediction's (isotropic, ``sigma`` pixels at the point), so the prediction fixes the depth
and the views keep the rest::

    x' = x + S (S + P)^-1 (p - x),   S' = S - S (S + P)^-1 S,   P = (sigma pixel)^2 I

The neighbours are taken from the point's own body part as far as its trajectory tells
(branch track12): the points nearest now alone mix body parts where two meet (on the
textured capture seed 2, 215 positions the fusion broke had most of their 8 neighbours on
another part, an arm by the torso). So they are the nearest in the 6-D space of now and
the seeding frame (a part that has come close since was far then), and of those the ones
whose distance to the point has not changed by more than a few pixels since (a rigid
motion keeps distances whatever its rotation; a part sliding past does not). Against the
true surface point, kept 3-D positions beyond 5 px-equivalents, held-out seeds 8 and 9:
3.50 -> 2.77% and 2.36 -> 1.98% (nearest now -> these), true-part neighbours 2.31 / 1.32%.

The prediction is itself wrong where the neighbours' own intersections drifted (branch
track14): on seeds 0 and 2 it is farther than 5 px-equivalents from the true point for
4.2% / 5.2% of the positions it is made for (the intersection for 3.7% / 4.3%), and where
it and the views disagree across the rays by more than 3 px-eq the views are the nearer
to the truth in 73% / 68% of them. So its weight falls with the disagreement: its
covariance ``P`` is scaled by ``max(1, m^2 / g^2)``, ``m`` the Mahalanobis distance
between the two in ``S + P``, which makes the correction redescend (largest near the gate,
smaller beyond). Held-out seeds 12 and 13: 3.52 -> 2.86% and 2.14 -> 1.83% (track12's
fusion -> gated, with sd 2 px instead of 2.5). And the fusion runs twice, the second time
with the neighbours' motion fitted to their fused positions, so that a neighbour whose
depth drifted misleads its neighbours less (tuning seeds 0, 2, 3, 8, 9: 1.76 -> 1.70% and
1.81 -> 1.67%).

What the fusion leaves are mostly points that slid along the surface in both views of
their pair (branch track14), a few tenths of a pixel a frame, which no one-frame check sees:
:func:`rigid_residuals` measures each point's offset from its neighbours' rigid map since
its seeding frame across its rays, and the neighbourhood's own held-out residual to that
map, and the tracker withholds points too far off (flag SLID, ``settings.SLIDE``; branch
track17: tuning seeds 0, 2, 3, kept 3-D beyond 5 px-eq 1.45 / 1.93 / 1.27% -> 0.90 / 1.08 /
0.87%, through -1.2 / -1.0 / -0.4 points). Where the two disagree by several px-eq the
prediction itself is mostly the one wrong (its error a median 6-21 px-eq there), so a point
is withheld, never moved onto it.

Only what is reported changes: the tracker follows its points from their intersections,
and the views (so every image figure) are untouched.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from elastocap._core import rigid_fits, track_rigid_held_out
from elastocap.tracking import settings

__all__ = ["NeighbourPlan", "nanmedian_rows", "neighbour_plans", "rigid_fusion", "rigid_motions", "rigid_residuals"]


def rigid_motions(a: NDArray[np.float64], b: NDArray[np.float64],
                  weights: NDArray[np.float64] | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Batched least-squares rigid fits ``b ~ R a + t`` (Kabsch) of (M, K, 3) point sets,
    optionally weighted per point (``weights`` (M, K), non-negative with a positive sum per
    set): ``R`` (M, 3, 3) proper rotations, ``t`` (M, 3)."""
    w = np.ones(a.shape[:2]) if weights is None else weights
    # The core's batched Kabsch: the rotation nearest to H^T by a polar decomposition, not
    # an SVD per set (the tracker fits tens of thousands of 8-point sets a frame).
    r, t = rigid_fits(np.ascontiguousarray(a, dtype=np.float64), np.ascontiguousarray(b, dtype=np.float64),
                      np.ascontiguousarray(w, dtype=np.float64))
    return r, t


def rigid_fusion(x: NDArray[np.float64], covariance: NDArray[np.float64], pixel: NDArray[np.float64],
                 seeded: NDArray[np.int64], history: dict[int, NDArray[np.float64]], *, neighbours: int,
                 sigma: float, both_frames: float = 0.0, candidates: int = 0,
                 stretch: float = float("inf"), min_neighbours: int = 3,
                 gate: float | None = None, passes: int | None = None,
                 plans: list[NeighbourPlan] | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Positions ``x`` (N, 3; NaN where not tracked) with ``covariance`` (N, 3, 3) fused with
    their neighbours' rigid-motion prediction (module docstring).

    ``seeded`` (N,) the key in ``history`` of each point's seeding frame (-1: none);
    ``history[key]`` (M, 3) the reported positions of the first M points on that frame (NaN
    where not tracked); ``pixel`` (N,) world units per pixel at each point. A point is
    predicted from the ``neighbours`` points nearest to it that were tracked on its seeding
    frame too: nearest now, or with ``both_frames`` > 0 nearest in the 6-D space of where
    they are now and, weighed by ``both_frames``, where they were then, so that a point of
    another body part that has come close since (an arm passing the torso, a thigh by the
    other), whose motion is not the point's, is not taken. With ``stretch`` finite they are
    the nearest ``neighbours`` among the ``candidates`` nearest so whose distance to the point
    has changed by less than ``stretch`` pixels since then (a rigid motion keeps distances
    whatever its rotation; a point of another part that moved past it does not), or the
    nearest ``neighbours`` where fewer than ``min_neighbours`` have. With ``gate`` finite
    (None: ``settings.RIGID_GATE``) the prediction's covariance ``P`` is scaled by ``max(1,
    m^2 / gate^2)``, ``m`` the Mahalanobis distance of the prediction from the intersection
    in ``S + P``: beyond the gate the correction falls as the disagreement grows (a
    redescending weight; module docstring). With ``passes`` > 1 (None:
    ``settings.RIGID_PASSES``) the fusion is repeated with the neighbours' rigid motions
    fitted to their fused positions of the pass before (the same neighbours; each point's
    own intersection and covariance stay the measurement), so that a neighbour's drift in
    depth weighs less in its neighbours' predictions. Points seeded on this frame, or with
    too few neighbours, are returned as they are. Returns the fused positions and
    covariances. ``plans``: the neighbours as :func:`neighbour_plans` chose them with these
    same arguments (computed here when not given: a frame that also asks
    :func:`rigid_residuals` chooses them once for both)."""
    if gate is None:
        gate = settings.RIGID_GATE
    if passes is None:
        passes = settings.RIGID_PASSES
    if not (isinstance(passes, (int, np.integer)) and passes >= 1):
        raise ValueError(f"passes must be a whole number >= 1, got {passes!r}")
    if not gate > 0:
        raise ValueError(f"gate must be positive (or infinite), got {gate!r}")
    if plans is None:
        plans = neighbour_plans(x, covariance, pixel, seeded, history, neighbours=neighbours, both_frames=both_frames,
                                candidates=candidates, stretch=stretch, min_neighbours=min_neighbours)
    fused, fused_cov = _fuse(x, x, covariance, pixel, plans, sigma=sigma, gate=gate)
    # A history frame that is this frame's own intersections (points seeded now) predicts
    # them where they are on the first pass; later passes would only spread the
    # neighbours' corrections onto them.
    later = [plan for plan in plans if not plan.now]
    for _ in range(passes - 1):
        fused, fused_cov = _fuse(x, fused, covariance, pixel, later, sigma=sigma, gate=gate)
    return fused, fused_cov


class NeighbourPlan(NamedTuple):
    """The points of one seeding frame and their chosen neighbours."""

    rows: NDArray[np.int64]  # (M,) the points
    near: NDArray[np.int64]  # (M, K) their candidate neighbours
    weight: NDArray[np.float64]  # (M, K) 1 for the chosen ones, else 0
    then: NDArray[np.float64]  # (N, 3) every point's position on that frame
    now: bool  # that frame's positions are this frame's intersections


def neighbour_plans(x: NDArray[np.float64], covariance: NDArray[np.float64], pixel: NDArray[np.float64],
                    seeded: NDArray[np.int64], history: dict[int, NDArray[np.float64]], *, neighbours: int,
                    both_frames: float = 0.0, candidates: int = 0, stretch: float = float("inf"),
                    min_neighbours: int = 3) -> list[NeighbourPlan]:
    """The neighbours of :func:`rigid_fusion` and :func:`rigid_residuals` (the same
    arguments), chosen once by the intersections ``x``: one plan per seeding frame in
    ``history`` (its points, their candidate neighbours, the chosen ones' weights, every
    point's position then). Read-only for both."""
    plans = []
    tracked = np.isfinite(x).all(axis=1) & np.isfinite(covariance).all(axis=(1, 2)) & np.isfinite(pixel)
    for key, before in history.items():
        rows = np.flatnonzero(tracked & (seeded == key))
        if rows.size == 0:
            continue
        then = np.full((len(x), 3), np.nan)
        then[: len(before)] = before[: len(x)]
        rows = rows[np.isfinite(then[rows]).all(axis=1)]
        both = np.flatnonzero(tracked & np.isfinite(then).all(axis=1))
        k = max(candidates, neighbours) if np.isfinite(stretch) else neighbours
        if rows.size == 0 or both.size < neighbours + 1:
            continue
        k = min(k, both.size - 1)
        # Its own row is among the nearest (distance 0): ask for one more and drop it.
        if both_frames > 0:
            w = float(both_frames)
            _, idx = cKDTree(np.hstack([x[both], w * then[both]])).query(np.hstack([x[rows], w * then[rows]]), k=k + 1)
        else:
            _, idx = cKDTree(x[both]).query(x[rows], k=k + 1)
        near = both[idx]
        own = near == rows[:, None]
        order = np.argsort(own, axis=1, kind="stable")[:, :k]
        near = np.take_along_axis(near, order, axis=1)
        take = np.zeros(near.shape, bool)
        take[:, :neighbours] = True
        if np.isfinite(stretch):
            # The point's own depth error changes its distances too (a few pixels along its
            # rays), so the bound is loose: it is for parts passing one another.
            now_d = np.linalg.norm(x[near] - x[rows][:, None], axis=2)
            then_d = np.linalg.norm(then[near] - then[rows][:, None], axis=2)
            kept = np.abs(now_d - then_d) < stretch * pixel[rows][:, None]
            kept &= np.cumsum(kept, axis=1) <= neighbours
            enough = kept.sum(axis=1) >= min_neighbours
            take[enough] = kept[enough]
        plans.append(NeighbourPlan(rows, near, take.astype(np.float64), then, bool(np.array_equal(then[both], x[both]))))
    return plans


def _fuse(x: NDArray[np.float64], moved: NDArray[np.float64], covariance: NDArray[np.float64],
          pixel: NDArray[np.float64], plans: list[NeighbourPlan], *, sigma: float,
          gate: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """One pass of :func:`rigid_fusion`: each planned point's intersection ``x`` fused with
    the prediction of its neighbours' rigid motion fitted to ``moved`` (``x`` itself on the
    first pass)."""
    x_out, cov_out = x.copy(), covariance.copy()
    for rows, near, weight, then, _ in plans:
        r, t = rigid_motions(then[near], moved[near], weight)
        predicted = np.einsum("nij,nj->ni", r, then[rows]) + t
        s = covariance[rows]
        prior = ((sigma * pixel[rows]) ** 2)[:, None, None] * np.eye(3)
        if np.isfinite(gate):
            # Where the neighbours' prediction and the views disagree by much more than
            # both allow, the prediction is the one more often wrong (its neighbours'
            # own intersections drifted, or they are not the point's part): its weight
            # falls with the square of the disagreement.
            d = predicted - x[rows]
            m2 = np.einsum("ni,ni->n", d, np.linalg.solve(s + prior, d[..., None])[..., 0])
            prior = prior * np.maximum(m2 / gate**2, 1.0)[:, None, None]
        total = s + prior
        gain = np.linalg.solve(total, s).transpose(0, 2, 1)  # S (S + P)^-1 (both symmetric)
        x_out[rows] = x[rows] + np.einsum("nij,nj->ni", gain, predicted - x[rows])
        cov_out[rows] = _fused_covariance(s, prior[:, 0, 0])
    return x_out, cov_out


def _fused_covariance(s: NDArray[np.float64], p: NDArray[np.float64]) -> NDArray[np.float64]:
    """(M, 3, 3) ``S - S (S + p I)^-1 S`` for symmetric positive definite ``s`` (M, 3, 3)
    and an isotropic prior's variances ``p`` (M,), positive definite by construction: in
    the eigenbasis of ``S`` each variance ``w`` becomes ``w p / (w + p)`` (no subtraction
    of nearly equal numbers along the rays, where ``w`` is far above ``p``), ``w`` held at
    least 1e-12 of the largest (an intersection rounded indefinite stays definite)."""
    w, v = np.linalg.eigh(0.5 * (s + s.transpose(0, 2, 1)))
    w = np.maximum(w, 1e-12 * np.maximum(w[:, -1:], 0.0))
    fused = w * p[:, None] / (w + p[:, None])
    fused = np.where(fused > 0, fused, np.finfo(float).tiny)
    out = np.einsum("nik,nk,njk->nij", v, fused, v)
    return 0.5 * (out + out.transpose(0, 2, 1))  # exactly symmetric


class RigidResiduals(NamedTuple):
    """Per point (N,), pixel equivalents, NaN where no prediction was made (seeded on this
    frame, too few neighbours, not tracked): ``across`` the distance of the point from its
    neighbours' rigid prediction across the direction to its cameras (a slide along the
    surface seen alike in both views of a narrow pair), ``along`` the same along it (the
    pair's depth, noisy by 1 px-eq per 0.1 px of disparity), ``spread`` the median distance
    of the chosen neighbours themselves from the rigid motion fitted to them (how rigidly
    the neighbourhood moved since the seeding frame); ``held_out`` the median distance of
    each chosen neighbour from where the others' rigid motion puts it (leave one out: how
    well the neighbourhood predicts a point it was not fitted to, which a thin limb's
    nearly collinear neighbours do badly across its axis while fitting themselves well);
    ``predicted`` (N, 3) world, the prediction itself."""

    across: NDArray[np.float64]
    along: NDArray[np.float64]
    spread: NDArray[np.float64]
    held_out: NDArray[np.float64]
    predicted: NDArray[np.float64]


def rigid_residuals(x: NDArray[np.float64], moved: NDArray[np.float64], covariance: NDArray[np.float64],
                    pixel: NDArray[np.float64], towards: NDArray[np.float64], seeded: NDArray[np.int64],
                    history: dict[int, NDArray[np.float64]], *, neighbours: int, both_frames: float = 0.0,
                    candidates: int = 0, stretch: float = float("inf"), min_neighbours: int = 3,
                    plans: list[NeighbourPlan] | None = None) -> RigidResiduals:
    """How far each point ``x`` (N, 3; NaN where not tracked) is from where its neighbours'
    rigid motion since its seeding frame puts it (:class:`RigidResiduals`). The neighbours
    are :func:`rigid_fusion`'s (the same arguments, chosen by ``x``); their motion is fitted
    to ``moved`` (N, 3; e.g. the fused positions, whose depth drifted less). ``towards``
    (N, 3) unit directions from the point to its cameras (their mean), ``pixel`` (N,) world
    units per pixel at the point. The seeding frame is the track's whole life: a point
    that slides a little on every frame passes every one-step check, but its offset from
    the neighbourhood's rigid map grows. ``plans``: as :func:`rigid_fusion`'s."""
    n = len(x)
    across, along, spread, held_out = (np.full(n, np.nan) for _ in range(4))
    prediction = np.full((n, 3), np.nan)
    if plans is None:
        plans = neighbour_plans(x, covariance, pixel, seeded, history, neighbours=neighbours, both_frames=both_frames,
                                candidates=candidates, stretch=stretch, min_neighbours=min_neighbours)
    for rows, near, weight, then, now in plans:
        if now:
            continue
        # The neighbours' positions then and now, gathered once for the fit and the K
        # leave-one-out fits of every point.
        a, b = then[near], moved[near]
        r, t = rigid_motions(a, b, weight)
        predicted = np.einsum("nij,nj->ni", r, then[rows]) + t
        prediction[rows] = predicted
        d = x[rows] - predicted
        u = towards[rows]
        depth = np.einsum("ni,ni->n", d, u)
        along[rows] = np.abs(depth) / pixel[rows]
        across[rows] = np.linalg.norm(d - depth[:, None] * u, axis=1) / pixel[rows]
        own = np.einsum("nij,nkj->nki", r, a) + t[:, None] - b
        res = np.where(weight > 0, np.linalg.norm(own, axis=2), np.nan) / pixel[rows][:, None]
        spread[rows] = nanmedian_rows(res)  # every row has chosen neighbours
        # Leave one out: K fits per point, each without one of its neighbours (where three
        # others remain; NaN elsewhere), in the core with each point's neighbours read in
        # place, not gathered once per fit.
        r1, t1 = track_rigid_held_out(np.ascontiguousarray(a), np.ascontiguousarray(b),
                                      np.ascontiguousarray(weight, dtype=np.float64), min_others=3.0)
        i, j = np.nonzero(np.isfinite(t1[..., 0]))
        if i.size:
            miss = np.einsum("nij,nj->ni", r1[i, j], a[i, j]) + t1[i, j] - b[i, j]
            loo = np.full(near.shape, np.nan)
            loo[i, j] = np.linalg.norm(miss, axis=1) / pixel[rows][i]
            held_out[rows] = nanmedian_rows(loo)  # NaN: rows without three neighbours
    return RigidResiduals(across, along, spread, held_out, prediction)


def nanmedian_rows(values: NDArray[np.float64]) -> NDArray[np.float64]:
    """(M,) each row's median of ``values`` (M, K) float64 ignoring NaN (NaN for a row of
    none), the same to the bit as ``np.nanmedian(values, axis=1)``: that sorts the rows
    behind a mask (``np.ma.median``: K < 600), ~0.2 ms a call here, where a plain sort puts
    the NaN last alike; the middle one, or the two middle ones' sum halved (as
    ``np.ma.median`` forms it; an odd count's middle one doubled and halved is itself; a zero
    median is +0)."""
    m, k = values.shape
    if k == 0:
        return np.full(m, np.nan)
    ordered = np.sort(values, axis=1)
    count = k - np.isnan(values).sum(axis=1)
    high = count // 2
    low = np.where(count % 2 == 1, high, high - 1)
    lo = np.take_along_axis(ordered, np.clip(low, 0, k - 1)[:, None], axis=1)[:, 0]
    hi = np.take_along_axis(ordered, np.clip(high, 0, k - 1)[:, None], axis=1)[:, 0]
    # + 0.0: a median of zeros is +0 there whatever their sign (the sum starts from +0).
    out = (lo + hi) / 2.0 + 0.0
    out[count == 0] = np.nan
    return out
