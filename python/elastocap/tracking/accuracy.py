"""Tracks measured against ground-truth surface points (synthetic captures).

Each track's reference is either its own seeded 3-D position carried through the sequence
by the rigid motion of the truth points around where it was seeded (a local Kabsch fit of
its nearest truth points; exact on rigid parts, close on smoothly deforming ones), or, given
as ``reference``, the true surface point it was seeded on
(:func:`elastocap.synth.track_reference.surface_reference`). The seeded position is the
tracker's own triangulation, off the surface by its depth error (a median 1 px-equivalent on
the textured capture), which the first reference keeps for the track's whole life: a camera
80-90 degrees away sees it as image error, and the 3-D error is measured from a point off the
surface. The image error is the distance between a track's views and the projections of its
reference."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from elastocap._core import InvalidInputError
from elastocap.cameras import Camera
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.tracks import Tracks

__all__ = ["TrackAccuracy", "track_accuracy"]


class TrackAccuracy(NamedTuple):
    """Per track: ``rms`` (N,) RMS image error over its tracked frames and the cameras that
    hold it where the truth is visible (every such view counts once), pixels; ``through``
    (N,) tracked on every frame after its seeding where its truth is visible in at least two cameras; ``expected``
    (F, N) those frames; ``error`` (F, N) the largest image error per frame (NaN where not
    tracked), pixels; ``error3d`` (F, N) the 3-D distance to the truth in pixel
    equivalents (over the pixel footprint at the truth's depth, mean over the cameras that
    see it); ``measured`` (N,) the tracks the figures are about: seeded, and (when the
    truth says which points are material) seeded on a point that shows its own texture on
    every frame, carried by such points only (and, with a ``reference``, having one);
    ``through_span`` (N,) tracked on every frame from its seeding up to the first on which
    its truth is visible in fewer than two cameras (a point then occluded and flagged has
    done its job; ``through`` asks it back under its id after the gap)."""

    rms: NDArray[np.float64]
    through: NDArray[np.bool_]
    expected: NDArray[np.bool_]
    error: NDArray[np.float64]
    error3d: NDArray[np.float64]
    measured: NDArray[np.bool_]
    through_span: NDArray[np.bool_]


def _kabsch(a: NDArray[np.float64], b: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Batched rigid fits b ~ R a + t of (N, K, 3) point sets."""
    ca, cb = a.mean(axis=1), b.mean(axis=1)
    h = np.einsum("nki,nkj->nij", a - ca[:, None], b - cb[:, None])
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.einsum("nij,njk->nik", vt.transpose(0, 2, 1), u.transpose(0, 2, 1))))
    fix = np.ones((len(a), 3))
    fix[:, 2] = d
    r = np.einsum("nji,nj,nkj->nik", vt, fix, u)
    return r, cb - np.einsum("nij,nj->ni", r, ca)


def track_accuracy(tracks: Tracks, cameras: Sequence[Camera], truth: NDArray[np.float64], visible: NDArray[np.bool_],
                   part: NDArray[np.int64] | None = None, *, neighbours: int = 8,
                   material: NDArray[np.bool_] | None = None, reference: NDArray[np.float64] | None = None) -> TrackAccuracy:
    """Measure ``tracks`` against truth positions (F, M, 3) and visibility (F, C, M) of
    surface points on the same frames (``part`` (M,): neighbours are taken on the nearest
    point's part only; ``material`` (F, M): where each truth point shows the texture it was
    seeded on; only points material on every frame carry tracks, and a track whose nearest
    truth point at its seeding is not one is left out of ``measured``; ``reference`` (F, N,
    3): each track's true position from its seeding frame on, measured against instead of
    its carried seeded position (NaN: the track has none and is left out of ``measured``);
    the truth's points still say where it is visible)."""
    f, n = tracks.flags.shape
    tracked = tracks.flags == TrackFlag.TRACKED
    first = np.where(tracked.any(axis=0), np.argmax(tracked, axis=0), -1)
    carried = np.full((f, n, 3), np.nan)
    expected = np.zeros((f, n), bool)
    error = np.full((f, n), np.nan)
    error3d = np.full((f, n), np.nan)
    m = truth.shape[1]
    part_ = np.zeros(m, np.int64) if part is None else np.asarray(part)
    usable = np.ones(m, bool) if material is None else np.all(np.asarray(material, bool), axis=0)
    if reference is not None:
        reference = np.asarray(reference, dtype=np.float64)
        if reference.shape != (f, n, 3):
            raise InvalidInputError(f"reference must have shape {(f, n, 3)}, got {reference.shape}")
    measured = first >= 0
    squares = np.zeros(n)
    counts = np.zeros(n, np.int64)
    for s in np.unique(first[first >= 0]):
        rows = np.flatnonzero(first == s)
        x0 = tracks.positions[s, rows]
        tree = cKDTree(truth[s])
        _, nearest = tree.query(x0, k=1)
        measured[rows] &= usable[nearest]
        # Neighbours on the nearest point's part, among the material ones.
        near = np.zeros((rows.size, neighbours), np.int64)
        for p in np.unique(part_[nearest]):
            on = np.flatnonzero((part_ == p) & usable)
            if on.size == 0:
                on = np.flatnonzero(part_ == p)
            sub = cKDTree(truth[s, on])
            sel = part_[nearest] == p
            _, idx = sub.query(x0[sel], k=min(neighbours, on.size))
            near[sel] = on[np.atleast_2d(idx).reshape(sel.sum(), -1)[:, :neighbours]] if on.size >= neighbours else on[0]
        if reference is not None:
            measured[rows] &= np.isfinite(reference[s, rows]).all(axis=1)
        for t in range(s, f):
            if reference is None:
                r, tr = _kabsch(truth[s, near], truth[t, near])
                carried[t, rows] = np.einsum("nij,nj->ni", r, x0) + tr
            else:
                carried[t, rows] = reference[t, rows]
            seen = visible[t][:, near].all(axis=2)  # (C, rows)
            expected[t, rows] = seen.sum(axis=0) >= 2
            errs = np.full((len(cameras), rows.size), np.nan)
            footprint = np.zeros(rows.size)
            for k, cam in enumerate(cameras):
                a = cam.project(carried[t, rows])[0]
                if tracks.views is not None:
                    b = tracks.views[t, rows, k]
                    held = np.isfinite(b).all(axis=1)
                else:
                    b = cam.project(np.nan_to_num(tracks.positions[t, rows]))[0]
                    held = np.ones(rows.size, bool)
                errs[k] = np.where(seen[k] & held & tracked[t, rows], np.linalg.norm(a - np.nan_to_num(b), axis=1), np.nan)
                footprint += np.where(seen[k], cam.to_camera(carried[t, rows])[:, 2] / cam.K[0, 0], 0.0)
            with np.errstate(all="ignore"):
                footprint /= seen.sum(axis=0)
                error3d[t, rows] = np.where(tracked[t, rows], np.linalg.norm(tracks.positions[t, rows] - carried[t, rows], axis=1) / footprint, np.nan)
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                error[t, rows] = np.where(np.isfinite(errs).any(axis=0), np.nanmax(errs, axis=0), np.nan)
            # The RMS is over every view the track holds (the "RMS image error"),
            # not over the worst view of each frame.
            held_errs = np.isfinite(errs)
            squares[rows] += (np.where(held_errs, errs, 0.0) ** 2).sum(axis=0)
            counts[rows] += held_errs.sum(axis=0)
    with np.errstate(all="ignore"):
        rms = np.where(counts > 0, np.sqrt(squares / counts), np.nan)
    through = ~(expected & ~tracked).any(axis=0) & (first >= 0)
    after = np.arange(f)[:, None] >= first[None, :]
    span = after & (np.cumsum(after & ~expected, axis=0) == 0)
    through_span = ~(span & ~tracked).any(axis=0) & (first >= 0)
    return TrackAccuracy(rms=rms, through=through, expected=expected, error=error, error3d=error3d, measured=measured,
                         through_span=through_span)
