"""The fitted sequence as the exports see it: one rest mesh and, per frame, the positions of
its vertices (one fixed topology), read from the fit stage's files one frame at a time.

``OUT/model/rest.npz`` gives the surface (``surface_nodes``, ``surface_faces``) and the rest
positions of the nodes; ``OUT/fit/<frame:06d>.npz`` each frame's node positions. A surface
vertex ``i`` is node ``surface_nodes[i]`` (as in :meth:`ElasticModel.surface_at`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError

__all__ = ["MeshSequence", "frame_step", "load_fitted_sequence", "vertex_normals"]


@dataclass(frozen=True)
class MeshSequence:
    """Meshes of one topology over frames, read lazily.

    Attributes
    ----------
    frames : list of int
        Frame numbers, ascending.
    faces : (F, 3) int64
        Triangles, indices into the vertices, counter-clockwise seen from outside.
    rest : (V, 3) float64
        The rest mesh's vertices (world units): what morph targets and point caches move.
    read : callable
        ``read(frame) -> (V, 3) float64``: the vertices of one frame (world units).
    """

    frames: list[int]
    faces: NDArray[np.int64]
    rest: NDArray[np.float64]
    read: Callable[[int], NDArray[np.float64]]

    @property
    def n_vertices(self) -> int:
        """Vertices of every mesh of the sequence."""
        return len(self.rest)

    def __iter__(self) -> Iterator[tuple[int, NDArray[np.float64]]]:
        """``(frame, vertices)`` in frame order, one frame in memory at a time."""
        for frame in self.frames:
            vertices = np.asarray(self.read(frame), dtype=np.float64)
            if vertices.shape != self.rest.shape:
                raise InvalidInputError(
                    f"frame {frame} has vertices of shape {vertices.shape}, the rest mesh {self.rest.shape}: "
                    "a sequence has one topology"
                )
            yield frame, vertices


def load_fitted_sequence(out: str | Path) -> MeshSequence:
    """The elastic fit written by the fit stage into ``out``.

    Raises
    ------
    FileNotFoundError
        No ``out/model/rest.npz`` or no fitted frame in ``out/fit/``.
    """
    out = Path(out)
    model_file = out / "model" / "rest.npz"
    if not model_file.exists():
        raise FileNotFoundError(f"no elastic model in {out} ({model_file} is missing): run the fit stage first")
    with np.load(model_file, allow_pickle=False) as data:
        surface_nodes = np.asarray(data["surface_nodes"], dtype=np.int64)
        surface_faces = np.asarray(data["surface_faces"], dtype=np.int64)
        rest = np.asarray(data["nodes"], dtype=np.float64)[surface_nodes]
    local = np.full(int(surface_nodes.max()) + 1, -1, dtype=np.int64)
    local[surface_nodes] = np.arange(len(surface_nodes))
    faces = np.ascontiguousarray(local[surface_faces])
    # A frame is fitted when both of its files exist (the stage writes the .npz first).
    frames = sorted(
        int(path.stem) for path in (out / "fit").glob("*.npz") if path.stem.isdigit() and path.with_suffix(".ply").exists()
    )
    if not frames:
        raise FileNotFoundError(f"no fitted frame in {out / 'fit'}: run the fit stage first")

    def read(frame: int) -> NDArray[np.float64]:
        with np.load(out / "fit" / f"{frame:06d}.npz", allow_pickle=False) as data:
            return np.asarray(data["positions"], dtype=np.float64)[surface_nodes]

    return MeshSequence(frames=frames, faces=faces, rest=rest, read=read)


def frame_step(frames: list[int], what: str) -> int:
    """The constant step between ``frames`` (1 for a single frame).

    Raises
    ------
    InvalidInputError
        The frames are not evenly spaced (``what`` names the format that needs it).
    """
    steps = np.unique(np.diff(frames))
    if len(steps) > 1:
        gaps = [(a, b) for a, b in zip(frames, frames[1:]) if b - a != steps.min()][:3]
        raise InvalidInputError(f"{what} needs evenly spaced frames; the sequence jumps at {gaps}")
    return int(steps[0]) if len(steps) else 1


def vertex_normals(vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> NDArray[np.float64]:
    """``(V, 3)`` unit vertex normals: the sum of the adjacent faces' area-weighted normals,
    normalised (a vertex on no face gets (0, 0, 0))."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    face_normals = np.cross(b - a, c - a)  # length = twice the area: area weighting for free
    normals = np.zeros_like(vertices)
    for k in range(3):
        for axis in range(3):
            normals[:, axis] += np.bincount(faces[:, k], weights=face_normals[:, axis], minlength=len(vertices))
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.asarray(np.divide(normals, length, out=np.zeros_like(normals), where=length > 0))
