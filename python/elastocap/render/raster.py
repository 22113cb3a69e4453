"""Vectorised triangle rasterisation: coverage and a z-buffer, sampled at pixel centres.

Used by :mod:`elastocap.synth.capture` to render exact silhouettes and shaded images of meshes.
Pixel ``(u, v)`` = (column, row) has its centre at integer coordinates (DESIGN
conventions), so a pixel is covered by a projected triangle when its centre lies inside it.

Why not ``cv2.fillPoly``: given several polygons in one call it fills by the even-odd rule
(a pixel covered by two overlapping triangles is left empty), so the union of a mesh's
overlapping projected triangles cannot be drawn in one call; one call per triangle costs a
Python loop over tens of thousands of faces. The fragments are found in Rust
(``rust/raster.rs``), bit for bit what the earlier numpy version found (every candidate
pixel of every triangle's bounding box tested at once), ~10x faster
(benches/README.md, session 12).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

import elastocap._core as _core


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
    uv = np.ascontiguousarray(uv, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    pixel, face, barycentric = _core.raster_fragments(uv, faces, int(width), int(height))
    return Fragments(pixel=pixel, face=face, barycentric=barycentric)


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
