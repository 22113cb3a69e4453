"""Where a tracked point sits in the model (issue 15): its MLS shape-function weights over
the nodes around it (SPEC 4.2; the material point a track is attached to,
:mod:`elastocap.elastic.tracks`), and the rigid motion of its neighbours that carries it
back to the rest frame (``TrackTerms(ahead=)``)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from elastocap._core import InvalidInputError

__all__ = ["material_weights", "placeable_weights", "rigid_carry"]

# MLS support: c times the distance to the farthest of the k nodes (SPEC 4.1's c = 1.1),
# enlarged by 1.25 where the moment matrix is ill-conditioned (as rust/mls.rs repairs).
_SUPPORT_FACTOR = 1.1
_ENLARGEMENT = 1.25
_RCOND_MIN = 1e-3


def _spline(r: NDArray[np.float64]) -> NDArray[np.float64]:
    """SPEC 4.2's cubic spline w(r), r >= 0."""
    return np.where(r <= 0.5, 2 / 3 - 4 * r**2 + 4 * r**3, np.where(r <= 1, 4 / 3 * (1 - r) ** 3, 0.0))


def material_weights(points: NDArray[np.float64], nodes: NDArray[np.float64], k: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """MLS shape functions of ``nodes`` evaluated at ``points`` (SPEC 4.2, linear basis).

    Raises :class:`InvalidInputError` when the nodes around a point do not span space
    (:func:`placeable_weights` leaves such points out instead).

    Parameters
    ----------
    points : (T, 3) float64
        Where to evaluate, world units.
    nodes : (N, 3) float64
        Node positions, world units.
    k : int
        Nodes per point (the nearest ones), at most N.

    Returns
    -------
    neighbours : (T, k) int64
    phi : (T, k) float64
        ``phi @ nodes[neighbours]`` reproduces ``points`` (linear reproduction) and rows sum
        to 1.
    """
    neighbours, phi, ok = _mls(points, nodes, k)
    if not ok.all():
        raise InvalidInputError(f"tracks: the nodes around {int((~ok).sum())} tracked points do not span space (MLS weights undefined)")
    return neighbours, phi


def placeable_weights(points: NDArray[np.float64], nodes: NDArray[np.float64],
                      k: int) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.bool_]]:
    """:func:`material_weights` of the points whose nodes span space, and which points
    those are (``(T,) bool``; the others' rows of ``phi`` are zero) instead of an error."""
    return _mls(points, nodes, k)


def _mls(points: NDArray[np.float64], nodes: NDArray[np.float64],
         k: int) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.bool_]]:
    k = min(k, len(nodes))
    distance, neighbours = cKDTree(nodes).query(points, k=k)
    neighbours = np.asarray(neighbours, np.int64).reshape(len(points), k)
    distance = np.asarray(distance).reshape(len(points), k)
    support = _SUPPORT_FACTOR * np.maximum(distance.max(axis=1), 1e-12)
    phi = np.zeros((len(points), k))
    todo = np.arange(len(points))
    for _ in range(5):
        offset = (nodes[neighbours[todo]] - points[todo, None, :]) / support[todo, None, None]
        weight = _spline(np.abs(offset)).prod(axis=2)
        basis = np.concatenate([np.ones(offset.shape[:2] + (1,)), offset], axis=2)
        moments = np.einsum("tk,tki,tkj->tij", weight, basis, basis)
        diagonal = np.sqrt(np.maximum(np.einsum("tii->ti", moments), 1e-300))
        scaled = moments / diagonal[:, :, None] / diagonal[:, None, :]
        ok = 1 / np.linalg.cond(scaled) >= _RCOND_MIN
        unit = np.zeros((len(todo), 4))
        unit[:, 0] = 1
        gamma = np.zeros((len(todo), 4))
        if ok.any():
            gamma[ok] = np.linalg.solve(moments[ok], unit[ok][:, :, None])[:, :, 0]
        phi[todo[ok]] = weight[ok] * np.einsum("tki,ti->tk", basis[ok], gamma[ok])
        todo = todo[~ok]
        if len(todo) == 0:
            break
        support[todo] *= _ENLARGEMENT
    placed = np.ones(len(points), bool)
    placed[todo] = False
    return neighbours, phi, placed


def rigid_carry(moved: NDArray[np.float64], rest: NDArray[np.float64], points: NDArray[np.float64], m: int,
                radius: float, tolerance: float, neighbours: bool = False) -> Any:
    """``points`` (T, 3) carried by the rigid motion of their ``m`` nearest reference
    points, which sit at ``moved`` (R, 3) and are to go to ``rest`` (R, 3): per point the
    least-squares rotation and translation (Kabsch) of those neighbours, applied to it.

    Returns the carried points (T, 3) and which are trusted (T,) bool: all ``m`` neighbours
    within ``radius``, not near a line (second singular value of their spread at least a
    tenth of the first: a rotation about the line is undetermined), and fitted by the rigid
    motion to an RMS residual of at most ``tolerance`` (world units; larger: they do not
    move together, e.g. a joint between them); with ``neighbours``, also the indices
    (into ``moved``) of each point's ``m`` neighbours, (T, m) int.
    """
    t = len(points)
    carried = np.zeros((t, 3))
    good = np.zeros(t, bool)
    if t == 0 or len(moved) < m:
        return (carried, good, np.zeros((t, m), np.int64)) if neighbours else (carried, good)
    distance, nearest = cKDTree(moved).query(points, k=m)
    distance, nearest = distance.reshape(t, m), nearest.reshape(t, m)
    near = (distance <= radius).all(axis=1)
    p, q = moved[nearest], rest[nearest]
    pc, qc = p.mean(axis=1), q.mean(axis=1)
    dp, dq = p - pc[:, None], q - qc[:, None]
    u, s, vt = np.linalg.svd(np.einsum("tmi,tmj->tij", dp, dq))
    # Proper rotations only: a reflection's last axis flipped back.
    sign = np.sign(np.linalg.det(np.einsum("tij,tjk->tik", u, vt)))
    vt[:, 2] *= np.where(sign == 0, 1.0, sign)[:, None]
    rotation = np.einsum("tji,tkj->tik", vt, u)  # V U^T: dq ~ R dp
    residual = np.sqrt(((np.einsum("tij,tmj->tmi", rotation, dp) - dq) ** 2).sum(axis=2).mean(axis=1))
    spread = np.linalg.svd(dp, compute_uv=False)
    planar = spread[:, 1] >= 0.1 * np.maximum(spread[:, 0], 1e-300)
    good = near & planar & (residual <= tolerance)
    carried = qc + np.einsum("tij,tj->ti", rotation, points - pc)
    return (carried, good, nearest) if neighbours else (carried, good)
