"""Per-pixel textured rendering of the capsule figure, ground-truth depth and the material
surface points of the textured synthetic capture (:mod:`elastocap.synth.textured`).

Every sub-pixel of an ``n x n`` grid per pixel is rasterised into a z-buffer against the
ground-truth mesh, its 3-D surface point found (perspective-correct barycentric
interpolation), and coloured by :meth:`CapsuleFigure.surface_colours` there: the texture is
evaluated per sub-pixel on the body, not interpolated between mesh vertices, so it is as sharp
in the image as the pattern is and fixed to each body part in every view. Shading is
Lambertian (view-independent), so a surface point has the same colour in every camera that
sees it, up to the sensor noise and the pixel's footprint.
"""

from __future__ import annotations

import numpy as np
import trimesh
from numpy.typing import NDArray

from elastocap.cameras import Camera
from elastocap.render import raster as _raster
from elastocap.render.mesh import AMBIENT, DEFAULT_LIGHT, project_mesh
from elastocap.synth.capsules import CapsuleFigure

__all__ = [
    "MATERIAL_TOLERANCE", "VISIBILITY_TOLERANCE", "material_mask", "material_points", "render_textured",
    "seed_material_points",
]

# A surface point counts as visible in a camera when one of the 2 x 2 pixel centres around
# its projection sees the surface within this depth of it (metres). Limbs are several
# centimetres thick, so an occluder is always further in front than this; surfaces seen at
# grazing angles (where depth changes by more than this per pixel) count as not visible.
VISIBILITY_TOLERANCE = 0.01

# A surface point is material in a frame when the texture seen at its truth position is the
# one it carried in frame 0: the same part's pattern, at pattern coordinates within this
# distance (metres; 0.1 mm is 0.02 px at 640 x 480 from 3 m). Away from the joints the
# truth is exact (distance 0); within the blend of two capsules the correction onto the
# blended surface slides it by up to centimetres, and the renderer's nearest-part choice
# can switch to the neighbouring part's pattern.
MATERIAL_TOLERANCE = 1e-4


def subpixel_camera(camera: Camera, n: int) -> Camera:
    """The camera whose pixels are ``camera``'s ``n x n`` sub-pixels: sub-pixel ``(i, j)`` of
    pixel ``(u, v)`` has its centre at ``(u - 1/2 + (i + 1/2) / n, v - 1/2 + (j + 1/2) / n)``,
    i.e. ``u' = n u + (n - 1) / 2`` (an exact change of pixel coordinates after the lens)."""
    scale = np.array([[n, 0.0, (n - 1) / 2], [0.0, n, (n - 1) / 2], [0.0, 0.0, 1.0]])
    return camera.replace(K=scale @ camera.K, width=camera.width * n, height=camera.height * n)


def _surface_hits(
    mesh: trimesh.Trimesh, camera: Camera
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """The nearest front-facing surface at every covered pixel centre of ``camera``:
    ``(flat pixel index (M,), world point (M, 3), interpolated unit normal (M, 3))``."""
    uv, depth, faces = project_mesh(mesh, camera)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    front = np.flatnonzero(np.einsum("ij,ij->i", np.cross(b - a, c - a), camera.center - a) > 0)
    found = _raster.fragments(uv, faces[front], camera.width, camera.height)
    drawn = _raster.nearest(found, depth, faces[front])
    corners = faces[front][drawn.face]
    # Perspective-correct barycentrics: screen-space weights divided by vertex depth.
    weights = drawn.barycentric / depth[corners]
    weights /= weights.sum(axis=1, keepdims=True)
    points = np.einsum("mk,mkd->md", weights, vertices[corners])
    normals = np.einsum("mk,mkd->md", weights, np.asarray(mesh.vertex_normals, dtype=np.float64)[corners])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    return drawn.pixel, points, normals


def render_textured(
    mesh: trimesh.Trimesh,
    figure: CapsuleFigure,
    frame: int,
    camera: Camera,
    background: NDArray[np.uint8],
    *,
    supersample: int,
    noise: float,
    rng: np.random.Generator,
) -> tuple[NDArray[np.uint8], NDArray[np.bool_], NDArray[np.float32]]:
    """One view of the textured figure.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The figure's ground-truth surface at ``frame`` (:meth:`CapsuleFigure.mesh`).
    figure : CapsuleFigure
    frame : int
    camera : Camera
    background : (H, W, 3) uint8
        The empty scene, RGB.
    supersample : int
        Sub-pixels per pixel along each axis.
    noise : float
        Standard deviation of the Gaussian sensor noise, grey levels (0 for none).
    rng : numpy.random.Generator
        Draws the noise.

    Returns
    -------
    image : (H, W, 3) uint8
        RGB: the mean of the sub-pixels' colours (figure or background), plus noise.
    mask : (H, W) bool
        The figure's silhouette at pixel centres.
    depth : (H, W) float32
        Depth along the optical axis (``z`` in the camera frame, metres) of the figure's
        surface seen at each pixel centre; NaN off the figure.
    """
    n = supersample
    width, height = camera.width, camera.height
    sub = subpixel_camera(camera, n)
    pixel, points, normals = _surface_hits(mesh, sub)
    light = np.asarray(DEFAULT_LIGHT, dtype=np.float64)
    light /= np.linalg.norm(light)
    shade = AMBIENT + (1 - AMBIENT) * np.maximum(normals @ light, 0.0)
    colour = figure.surface_colours(points, frame).astype(np.float64) * shade[:, None]
    # Sub-pixel (row r, column c) -> its pixel; the background fills the sub-pixels missed.
    row, column = np.divmod(pixel, width * n)
    owner = (row // n) * width + column // n
    total = np.zeros((height * width, 3))
    np.add.at(total, owner, colour)
    hits = np.bincount(owner, minlength=height * width).astype(np.float64)
    image = (total + (n * n - hits)[:, None] * background.reshape(-1, 3)) / (n * n)
    if noise > 0:
        image += rng.normal(0.0, noise, image.shape)
    picture = np.clip(np.rint(image), 0, 255).astype(np.uint8).reshape(height, width, 3)

    centre_pixel, centre_points, _ = _surface_hits(mesh, camera)
    flat = np.full(height * width, np.nan, dtype=np.float32)
    flat[centre_pixel] = camera.to_camera(centre_points)[:, 2]
    depth = flat.reshape(height, width)
    return picture, np.isfinite(depth), depth


def seed_material_points(
    figure: CapsuleFigure, count: int, *, spacing: float, seed: int
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """``count`` material points of the figure's surface, uniform by area on frame 0's mesh.

    Returns
    -------
    part : (N,) int64
        The body part (index into :data:`~elastocap.synth.capsules.PARTS`) each point is
        fixed to: the nearest capsule at frame 0.
    local : (N, 3) float64
        The point in its part's frame (metres): ``R_part^T (X - start_part)``, the frame the
        texture pattern is fixed in.
    """
    mesh = figure.mesh(0, spacing)
    points, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    points = np.asarray(points, dtype=np.float64)
    part = np.argmin(figure.part_distances(points, 0), axis=1).astype(np.int64)
    c = figure.capsules(0)
    local = np.einsum("nji,nj->ni", c.frames[part], points - c.starts[part])
    return part, local


def material_points(
    figure: CapsuleFigure, frame: int, part: NDArray[np.int64], local: NDArray[np.float64], *, iterations: int = 4
) -> NDArray[np.float64]:
    """The material points at ``frame``: moved rigidly with their part, then put back on the
    surface (the zero level of :meth:`CapsuleFigure.sdf`) by Newton steps along the
    field's gradient.

    The smooth blend between parts deforms near the joints, so a point moved rigidly with
    its part can sit off the surface by up to a few millimetres there; the correction moves
    it along the normal only, keeping its place on the body. Returns ``(N, 3)`` float64,
    world, metres.
    """
    c = figure.capsules(frame)
    X = c.starts[part] + np.einsum("nij,nj->ni", c.frames[part], local)
    step = 1e-5
    for _ in range(iterations):
        f = figure.sdf(X, frame)
        offsets = np.eye(3) * step
        gradient = np.stack(
            [(figure.sdf(X + o, frame) - figure.sdf(X - o, frame)) / (2 * step) for o in offsets], axis=1
        )
        X = X - (f / np.maximum(np.einsum("ij,ij->i", gradient, gradient), 1e-12))[:, None] * gradient
    return X


def material_mask(
    figure: CapsuleFigure, frame: int, part: NDArray[np.int64], local: NDArray[np.float64], points: NDArray[np.float64]
) -> NDArray[np.bool_]:
    """``(N,) bool``: which truth points ``points`` (their :func:`material_points` at
    ``frame``) show the texture they were seeded on (:data:`MATERIAL_TOLERANCE`).

    The renderer colours a surface point with the pattern of its nearest capsule, in that
    capsule's frame (:meth:`CapsuleFigure.surface_colours`); a truth point is material when
    that capsule is still its ``part`` and its coordinates there are still ``local``.
    """
    c = figure.capsules(frame)
    nearest = np.argmin(figure.part_distances(points, frame), axis=1)
    coordinates = np.einsum("nji,nj->ni", c.frames[part], points - c.starts[part])
    return (nearest == part) & (np.linalg.norm(coordinates - local, axis=1) <= MATERIAL_TOLERANCE)


def visible_points(
    points: NDArray[np.float64], camera: Camera, depth: NDArray[np.float32]
) -> NDArray[np.bool_]:
    """``(N,) bool``: which points ``camera`` sees, given its depth map ``(H, W)``.

    A point is visible when it projects inside the image, in front of the camera, and one of
    the four pixel centres around its projection sees the surface within
    :data:`VISIBILITY_TOLERANCE` of the point's depth.
    """
    seen = camera.visible(points)
    uv, z = camera.project(points)
    out = np.zeros(len(points), dtype=bool)
    if not seen.any():
        return out
    u0 = np.floor(uv[seen, 0]).astype(np.int64)
    v0 = np.floor(uv[seen, 1]).astype(np.int64)
    close = np.zeros(int(seen.sum()), dtype=bool)
    for du in (0, 1):
        for dv in (0, 1):
            u = np.clip(u0 + du, 0, camera.width - 1)
            v = np.clip(v0 + dv, 0, camera.height - 1)
            d = depth[v, u].astype(np.float64)
            with np.errstate(invalid="ignore"):
                close |= np.abs(d - z[seen]) <= VISIBILITY_TOLERANCE
    out[seen] = close
    return out
