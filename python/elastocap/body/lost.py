"""How well a body state explains a frame, and when a tracked frame counts as lost
(issue 16): :class:`FrameQuality`, :func:`observation_distances`, :func:`lost_threshold`.

Masks alone, a limb that drifts off its data costs only a few percent of the rays and the
median ray distance does not move, so the tracker's lost test compares a frame's
explained share with the recent frames' own spread rather than a fixed share.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap.body.model import SKIN_LEVEL, BodyModel, BodyState

__all__ = ["EXPLAINED_DISTANCE", "FrameQuality", "lost_threshold", "observation_distances"]

#: Observations within this distance of the fitted skin (metres) count as explained.
EXPLAINED_DISTANCE = 0.02
#: A tracked frame is lost when its explained share falls below the upper quartile of the
#: recent frames' (what the track explained while it held: a slow drift pulls their median
#: down with it, tuning seed 2's frames 17-21) by more than this many times their spread
#: (``1.4826`` times the median absolute deviation, so a Gaussian's standard deviation) ...
LOST_SPREADS = 3.0
#: ... and by at least this much. Masks alone, the share of a well-tracked frame moves by
#: up to ~0.02 from frame to frame (spread ~0.005-0.01) and the median ray distance stays
#: at 2-4 mm even when a limb has drifted 10 cm (the capsule figure, tuning seed 2: frame
#: 10 fell 0.849 -> 0.809 with the skin from 16 to 23 mm, frame 11 to 0.67 and 36 mm; the
#: fixed drop of 0.1 used before waited for frame 11; ``benches/README.md``, branch body7).
LOST_DROP = 0.03
#: Frames whose quality sets the reference of the lost test, and how many it needs before
#: it trusts their spread (fewer: the spread is :data:`LOST_PRIOR_SPREAD`).
LOST_RECENT = 10
LOST_MIN_RECENT = 4
#: The spread assumed for the first tracked frames, whose few predecessors do not measure
#: one: the largest spread of a held masks-only track (1.4826 MAD of the explained share,
#: 0.004-0.010 on the capsule figure's tuning seeds 2 and 12, ``benches/README.md``,
#: branch body7). Before, these frames were lost only 0.1 below their predecessors' median,
#: which let a drift of 5 mm skin pass for three frames (branch body8).
LOST_PRIOR_SPREAD = 0.01


@dataclass(frozen=True)
class FrameQuality:
    """How well a state explains one frame's observations.

    Attributes
    ----------
    median_distance : float
        Median approximate distance ``|F - T| / |grad F|`` of the points and silhouette rays
        from the skin, metres (rays: at their field maximum).
    explained : float
        Share of them within :data:`EXPLAINED_DISTANCE`.
    observations : int
    """

    median_distance: float
    explained: float
    observations: int


def observation_distances(
    model: BodyModel, state: BodyState, points: Any, origins: Any, directions: Any, side: Any = None
) -> NDArray[np.float64]:
    """Approximate distances (metres) of points and silhouette rays from the skin of
    ``state``: ``|F - T| / |grad F|`` at each point, and at each ray's field maximum (a ray
    that misses the model: infinity; a one-sided ray, ``side`` +1 / -1, that is satisfied:
    0). Points first, then rays."""
    out = []
    if len(points):
        f, g, _ = model.field(points, state)
        out.append(_distance(f, g))
    if len(origins):
        found = model.ray_maxima(origins, directions, state)
        f, g, _ = model.field(found["points"], state)
        d = _distance(f, g)
        d[~found["hit"]] = np.inf
        if side is not None:
            side = np.asarray(side)
            value = np.where(found["hit"], found["values"], 0.0)
            d[((side > 0) & (value >= SKIN_LEVEL)) | ((side < 0) & (value <= SKIN_LEVEL))] = 0.0
        out.append(d)
    return np.concatenate(out) if out else np.zeros(0)


def _distance(f: NDArray[np.float64], g: NDArray[np.float64]) -> NDArray[np.float64]:
    norm = np.linalg.norm(g, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.abs(f - SKIN_LEVEL) / norm
    d[(f < 1e-8) | ~np.isfinite(d)] = np.inf
    return np.asarray(d)


def lost_threshold(recent: Sequence[float]) -> float:
    """The explained share under which a tracked frame counts as lost, given the shares of
    the recent observed frames (oldest first): their upper quartile less
    :data:`LOST_SPREADS` times their spread (``1.4826`` times the median absolute deviation
    from their median), and at least :data:`LOST_DROP` less; with fewer than
    :data:`LOST_MIN_RECENT` frames, whose spread says little, the spread is
    :data:`LOST_PRIOR_SPREAD`; with none, 0.9."""
    shares = np.asarray(recent, dtype=np.float64)[-LOST_RECENT:]
    if len(shares) == 0:
        return 0.9
    median = float(np.median(shares))
    if len(shares) < LOST_MIN_RECENT:
        spread = LOST_PRIOR_SPREAD
    else:
        spread = 1.4826 * float(np.median(np.abs(shares - median)))
    return float(np.percentile(shares, 75)) - max(LOST_SPREADS * spread, LOST_DROP)

