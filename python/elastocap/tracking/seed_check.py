"""A seed's depth re-matched with a small window (issue 15, the drift line; drift15).

A seed is found on a pixel of one camera and matched in its stereo partner on the epipolar
line with the tracker's window (15 px). The pairs of the capture's rig see a point under
~5-6 degrees, so the depth is about ten times as sensitive as the partner's match along
the line: a quarter of a pixel there is ~2.5 pixel equivalents of depth. A window matched
on a convex surface (a limb) finds the depth of the patch's mean surface, which lies behind
the surface at its centre by about w^2 / (6 r) for a half-width w and a limb of radius r:
measured on tuning fit seed 51 (benches/README.md, drift15) the seeds' partner views lie
~0.25 px off the true point's projection, always on the side that puts the point behind the
surface (95% of the seeds more than 5 px-eq off lie behind it, none beside it: the error is
along the seed camera's ray), and re-matched with windows of 7 / 9 / 11 / 15 px the median
depth error is 0.5 / 1.0 / 1.7 / 3.7 px-eq, close to the square of the window.

:func:`rematch_depth` re-matches each seed's other views from the seed's pixel with a
smaller window on the same epipolar line, started where the large window converged, and
keeps the new centre where it converged, correlates and stays within ``reach`` of the
start (the bias is a fraction of a pixel; a small window's match that walks farther has
found other texture). The tracking that follows is unchanged: each view is then tracked in
its own camera, frame to frame, which carries the seed's depth on.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from elastocap.cameras import Camera
from elastocap.stereo import match_patches
from elastocap.stereo.matching import MatchStatus

__all__ = ["rematch_depth"]


def _epipolar_lines(seed_cam: Camera, other: Camera, seeds: NDArray[np.float64],
                    views: NDArray[np.float64]) -> NDArray[np.float64]:
    """(M, 3) lines ``(a, b, c)`` in ``other``'s pixels of the seeds' rays (M, 2 pixels in
    ``seed_cam``), through two points on each ray around the depth where it passes
    nearest the ray of its view (M, 2) in ``other``."""
    o1, d1 = seed_cam.rays(seeds)
    o2, d2 = other.rays(views)
    w = o1 - o2
    a, b, c = (d1 * d1).sum(1), (d1 * d2).sum(1), (d2 * d2).sum(1)
    d, e = (d1 * w).sum(1), (d2 * w).sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (b * e - c * d) / (a * c - b * b)
    # Two points a tenth of the depth either side: both in front of the camera, and far
    # enough apart that the line's direction is not rounding.
    p, _ = other.project(o1 + (0.9 * t)[:, None] * d1)
    q, _ = other.project(o1 + (1.1 * t)[:, None] * d1)
    return np.column_stack([p[:, 1] - q[:, 1], q[:, 0] - p[:, 0], p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]])


def rematch_depth(images: Sequence[NDArray[np.float32]], cameras: Sequence[Camera], camera: int,
                  views: NDArray[np.float64], *, size: int, min_correlation: float, min_texture: float,
                  reach: float = 1.0) -> NDArray[np.float64]:
    """Seeds' views (M, C, 2 pixels; NaN where not matched) with every view but the seed's
    own re-matched from the seed's pixel in ``camera`` with a ``size`` px window on the
    seed ray's epipolar line; a view keeps its old centre where the small window did not
    converge, correlates under ``min_correlation``, has a texture under ``min_texture``
    (``match_patches``' gradient floor) or moved more than ``reach`` pixels.

    Returns a new array; ``views`` is not changed."""
    out = np.array(views, dtype=np.float64, copy=True)
    if len(out) == 0:
        return out
    seeds = out[:, camera]
    for j, other in enumerate(cameras):
        if j == camera:
            continue
        rows = np.flatnonzero(np.isfinite(out[:, j]).all(axis=1) & np.isfinite(seeds).all(axis=1))
        if rows.size == 0:
            continue
        start = out[rows, j]
        line = _epipolar_lines(cameras[camera], other, seeds[rows], start)
        good = np.isfinite(line).all(axis=1)
        rows, start, line = rows[good], start[good], line[good]
        if rows.size == 0:
            continue
        m = match_patches(images[camera], seeds[rows], [images[j]], initial=start[:, None, :],
                          epipolar=line[:, None, :], size=size, min_texture=min_texture, max_iterations=20)
        found = m.positions[:, 0]
        with np.errstate(invalid="ignore"):
            ok = ((m.status[:, 0] == MatchStatus.CONVERGED) & (m.correlation[:, 0] >= min_correlation)
                  & (np.linalg.norm(found - start, axis=1) <= reach))
        out[rows[ok], j] = found[ok]
    return out
