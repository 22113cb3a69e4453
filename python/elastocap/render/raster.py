"""Vectorised triangle rasterisation: coverage and a z-buffer, sampled at pixel centres.

Used by :mod:`elastocap.synth.capture` to render exact silhouettes and shaded images of meshes.
Pixel ``(u, v)`` = (column, row) has its centre at integer coordinates (DESIGN
conventions), so a pixel is covered by a projected triangle when its centre lies inside it.

Why not ``cv2.fillPoly``: given several polygons in one call it fills by the even-odd rule
(a pixel covered by two overlapping triangles is left empty), so the union of a mesh's
overlapping projected triangles cannot be drawn in one call; one call per triangle costs a
Python loop over tens of thousands of faces. Here every candidate pixel of every
triangle's bounding box is tested at once with numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

# A pixel centre on a triangle's edge counts as inside when its barycentric coordinates are
# above -EDGE_TOLERANCE: edges shared by two triangles are evaluated from each triangle's
# own corner, and the two results may differ by rounding (~1e-13 at pixel coordinates of
# ~1e3); including such centres in both triangles leaves no crack between them.
EDGE_TOLERANCE = 1e-9


@dataclass(frozen=True)
class Fragments:
    """Pixel centres inside projected triangles: one row per (pixel, triangle) pair.

    Attributes
    ----------
    pixel : (M,) int64
        Flat pixel index ``v * width + u``.
    face : (M,) int64
        Index into the faces given to :func:`fragments`.
    barycentric : (M, 3) float64
        Screen-space barycentric coordinates of the pixel centre in the projected triangle.
    """

    pixel: NDArray[np.int64]
    face: NDArray[np.int64]
    barycentric: NDArray[np.float64]


def fragments(
    uv: NDArray[np.float64], faces: NDArray[np.int64], width: int, height: int
) -> Fragments:
    """Every pixel centre inside every projected triangle.

    Parameters
    ----------
    uv : (V, 2) float64
        Projected vertices, pixels.
    faces : (F, 3) int64
        Vertex indices per triangle; either orientation.
    width, height : int
        Image size, pixels; centres outside the image are not reported.

    Returns
    -------
    Fragments
        Triangles of zero projected area cover nothing.
    """
    # Per-corner coordinate columns: reductions over a length-3 axis are slow in numpy.
    u0, u1, u2 = (uv[faces[:, i], 0] for i in range(3))
    v0, v1, v2 = (uv[faces[:, i], 1] for i in range(3))
    u_lo = np.maximum(np.ceil(np.minimum(np.minimum(u0, u1), u2) - EDGE_TOLERANCE), 0.0)
    v_lo = np.maximum(np.ceil(np.minimum(np.minimum(v0, v1), v2) - EDGE_TOLERANCE), 0.0)
    u_hi = np.minimum(np.floor(np.maximum(np.maximum(u0, u1), u2) + EDGE_TOLERANCE), width - 1.0)
    v_hi = np.minimum(np.floor(np.maximum(np.maximum(v0, v1), v2) + EDGE_TOLERANCE), height - 1.0)
    twice_area = (u1 - u0) * (v2 - v0) - (v1 - v0) * (u2 - u0)
    with np.errstate(invalid="ignore"):
        keep = np.flatnonzero((u_hi >= u_lo) & (v_hi >= v_lo) & (twice_area != 0) & np.isfinite(twice_area))
    if keep.size == 0:
        empty_i = np.zeros(0, np.int64)
        return Fragments(empty_i, empty_i, np.zeros((0, 3)))
    u_lo, v_lo = u_lo[keep], v_lo[keep]
    nu = (u_hi[keep] - u_lo).astype(np.int64) + 1
    nv = (v_hi[keep] - v_lo).astype(np.int64) + 1
    inverse_area = 1.0 / twice_area[keep]
    # Barycentric coordinate i is the edge function of the opposite edge over twice the
    # area; an affine function of the offset (du, dv) from the bounding box's corner:
    # slope_u * du + slope_v * dv + value at the corner.
    coefficients = []
    for (ua, va), (ub, vb) in (((u1, v1), (u2, v2)), ((u2, v2), (u0, v0))):
        ua, va, ub, vb = ua[keep], va[keep], ub[keep], vb[keep]
        eu, ev = ub - ua, vb - va
        coefficients.append(
            (-ev * inverse_area, eu * inverse_area, (eu * (v_lo - va) - ev * (u_lo - ua)) * inverse_area)
        )

    counts = nu * nv
    owner = np.repeat(np.arange(keep.size), counts)
    first = np.cumsum(counts) - counts
    offset = np.arange(int(counts.sum()), dtype=np.int64) - first[owner]
    row_length = nu[owner]
    dv = offset // row_length
    du = offset - dv * row_length
    (a0, b0, c0), (a1, b1, c1) = coefficients
    l0 = a0[owner] * du + b0[owner] * dv + c0[owner]
    l1 = a1[owner] * du + b1[owner] * dv + c1[owner]
    l2 = 1.0 - l0 - l1
    inside = (l0 >= -EDGE_TOLERANCE) & (l1 >= -EDGE_TOLERANCE) & (l2 >= -EDGE_TOLERANCE)
    owner = owner[inside]
    u = u_lo[owner].astype(np.int64) + du[inside]
    v = v_lo[owner].astype(np.int64) + dv[inside]
    return Fragments(
        pixel=v * width + u,
        face=keep[owner],
        barycentric=np.stack([l0[inside], l1[inside], l2[inside]], axis=1),
    )


def coverage(
    uv: NDArray[np.float64], faces: NDArray[np.int64], width: int, height: int
) -> NDArray[np.bool_]:
    """``(height, width) bool``: pixels whose centre lies in at least one projected
    triangle (the union of the triangles, whatever their orientation or overlap)."""
    covered = np.zeros(height * width, dtype=bool)
    covered[fragments(uv, faces, width, height).pixel] = True
    return covered.reshape(height, width)


def nearest(
    found: Fragments, depth: NDArray[np.float64], faces: NDArray[np.int64]
) -> Fragments:
    """The fragment nearest to the camera at each covered pixel (a z-buffer).

    Parameters
    ----------
    found : Fragments
        From :func:`fragments`.
    depth : (V,) float64
        Camera-space depth of each vertex, positive.
    faces : (F, 3) int64
        The faces ``found`` refers to.

    Returns
    -------
    Fragments
        One per covered pixel, sorted by pixel.

    Notes
    -----
    Depth is interpolated perspective-correctly: ``1 / z`` is affine in the image of a
    planar triangle under a pinhole projection, so it is interpolated with the screen-space
    barycentric coordinates (lens distortion bends this slightly; the triangles here are a
    few pixels wide).
    """
    inverse_depth = np.einsum("ij,ij->i", found.barycentric, 1.0 / depth[faces[found.face]])
    order = np.lexsort((-inverse_depth, found.pixel))
    pixel = found.pixel[order]
    first = np.ones(pixel.size, dtype=bool)
    first[1:] = pixel[1:] != pixel[:-1]
    chosen = order[first]
    return Fragments(found.pixel[chosen], found.face[chosen], found.barycentric[chosen])
