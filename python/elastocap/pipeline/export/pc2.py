"""Point caches for Blender's Mesh Cache modifier: PC2 (vertex positions per frame) with an
OBJ of the rest mesh whose vertex order the cache follows.

The PC2 layout (little-endian)::

    char  signature[12]   "POINTCACHE2\\0"
    int32 version         1
    int32 numPoints
    float startFrame
    float sampleRate      frames between samples
    int32 numSamples
    float32 xyz[numSamples][numPoints][3]

Written frame by frame: memory does not grow with the take's length. PC2 stores frames,
not seconds: the animation plays at the scene's frame rate. Both files are in export
space (metres, +Y up, like glTF). In Blender (checked with 3.4): import the OBJ with its
default axes (forward -Z, up Y: the importer turns the object, not the vertices), add a
Mesh Cache modifier with format PC2 and leave its axes at their defaults; every frame's
vertices then match the fit to float32 precision.
"""

from __future__ import annotations

import io
import struct
from pathlib import Path

import numpy as np

from elastocap._io import atomic_write
from elastocap.pipeline.export.sequence import MeshSequence, frame_step
from elastocap.pipeline.export.settings import ExportSettings

__all__ = ["PC2_SIGNATURE", "write_obj", "write_pc2"]

PC2_SIGNATURE = b"POINTCACHE2\0"


def write_pc2(path: str | Path, sequence: MeshSequence, settings: ExportSettings) -> Path:
    """Write the vertices of every frame of ``sequence`` as a PC2 point cache; returns
    ``path`` (written atomically).

    ``startFrame`` is the first frame number and ``sampleRate`` the step between frames.

    Raises
    ------
    InvalidInputError
        The frames are not evenly spaced (a point cache has one sample rate).
    """
    path = Path(path)
    step = frame_step(sequence.frames, "a PC2 point cache")
    header = PC2_SIGNATURE + struct.pack(
        "<iiffi", 1, sequence.n_vertices, float(sequence.frames[0]), float(step), len(sequence.frames)
    )

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            f.write(header)
            for _, vertices in sequence:
                f.write(settings.space.points(vertices).astype("<f4").tobytes())

    atomic_write(path, write)
    return path


def write_obj(path: str | Path, sequence: MeshSequence, settings: ExportSettings) -> Path:
    """Write the rest mesh of ``sequence`` as a Wavefront OBJ (vertices in the order of the
    point cache, triangles counter-clockwise from outside); returns ``path``."""
    path = Path(path)
    vertices = settings.space.points(sequence.rest)
    buffer = io.BytesIO()
    buffer.write(f"# elastocap rest mesh of {settings.take}: {len(vertices)} vertices, metres, +Y up\no {settings.take}\n".encode())
    np.savetxt(buffer, vertices, fmt="v %.9g %.9g %.9g")
    np.savetxt(buffer, np.asarray(sequence.faces) + 1, fmt="f %d %d %d")
    atomic_write(path, lambda tmp: tmp.write_bytes(buffer.getvalue()))
    return path
