"""Rendering meshes into cameras: projection, exact silhouettes and shaded colour images
over a given background, on the rasteriser of :mod:`elastocap.render.raster`.

A low layer (cameras and numpy only): result pictures, reports, the body stage, the
model-based silhouettes and the synthetic captures all draw with it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_float_array
from elastocap.cameras.camera import Camera
from elastocap.render import raster as _raster

__all__ = ["AMBIENT", "BACKGROUND_GREY", "DEFAULT_LIGHT", "project_mesh", "render_image", "render_mesh", "render_silhouette"]

# Grey level of render_image's default background.
BACKGROUND_GREY = 128


# Default direction towards the key light (world, y up): above, in front at yaw 0, a little
# to the side.
DEFAULT_LIGHT = (0.35, 1.0, 0.55)
# Share of the light that reaches surfaces facing away from the key light.
AMBIENT = 0.4


def project_mesh(
    mesh: trimesh.Trimesh, camera: Camera
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """The mesh's vertices in a camera: ``(uv (V, 2) float64 pixels, depth (V,) float64
    world units along the optical axis, faces (F, 3) int64)``.

    Raises
    ------
    InvalidInputError
        Not a Trimesh / Camera; a vertex used by a face is not in front of the camera, or
        lies beyond the camera's distortion fold radius (where the lens model does not
        apply).
    """
    if not isinstance(mesh, trimesh.Trimesh):
        raise InvalidInputError(f"mesh must be a trimesh.Trimesh, got {type(mesh).__name__}")
    if not isinstance(camera, Camera):
        raise InvalidInputError(f"camera must be an elastocap.Camera, got {type(camera).__name__}")
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    uv, depth = camera.project(vertices)
    if len(faces):
        used = np.zeros(len(vertices), dtype=bool)
        used[faces.ravel()] = True
        behind = int(np.count_nonzero(~(depth[used] > 0)))
        if behind:
            raise InvalidInputError(
                f"mesh: {behind} vertices are not in front of camera {camera.name!r} (depth <= 0): "
                "move the camera or clip the mesh"
            )
        ab = camera.to_camera(vertices[used])
        radius = np.hypot(ab[:, 0], ab[:, 1]) / ab[:, 2]
        if not np.all(radius < camera.fold_radius):
            raise InvalidInputError(
                f"mesh: vertices lie beyond the distortion fold radius of camera {camera.name!r}, "
                "where the lens model does not apply"
            )
    return uv, depth, faces


def render_silhouette(mesh: trimesh.Trimesh, camera: Camera) -> NDArray[np.bool_]:
    """The mesh's silhouette in a camera, exact at pixel centres.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        World coordinates; entirely in front of the camera.
    camera : Camera
        With its distortion and skew.

    Returns
    -------
    (H, W) bool
        True where the pixel centre lies inside the projection of some triangle (the
        union of all projected triangles, whatever their orientation).

    Raises
    ------
    InvalidInputError
        A vertex is not in front of the camera, or beyond its distortion fold radius.

    Notes
    -----
    Vertices are projected with :meth:`Camera.project` (distortion included); the edges
    between them are straight in the image, which for ~1 cm triangles departs from the
    curved image of a straight edge by far less than a pixel. Every pixel centre in every
    triangle's bounding box is tested at once with numpy. (``cv2.fillPoly`` given all
    triangles in one call fills by the even-odd rule, leaving holes wherever two projected
    triangles overlap, e.g. a limb in front of the body.)
    """
    return _render(mesh, camera, image=False)[0]


def render_image(
    mesh: trimesh.Trimesh,
    camera: Camera,
    *,
    light: Any = DEFAULT_LIGHT,
    background: Any = None,
) -> NDArray[np.uint8]:
    """A shaded colour image of the mesh over a background.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        World coordinates, closed and outward-oriented (back faces are culled), entirely
        in front of the camera. Vertex colours are used when present, else a light grey.
    camera : Camera
    light : (3,) array_like, default DEFAULT_LIGHT, keyword-only
        Direction towards a distant light, world coordinates (normalised here).
    background : (H, W, 3) uint8, optional, keyword-only
        What is seen where the mesh is not, RGB; default a uniform grey
        (``BACKGROUND_GREY``). The synthetic captures pass their textured room.

    Returns
    -------
    (H, W, 3) uint8
        **RGB**.

    Raises
    ------
    InvalidInputError
        As :func:`render_silhouette`; a zero or non-finite ``light``; a ``background`` of
        the wrong shape.

    Notes
    -----
    Hidden surfaces: back faces are culled, and the remaining triangles rasterised at pixel
    centres into a z-buffer (the nearest fragment per pixel, depth interpolated
    perspective-correctly). Shading is Lambertian with an ambient floor,
    ``colour * (AMBIENT + (1 - AMBIENT) max(0, n . l))``, with the vertex normals and
    colours interpolated per pixel (perspective-correct); no shadows.
    """
    image = _render(mesh, camera, image=True, silhouette=False, light=light, background=background)[1]
    assert image is not None
    return image


def render_mesh(
    mesh: trimesh.Trimesh,
    camera: Camera,
    *,
    light: Any = DEFAULT_LIGHT,
    background: Any = None,
) -> tuple[NDArray[np.bool_], NDArray[np.uint8]]:
    """Silhouette and shaded image at once, from one projection and one rasterisation:
    ``(render_silhouette(...), render_image(...))`` at the cost of about one of them."""
    mask, picture = _render(mesh, camera, image=True, light=light, background=background)
    assert picture is not None
    return mask, picture


def _render(
    mesh: trimesh.Trimesh,
    camera: Camera,
    *,
    image: bool,
    silhouette: bool = True,
    light: Any = DEFAULT_LIGHT,
    background: Any = None,
) -> tuple[NDArray[np.bool_], NDArray[np.uint8] | None]:
    """Silhouette and/or shaded image from one projection and one rasterisation."""
    uv, depth, faces = project_mesh(mesh, camera)
    width, height = camera.width, camera.height
    if image:
        direction = as_float_array("light", light).reshape(-1)
        if direction.shape != (3,) or not np.isfinite(direction).all() or not np.any(direction):
            raise InvalidInputError(f"light must be a non-zero finite 3-vector, got {light!r}")
        direction = direction / np.linalg.norm(direction)
        if background is None:
            picture = np.full((height, width, 3), BACKGROUND_GREY, dtype=np.uint8)
        else:
            picture = np.array(background, dtype=np.uint8)
            if picture.shape != (height, width, 3):
                raise InvalidInputError(f"background must have shape {(height, width, 3)}, got {picture.shape}")
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        corner = [vertices[faces[:, i]] for i in range(3)]
        front = np.einsum("ij,ij->i", np.cross(corner[1] - corner[0], corner[2] - corner[0]), camera.center - corner[0]) > 0
        # The silhouette needs every face; the picture only the front ones.
        drawn_faces = np.arange(len(faces)) if silhouette else np.flatnonzero(front)
    else:
        drawn_faces = np.arange(len(faces))
    found = _raster.fragments(uv, faces[drawn_faces], width, height)
    found = _raster.Fragments(found.pixel, drawn_faces[found.face], found.barycentric)
    mask = np.zeros(height * width, dtype=bool)
    if silhouette:
        mask[found.pixel] = True
    if not image:
        return mask.reshape(height, width), None
    if silhouette:
        keep = front[found.face]
        found = _raster.Fragments(found.pixel[keep], found.face[keep], found.barycentric[keep])
    drawn = _raster.nearest(found, depth, faces)
    corners = faces[drawn.face]  # (M, 3)
    weights = drawn.barycentric / depth[corners]
    weights /= weights.sum(axis=1, keepdims=True)
    normal = _interpolate(weights, np.asarray(mesh.vertex_normals, dtype=np.float64), corners)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    shade = AMBIENT + (1 - AMBIENT) * np.maximum(normal @ direction, 0.0)
    colour = _interpolate(weights, _vertex_colours(mesh), corners) * shade[:, None]
    picture.reshape(-1, 3)[drawn.pixel] = np.clip(np.rint(colour), 0, 255).astype(np.uint8)
    return mask.reshape(height, width), picture


def _interpolate(
    weights: NDArray[np.float64], values: NDArray[np.float64], corners: NDArray[np.int64]
) -> NDArray[np.float64]:
    """``sum_k weights[:, k] * values[corners[:, k]]``: (M, 3) weights, (V, D) values."""
    return (
        weights[:, 0, None] * values[corners[:, 0]]
        + weights[:, 1, None] * values[corners[:, 1]]
        + weights[:, 2, None] * values[corners[:, 2]]
    )


def _vertex_colours(mesh: trimesh.Trimesh) -> NDArray[np.float64]:
    visual = mesh.visual
    if isinstance(visual, trimesh.visual.ColorVisuals) and visual.kind == "vertex":
        return np.asarray(visual.vertex_colors, dtype=np.float64)[:, :3]
    return np.full((len(mesh.vertices), 3), 200.0)
