"""Revival of lost points under their own id (issue 15): a point that left two-camera
visibility (an arm passing in front of it, a limb turning away) or whose views all failed
at once keeps its anchor patches and its last 3-D position. While it is lost, its position
is predicted from the motion of the points that were tracked around it when it was lost
and are tracked now (a limb's points move together; a constant-velocity guess over
several frames does not follow a swinging arm), and its anchors are matched at the projections of that
prediction. It comes back when at least two views match, intersect within the residual
threshold and land near the prediction.

The state is per point (flat arrays, written with each frame so that a run resumes; the
positions of the last frames are read back from their files)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

__all__ = ["Lost"]

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

    def predict(self, rows: NDArray[np.int64], now: NDArray[np.float64]) -> NDArray[np.float64]:
        """(M, 3) predicted positions of ``rows``: their last position moved by the median
        displacement of the ``NEIGHBOURS`` points nearest to it among those tracked on the
        last frame before it was lost and now (``now`` (N, 3), NaN where not tracked); NaN
        without that frame's positions or with fewer than ``MIN_NEIGHBOURS`` such points."""
        out = np.full((len(rows), 3), np.nan)
        frames = sorted(self.history)
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
            k = min(NEIGHBOURS, both.size)
            _, near = cKDTree(then[both]).query(self.x[rows[group]], k=k)
            near = both[np.asarray(near).reshape(len(group), k)]
            shift = np.median(now[near] - then[near], axis=1)
            out[group] = self.x[rows[group]] + shift
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
