"""Silhouette rendering (``rust/raster.rs``) against OpenCV filling the projected triangles
one call each (a single ``cv2.fillPoly`` call fills by the even-odd rule and leaves holes
where triangles overlap)."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import trimesh

from elastocap.render import render_silhouette
from elastocap.synth.capture import ring_rig

from peer_cases._common import _compare


def _fill_triangles(uv: np.ndarray, faces: np.ndarray, width: int, height: int) -> np.ndarray:
    """The peer: ``cv2.fillConvexPoly`` per triangle, at 1/16 pixel precision."""
    image = np.zeros((height, width), np.uint8)
    fixed = np.round(uv * 16).astype(np.int32)
    for face in faces:
        cv2.fillConvexPoly(image, fixed[face], 1, lineType=cv2.LINE_8, shift=4)
    return image.astype(bool)


def render_cases(repeats: int) -> list[dict[str, Any]]:
    """A 20,480-face sphere over most of a 1024x768 camera (the demo's and the fits' size),
    distortion and skew included; the row also gives the IoU of the two silhouettes."""
    camera = ring_rig(8, width=1024, height=768).cameras[5]
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=0.8)
    mesh.apply_translation((0.0, 0.9, 0.0))
    faces = np.asarray(mesh.faces)
    ours = lambda: render_silhouette(mesh, camera)  # noqa: E731
    peer = lambda: _fill_triangles(camera.project(np.asarray(mesh.vertices))[0], faces, camera.width, camera.height)  # noqa: E731
    row = _compare("render_silhouette_20k_faces_1024x768", len(faces), ours, "cv2.fillConvexPoly per triangle", peer, repeats)
    a, b = ours(), peer()
    row["iou_with_peer"] = round(float((a & b).sum() / (a | b).sum()), 4)
    return [row]
