"""Revival of lost points under their own id (issue 15): a point that left two-camera
visibility (an arm passing in front of it, a limb turning away) or whose views all failed
at once keeps its anchor patches and its last 3-D position. While it is lost, its position
is predicted from the rigid motion of points of its own body part that were tracked around
it when it was lost and are tracked now (a limb's points move together; a constant-velocity
guess over several frames does not follow a swinging arm; the points nearest it then are often
the occluding arm's: :func:`own_part`), and its anchors are matched at the projections of
that prediction (optionally warped by the part's motion:
:mod:`elastocap.tracking.revival_warp`). It comes back when at least two views match,
intersect within the residual threshold and land near the prediction.

The state is per point (flat arrays, written with each frame so that a run resumes; the
positions of the last frames are read back from their files)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from elastocap.tracking import settings
from elastocap.tracking.filters import pixel_size
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.revival_warp import anchor_affines, warped_search
from elastocap.tracking.rigidity import rigid_motions
from elastocap.tracking.views import intersect_views, project_all
from elastocap.tracking.visibility import predicted_visible

if TYPE_CHECKING:
    from elastocap.tracking.step import FrameTracker

__all__ = ["Lost", "revive"]

# Neighbours whose motion predicts a lost point, and the fewest that will do.
NEIGHBOURS = 8
MIN_NEIGHBOURS = 3


class Lost:
    """Per point: the frame it was lost on (-1 while not lost) and its last 3-D position;
    and the tracked positions of every point over the last frames (to choose, when a lost
    point is predicted, neighbours tracked both then and now)."""

    def __init__(self, window: int) -> None:
        self.window = window
        self.since = np.zeros(0, np.int64)
        self.x = np.zeros((0, 3))
        self.history: dict[int, NDArray[np.float64]] = {}
        self.chosen: dict[int, tuple[NDArray[np.int64], int]] = {}

    def grow(self, n: int) -> None:
        extra = n - len(self.since)
        if extra > 0:
            self.since = np.concatenate([self.since, np.full(extra, -1, np.int64)])
            self.x = np.concatenate([self.x, np.full((extra, 3), np.nan)])

    def remember(self, frame: int, positions: NDArray[np.float64]) -> None:
        """The tracked positions (N, 3; NaN where not tracked) written for ``frame``."""
        self.history[frame] = positions.copy()
        for old in [f for f in self.history if f < frame - self.window - 1]:
            del self.history[old]

    def record(self, died: NDArray[np.bool_], last: NDArray[np.float64], frame: int) -> None:
        """Points ``died`` (N,) were lost on ``frame``; ``last`` (N, 3) are their last
        positions (tracked or predicted)."""
        self.grow(len(died))
        rows = np.flatnonzero(died & np.isfinite(last).all(axis=1))
        self.since[rows] = frame
        self.x[rows] = last[rows]

    def forget(self, where: NDArray[np.bool_]) -> None:
        self.grow(len(where))
        self.since[: len(where)][where] = -1

    def candidates(self, frame: int) -> NDArray[np.int64]:
        """Points lost before ``frame`` and at most ``window`` frames before it."""
        return np.flatnonzero((self.since >= 0) & (self.since < frame) & (frame - self.since <= self.window))

    def predict(self, rows: NDArray[np.int64], now: NDArray[np.float64], *,
                seeded: NDArray[np.int64] | None = None, seeds: dict[int, NDArray[np.float64]] | None = None,
                pixel: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """(M, 3) predicted positions of ``rows``: their last position moved by the motion
        of neighbours tracked on the last frame before it was lost and now (``now`` (N, 3),
        NaN where not tracked); NaN without that frame's positions or with fewer than
        ``MIN_NEIGHBOURS`` such points.

        With ``seeded`` (N,), ``seeds`` and ``pixel`` (M,) given and
        ``settings.REVIVE_OWN_PART`` (the tracker's seeding frame of each point, the
        positions on those frames, world units per pixel at ``rows``), the neighbours are
        those of its own body part as far as their trajectories tell (:func:`own_part`) and
        their rigid motion moves it; else the ``NEIGHBOURS`` points nearest to it then, by
        their rigid motion (``settings.REVIVE_RIGID``) or their median displacement."""
        out = np.full((len(rows), 3), np.nan)
        frames = sorted(self.history)
        # Per point predicted from its own part: those neighbours and the frame before the
        # loss (for the anchors' warp, :func:`~elastocap.tracking.revival_warp.anchor_affines`).
        self.chosen = {}
        own = settings.REVIVE_OWN_PART and seeded is not None and seeds is not None and pixel is not None
        for since in np.unique(self.since[rows]):
            before = [f for f in frames if f < since]
            if not before:
                continue
            then = self.history[before[-1]]
            m = min(len(then), len(now))
            both = np.flatnonzero(np.isfinite(then[:m]).all(axis=1) & np.isfinite(now[:m]).all(axis=1))
            if both.size < MIN_NEIGHBOURS:
                continue
            group = np.flatnonzero(self.since[rows] == since)
            if own:
                assert seeded is not None and seeds is not None and pixel is not None
                for key in np.unique(seeded[rows[group]]):
                    sub = group[seeded[rows[group]] == key]
                    earlier = _padded(seeds.get(int(key)), len(then))
                    near, take = own_part(self.x[rows[sub]], earlier[rows[sub]], then, earlier, both, pixel[sub])
                    r, t = rigid_motions(then[near], now[near], take.astype(np.float64))
                    out[sub] = np.einsum("mij,mj->mi", r, self.x[rows[sub]]) + t
                    if settings.REVIVE_WARP:
                        for j, row in enumerate(rows[sub]):
                            self.chosen[int(row)] = (near[j][take[j]], int(before[-1]))
                continue
            k = min(NEIGHBOURS, both.size)
            _, near = cKDTree(then[both]).query(self.x[rows[group]], k=k)
            near = both[np.asarray(near).reshape(len(group), k)]
            if settings.REVIVE_RIGID:
                out[group] = _rigid_motion(then[near], now[near], self.x[rows[group]])
            else:
                out[group] = self.x[rows[group]] + np.median(now[near] - then[near], axis=1)
        return out

    def state(self, n: int) -> dict[str, NDArray[np.generic]]:
        self.grow(n)
        return {"lost_since": self.since[:n], "lost_x": self.x[:n]}

    def restore(self, arrays: dict[str, NDArray[np.generic]], history: dict[int, NDArray[np.float64]]) -> None:
        """The state written with a frame, and the positions of the frames before it."""
        self.history = {f: np.asarray(x, float) for f, x in history.items()}
        if "lost_since" in arrays:
            self.since = np.asarray(arrays["lost_since"], np.int64).copy()
            self.x = np.asarray(arrays["lost_x"], float).copy()


def _padded(positions: NDArray[np.float64] | None, n: int) -> NDArray[np.float64]:
    """``positions`` (M, 3) as (n, 3), NaN past M or where missing."""
    out = np.full((n, 3), np.nan)
    if positions is not None:
        m = min(n, len(positions))
        out[:m] = positions[:m]
    return out


def own_part(x: NDArray[np.float64], x_seed: NDArray[np.float64], then: NDArray[np.float64], seed: NDArray[np.float64],
             candidates: NDArray[np.int64], pixel: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """The neighbours (M, K) of lost points at ``x`` (M, 3) on the last frame before their
    loss (``x_seed`` on their seeding frame) whose rigid motion (``then`` (N, 3) -> now)
    predicts them, and which of them count (M, K): of the ``candidates`` (tracked then and
    now), the ``settings.REVIVE_CANDIDATES`` nearest in the 6-D space of then and the seeding frame
    (``seed``; a part that has come close since was far then), and of those the nearest
    ``NEIGHBOURS`` whose distance to the point changed by less than ``settings.RIGID_STRETCH``
    pixels (``pixel`` (M,) world units) between the two (a rigid motion keeps distances; a
    part sliding past does not): branch track12's rule for the fusion. Where the seeding
    frame is unknown, or fewer than ``MIN_NEIGHBOURS`` keep their distance, the nearest
    then. A point lost by an arm passing in front of it is lost where another part comes
    close: the nearest points then are the arm's as often as its own."""
    cand = candidates[np.isfinite(seed[candidates]).all(axis=1)]
    dated = np.isfinite(x_seed).all(axis=1) & np.isfinite(pixel)
    if cand.size < MIN_NEIGHBOURS:
        dated[:] = False
        cand = candidates
    k = min(max(settings.REVIVE_CANDIDATES, NEIGHBOURS), cand.size)
    near = np.zeros((len(x), k), np.int64)
    if dated.any():
        _, idx = cKDTree(np.hstack([then[cand], seed[cand]])).query(np.hstack([x[dated], x_seed[dated]]), k=k)
        near[dated] = cand[np.asarray(idx).reshape(-1, k)]
    if (~dated).any():
        k3 = min(k, candidates.size)
        _, idx = cKDTree(then[candidates]).query(x[~dated], k=k3)
        near[~dated, :k3] = candidates[np.asarray(idx).reshape(-1, k3)]
        near[~dated, k3:] = near[~dated, :1]
    take = np.zeros(near.shape, bool)
    take[:, :NEIGHBOURS] = True
    with np.errstate(invalid="ignore"):
        d_then = np.linalg.norm(then[near] - x[:, None], axis=2)
        d_seed = np.linalg.norm(seed[near] - x_seed[:, None], axis=2)
        kept = np.abs(d_then - d_seed) < settings.RIGID_STRETCH * pixel[:, None]
    kept &= dated[:, None]
    kept &= np.cumsum(kept, axis=1) <= NEIGHBOURS
    enough = kept.sum(axis=1) >= MIN_NEIGHBOURS
    take[enough] = kept[enough]
    return near, take


def _rigid_motion(then: NDArray[np.float64], now: NDArray[np.float64], x: NDArray[np.float64]) -> NDArray[np.float64]:
    """``x`` (M, 3) moved by the least-squares rigid motion (Kabsch) of the point sets
    ``then`` -> ``now`` (M, K, 3). A limb swings: a shift alone misses its rotation by the
    lever arm from the neighbours' centre (seed 0, offline: the median prediction error
    9.7 px-eq with the median shift, 4.6 with the rigid motion)."""
    ca, cb = then.mean(axis=1), now.mean(axis=1)
    h = np.einsum("mki,mkj->mij", then - ca[:, None], now - cb[:, None])
    u, _, vt = np.linalg.svd(h)
    # A reflection (coplanar or noisy neighbours) is turned into the nearest rotation.
    d = np.sign(np.linalg.det(np.einsum("mji,mkj->mik", vt, u)))
    vt[:, 2] *= d[:, None]
    r = np.einsum("mji,mkj->mik", vt, u)
    return np.einsum("mij,mj->mi", r, x - ca) + cb


def revive(tracker: FrameTracker, frame: int, grey: list[NDArray[np.float32]], masks: list[NDArray[np.bool_]],
           alive: NDArray[np.bool_], uv: NDArray[np.float64], cov2d: NDArray[np.float64], x: NDArray[np.float64],
           xcov: NDArray[np.float64], x_state: NDArray[np.float64], flags: NDArray[np.uint8],
           flags2d: NDArray[np.uint8]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Records the points lost on this frame and brings back lost ones whose anchors
    match again (``uv``, ``cov2d``, ``xcov``, ``flags`` and ``flags2d`` are updated in
    place); returns ``x`` and ``x_state``."""
    assert tracker.lost is not None and tracker.anchors is not None
    n, c = uv.shape[:2]
    tracker.lost.grow(n)
    left = np.any(np.isfinite(uv[..., 0]), axis=1)
    if settings.REVIVE_LAST_PATCH and tracker.grey is not None and tracker.lost.history:
        # The anchors of the points lost now cut again from their last tracked frame (the
        # image and views the step started from): an anchor's patch cut long ago shows the
        # surface as it was then, and a surface that turned since is not found by it.
        died = (alive & ~left)[:, None] & np.isfinite(tracker.uv[:n, :, 0]) & tracker.anchors.held[:n]
        tracker.anchors.cut(tracker.grey, tracker.uv[:n], died, max(tracker.lost.history), weights=tracker.weights)
    tracker.lost.record(alive & ~left, tracker.x_last, frame)
    tracker.lost.forget((tracker.lost.since[:n] >= 0) & (frame - tracker.lost.since[:n] > settings.REVIVE_FRAMES))
    rows = tracker.lost.candidates(frame)
    rows = rows[(rows < n) & ~left[rows]]
    if rows.size == 0:
        return x, x_state
    tracked = np.all(np.isfinite(x), axis=1)
    pixel = pixel_size(tracker.cameras, tracker.lost.x[rows], tracker.anchors.held[rows])
    predicted = tracker.lost.predict(rows, np.where(tracked[:, None], x, np.nan), seeded=tracker.seeded_at,
                                     seeds=tracker.history, pixel=pixel)
    targets = project_all(tracker.cameras, predicted, margin=tracker.size)
    if settings.PREDICT_VISIBILITY:
        # The cameras that held the point and are predicted to see it again.
        asked = np.isfinite(targets).all(axis=2) & tracker.anchors.held[rows]
        normals = tracker.normals(predicted, x, tracker.anchors.held[rows])
        seen = predicted_visible(tracker.cameras, masks, predicted, normals, x, asked, facing=settings.REVIVE_FACING)
        targets[asked & ~seen] = np.nan
    where = np.zeros((n, c), bool)
    starts = np.full((n, c, 2), np.nan)
    for k in range(c):
        t = targets[:, k]
        seen = np.all(np.isfinite(t), axis=1)
        iu = np.clip(np.round(np.nan_to_num(t[:, 0])).astype(int), 0, masks[k].shape[1] - 1)
        iv = np.clip(np.round(np.nan_to_num(t[:, 1])).astype(int), 0, masks[k].shape[0] - 1)
        ok = seen & masks[k][iv, iu] & tracker.anchors.held[rows, k]
        where[rows[ok], k] = True
        starts[rows[ok], k] = t[ok]
    pairs = where[rows].sum(axis=1) >= 2
    rows, predicted = rows[pairs], predicted[pairs]
    if rows.size == 0:
        return x, x_state
    found, fcov = tracker.anchors.search(grey, starts, where, radius=settings.REVIVE_RADIUS,
                                      min_correlation=min(tracker.min_correlation, settings.REVIVE_CORRELATION),
                                      box_correlation=min(tracker.min_correlation, settings.BOX_CORRELATION),
                                      forward_backward=tracker.o["forward_backward"], min_texture=tracker.keep_texture,
                                      max_iterations=settings.STEP_ITERATIONS)
    if settings.REVIVE_WARP and tracker.lost.chosen:
        # The anchors warped by the part's motion since they were cut; the plain search
        # keeps the views the warp does not find.
        warped, wcov = warped_search(tracker, grey, starts, where, rows,
                                     anchor_affines(tracker, rows, predicted, np.where(tracked[:, None], x, np.nan)))
        better = np.isfinite(warped[..., 0])
        found = np.where(better[..., None], warped, found)
        fcov = np.where(better[..., None, None], wcov, fcov)
    two = np.isfinite(found[rows, :, 0]).sum(axis=1) >= 2
    rows, predicted = rows[two], predicted[two]
    if rows.size == 0:
        return x, x_state
    bx, bcov, bused, _ = intersect_views(tracker.cameras, found[rows], fcov[rows],
                                         max_residual=min(tracker.o["max_residual"], settings.REVIVE_RESIDUAL), floor=settings.FLOOR)
    ok = np.isfinite(bx).all(axis=1)
    with np.errstate(invalid="ignore"):
        near = np.linalg.norm(bx - predicted, axis=1) <= settings.REVIVE_REACH * pixel_size(tracker.cameras, bx, bused)
    ok &= near
    back = rows[ok]
    uv[back] = np.where(bused[ok][..., None], found[back], np.nan)
    cov2d[back] = np.where(bused[ok][..., None, None], fcov[back], np.nan)
    flags2d[back] = np.where(bused[ok], TrackFlag.TRACKED, flags2d[back])
    x, x_state = x.copy(), x_state.copy()
    x[back], xcov[back], x_state[back] = bx[ok], bcov[ok], bx[ok]
    flags[back] = TrackFlag.TRACKED
    revived = np.zeros(n, bool)
    revived[back] = True
    tracker.lost.forget(revived)
    if settings.REVIVE_RECUT:
        # The anchors of a surface that turned away and back are old: the views found
        # now are cut again from this frame (at the end of the step).
        tracker.anchors.drop(revived[:, None] & np.ones(c, bool))
    return x, x_state
