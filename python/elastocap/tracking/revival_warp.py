"""The anchor patches of a lost point warped by its body part's motion since they were cut
(issue 15, branch track15; ``settings.REVIVE_WARP``, off): a limb that swung or turned while
a point was hidden shows the point's surface rotated and foreshortened, which the
revival's box search (translation only) may not find. Measured on the textured capture it
finds no more points (benches/README.md, branch track15): the anchors that fail where the
prediction is right fail for their age (shading and turn), not the in-image affine."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap import _core
from elastocap.tracking import settings
from elastocap.tracking.filters import pixel_size
from elastocap.tracking.rigidity import rigid_motions

if TYPE_CHECKING:
    from elastocap.tracking.step import FrameTracker

__all__ = ["anchor_affines", "warped_search"]

# The fewest neighbours whose rigid motion gives a warp.
MIN_NEIGHBOURS = 3


def anchor_affines(tracker: FrameTracker, rows: NDArray[np.int64], predicted: NDArray[np.float64],
                   now: NDArray[np.float64]) -> NDArray[np.float64]:
    """(M, C, 2, 2) the image affine from each held anchor patch of ``rows`` (as cut) to
    the point predicted now at ``predicted`` (M, 3): the surface plane of the point's own
    neighbours (``Lost.chosen``) on the anchor's frame (or the nearest frame the revival
    remembers), moved by their rigid motion to ``now`` (N, 3), both projected into the
    camera. Identity where unknown or ill-conditioned. A limb that swung or turned while a
    point was hidden shows its anchor rotated and foreshortened, which the box search
    (translation only) does not find; the least-squares match would have followed it."""
    lost, anchors = tracker.lost, tracker.anchors
    assert lost is not None and anchors is not None
    m, c = len(rows), len(tracker.cameras)
    out = np.broadcast_to(np.eye(2), (m, c, 2, 2)).copy()
    frames = np.array(sorted(lost.history))
    pairs, before, after = [], [], []
    for i, row in enumerate(rows.tolist()):
        if row not in lost.chosen or not np.isfinite(predicted[i]).all():
            continue
        near, _ = lost.chosen[row]
        for k in np.flatnonzero(anchors.held[row]):
            fa = frames[np.argmin(np.abs(frames - anchors.frame[row, k]))]
            pairs.append((i, k))
            before.append(lost.history[int(fa)][near] if len(lost.history[int(fa)]) > near.max() else np.full((near.size, 3), np.nan))
            after.append(now[near])
    if not pairs:
        return out
    kmax = max(len(b) for b in before)
    a = np.zeros((len(pairs), kmax, 3))
    b = np.zeros((len(pairs), kmax, 3))
    w = np.zeros((len(pairs), kmax))
    for j, (pa, pb) in enumerate(zip(before, after)):
        ok = np.isfinite(pa).all(axis=1) & np.isfinite(pb).all(axis=1)
        a[j, : ok.sum()], b[j, : ok.sum()], w[j, : ok.sum()] = pa[ok], pb[ok], 1.0
    enough = w.sum(axis=1) >= MIN_NEIGHBOURS
    w[~enough] = 1.0
    r, t = rigid_motions(a, b, w)
    idx = np.array(pairs)
    x_now = predicted[idx[:, 0]]
    x_then = np.einsum("pji,pj->pi", r, x_now - t)
    # The neighbours' plane then: its two largest directions.
    wn = w / w.sum(axis=1, keepdims=True)
    centre = np.einsum("pk,pki->pi", wn, a)
    d = a - centre[:, None]
    _, vec = np.linalg.eigh(np.einsum("pk,pki,pkj->pij", wn, d, d))
    tangent = vec[:, :, 1:].transpose(0, 2, 1)  # (P, 2, 3)
    step = pixel_size(tracker.cameras, x_now, np.ones((len(idx), c), bool))[:, None, None] * tangent
    for k in np.unique(idx[:, 1]):
        sel = np.flatnonzero((idx[:, 1] == k) & enough)
        if sel.size == 0:
            continue
        cam = tracker.cameras[k]

        def jacobian(x: NDArray[np.float64], e: NDArray[np.float64]) -> NDArray[np.float64]:
            u0 = cam.project(x)[0]
            return np.stack([cam.project(x + e[:, j])[0] - u0 for j in range(2)], axis=2)  # (S, 2, 2)

        ja = jacobian(x_then[sel], step[sel])
        jb = jacobian(x_now[sel], np.einsum("pij,pkj->pki", r[sel], step[sel]))
        with np.errstate(all="ignore"):
            affine = jb @ np.linalg.pinv(ja)
            sv = np.linalg.svd(affine, compute_uv=False)
        # A grazing view then or now (a near-singular map) is left to the plain search.
        sane = np.isfinite(sv).all(axis=1) & (sv[:, 1] > 1 / 3) & (sv[:, 0] < 3)
        out[idx[sel[sane], 0], k] = affine[sane]
    return out


def warped_search(tracker: FrameTracker, grey: list[NDArray[np.float32]], starts: NDArray[np.float64],
                  where: NDArray[np.bool_], rows: NDArray[np.int64],
                  affines: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``Anchors.search`` with each anchor patch of ``rows`` (and its weights) warped by its
    affine (``affines`` (M, C, 2, 2), :func:`anchor_affines`) about its centre first:
    positions (N, C, 2) and covariances, NaN where not found."""
    anchors = tracker.anchors
    assert anchors is not None
    n, c = starts.shape[:2]
    out = np.full((n, c, 2), np.nan)
    cov = np.full((n, c, 2, 2), np.nan)
    side, half = anchors.side, anchors.side // 2
    position = np.full(n, -1)
    position[rows] = np.arange(len(rows))
    where = where & anchors.held[:n] & np.isfinite(starts).all(axis=2)
    for k in range(c):
        sel = np.flatnonzero(where[:, k] & (position >= 0))
        if sel.size == 0:
            continue
        per_row = int(np.ceil(np.sqrt(sel.size)))
        tiles = np.zeros((2, per_row * per_row, side, side), np.float32)
        centre = np.array([half, half], float)
        for j, p in enumerate(sel.tolist()):
            inverse = np.linalg.inv(affines[position[p], k])
            warp = np.hstack([inverse, (centre - inverse @ centre)[:, None]])
            for layer, source in enumerate((anchors.patches[p, k], anchors.weights[p, k])):
                tiles[layer, j] = cv2.warpAffine(source, warp, (side, side), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        mosaic, weighs = (np.ascontiguousarray(tiles[layer].reshape(per_row, per_row, side, side).transpose(0, 2, 1, 3)
                                               .reshape(per_row * side, per_row * side)) for layer in range(2))
        index = np.arange(sel.size)
        centres = np.column_stack([(index % per_row) * side + half, (index // per_row) * side + half]).astype(float)
        previous = 2 * centres - starts[sel, k]
        pos, flags, pcov, corr = _core.track_step(
            [mosaic], [grey[k]], centres[None], previous[None], size=anchors.size, radius=settings.REVIVE_RADIUS,
            min_correlation=min(tracker.min_correlation, settings.BOX_CORRELATION), forward_backward=tracker.o["forward_backward"],
            min_texture=tracker.keep_texture, max_iterations=settings.STEP_ITERATIONS,
            weights=([weighs], [np.ones_like(grey[k])]))
        good = (flags[0] == 0) & (corr[0] >= min(tracker.min_correlation, settings.REVIVE_CORRELATION))
        out[sel[good], k] = pos[0, good]
        cov[sel[good], k] = pcov[0, good]
    return out, cov
