"""Reported positions checked against the silhouettes of every camera (issue 15): a point on
the subject's surface projects inside (or on the edge of) the silhouette of every camera
whose image it falls in, whichever cameras hold its views. A narrow stereo pair places its
points well across its rays (0.2 px-eq) but poorly along them (1.5 px-eq), and after the
rigid fusion and the SLID check most kept positions beyond 5 px-eq are off along the rays
(72-91% on the tuning seeds, benches/README.md, track18), the majority in front of the
surface. A camera of another pair that sees the limb from the side sees such a depth error
across its image, and a point in front of the surface near that camera's outline lies
outside its silhouette. The check needs no neighbours (it sees a neighbourhood that drifted
in depth together, which the rigid checks cannot) and no image matching: the frame's masks
are already read by the tracker."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from elastocap.cameras import Camera

__all__ = ["outside_silhouettes"]


def _disk(radius: float) -> NDArray[np.intp]:
    """(K, 2) integer pixel offsets (du, dv) within ``radius`` of the origin."""
    r = int(np.floor(radius))
    dv, du = np.mgrid[-r : r + 1, -r : r + 1]
    inside = du**2 + dv**2 <= radius**2
    return np.column_stack([du[inside], dv[inside]]).astype(np.intp)


def outside_silhouettes(cameras: Sequence[Camera], masks: Sequence[NDArray[np.bool_]], points: NDArray[np.float64],
                        margin: float) -> NDArray[np.bool_]:
    """(N,) whether ``points`` project farther than ``margin`` pixels outside the
    silhouette of some camera: no silhouette pixel within ``margin`` of the projection's
    nearest pixel, in a camera the point is in front of and projects inside the image of.

    Parameters
    ----------
    cameras : sequence of Camera
    masks : sequence of (H, W) bool
        The frame's silhouettes, one per camera (True on the subject).
    points : (N, 3) float64
        World positions; NaN rows are never outside.
    margin : float
        Pixels, >= 0: the silhouettes' own error (a segmented mask's edge) and the
        rounding to the pixel grid. The distance is Euclidean, the same as a distance
        transform's, computed only where the projection is off the silhouette.

    Returns
    -------
    (N,) bool
    """
    n = len(points)
    out = np.zeros(n, bool)
    ok = np.isfinite(points).all(axis=1)
    if not ok.any():
        return out
    rows = np.flatnonzero(ok)
    x = points[rows]
    disk = _disk(margin)
    for cam, mask in zip(cameras, masks):
        h, w = mask.shape
        uv, depth = cam.project(x)
        iu, iv = np.round(uv[:, 0]), np.round(uv[:, 1])
        inside = (depth > 0) & (iu >= 0) & (iv >= 0) & (iu <= w - 1) & (iv <= h - 1)
        at = np.flatnonzero(inside)
        iu, iv = iu[at].astype(np.intp), iv[at].astype(np.intp)
        off = ~mask[iv, iu]
        if not off.any():
            continue
        at, iu, iv = at[off], iu[off], iv[off]
        # Silhouette pixels within the margin (clipped to the image: pixels beyond it are
        # unknown, and the clipped ones are read again, which changes nothing).
        su = np.clip(iu[:, None] + disk[None, :, 0], 0, w - 1)
        sv = np.clip(iv[:, None] + disk[None, :, 1], 0, h - 1)
        far = ~mask[sv, su].any(axis=1)
        out[rows[at[far]]] = True
    return out
