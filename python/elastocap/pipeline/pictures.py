"""Pictures of results a person looks at: meshes over camera images, contact sheets."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import trimesh
from numpy.typing import NDArray

from elastocap._io import save_image
from elastocap.cameras.camera import Camera
from elastocap.render import render_silhouette

__all__ = ["contact_sheet", "mesh_over_image", "save_png"]


def mesh_over_image(
    image: NDArray[np.uint8],
    mesh: trimesh.Trimesh,
    camera: Camera,
    *,
    colour: tuple[int, int, int] = (40, 220, 90),
    alpha: float = 0.45,
) -> NDArray[np.uint8]:
    """``(H, W, 3)`` RGB: ``image`` with the mesh's silhouette in ``camera`` tinted and its
    outline drawn, so that where the mesh and the image disagree is plain to see."""
    silhouette = render_silhouette(mesh, camera).astype(np.uint8)
    out = image.astype(np.float64)
    tint = np.array(colour, np.float64)
    inside = silhouette.astype(bool)
    out[inside] = (1 - alpha) * out[inside] + alpha * tint
    contours, _ = cv2.findContours(silhouette, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    result = np.ascontiguousarray(out.round().clip(0, 255).astype(np.uint8))
    cv2.drawContours(result, contours, -1, colour, 1)
    return result


def contact_sheet(
    images: Sequence[NDArray[np.uint8]], labels: Sequence[str], *, columns: int = 4, width: int = 320
) -> NDArray[np.uint8]:
    """``(H, W, 3)`` RGB: the images scaled to ``width`` pixels, labelled, in a grid."""
    tiles = []
    for image, label in zip(images, labels):
        scale = width / image.shape[1]
        tile = cv2.resize(image, (width, round(image.shape[0] * scale)), interpolation=cv2.INTER_AREA)
        cv2.putText(tile, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(tile)
    height = max(t.shape[0] for t in tiles)
    tiles = [np.pad(t, ((0, height - t.shape[0]), (0, 0), (0, 0))) for t in tiles]
    blank = np.zeros_like(tiles[0])
    rows = [
        np.concatenate(tiles[i : i + columns] + [blank] * (columns - len(tiles[i : i + columns])), axis=1)
        for i in range(0, len(tiles), columns)
    ]
    return np.concatenate(rows, axis=0)


def save_png(path: Path, image: NDArray[np.uint8]) -> None:
    """An RGB image as PNG, atomically."""
    save_image(path.with_suffix(".png"), image)
