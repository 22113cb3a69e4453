"""GLB (binary glTF 2.0) of a fitted sequence: the rest mesh with one morph target per frame
and an animation of the morph weights at the capture's frame rate.

Each target holds the frame's position deltas from the rest mesh and its normal deltas; the
weights animation has one key per frame, the frame's target at weight 1 and every other at
0, with STEP interpolation, so that at frame ``f``'s time the mesh is exactly frame ``f``
(``t = (f - first frame) / fps`` seconds).

Memory: the writer streams (it reads the frames twice, once for the bounds glTF requires of
every POSITION accessor, once to write), but a viewer holds all targets: ``24 V`` bytes per
frame (float32 position and normal deltas) plus the dense weights ``4 N^2`` bytes. For long
takes use the point caches (PC2, USD), which stream on both sides.

Blender's importer (checked with 3.4) turns the targets into shape keys and the weights into
constant-interpolated keys at ``t x`` the scene's frame rate: set the scene to the capture's
rate to see frame ``f`` at Blender frame ``f - first``.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pygltflib as gltf
from numpy.typing import NDArray

from elastocap._io import atomic_write
from elastocap.pipeline.export.sequence import MeshSequence, vertex_normals
from elastocap.pipeline.export.settings import ExportSettings

__all__ = ["write_glb"]

_MAGIC, _VERSION = 0x46546C67, 2  # "glTF"
_JSON, _BIN = 0x4E4F534A, 0x004E4942
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


def _frame_arrays(
    vertices: NDArray[np.float64], sequence: MeshSequence, settings: ExportSettings, rest: NDArray[np.float64], rest_normals: NDArray[np.float64]
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Position and normal deltas of one frame in export space, float32."""
    position = settings.space.points(vertices)
    normals = settings.space.directions(vertex_normals(vertices, sequence.faces))
    # Deltas in float64 then rounded once: rest + delta reproduces the frame to float32's
    # precision of the delta, not of the absolute position.
    return (position - rest).astype(np.float32), (normals - rest_normals).astype(np.float32)


def write_glb(path: str | Path, sequence: MeshSequence, settings: ExportSettings, *, name: str | None = None) -> Path:
    """Write ``sequence`` as a GLB with one morph target per frame; returns ``path``.

    Parameters
    ----------
    path : path
        The ``.glb`` file, written atomically.
    sequence : MeshSequence
        The meshes (world units), e.g. :func:`load_fitted_sequence`.
    settings : ExportSettings
        Frame rate and the map to metres, +Y up.
    name : str, optional
        Name of the node and mesh (default: ``settings.take``).

    Notes
    -----
    glTF 2.0, section 3.7.2.2 (morph targets): ``POSITION`` and ``NORMAL`` targets are
    displacements added to the base attributes, weighted by the node's weights, which the
    animation channel (path ``"weights"``) sets per key. Target names are in
    ``mesh.extras.targetNames`` (the convention Blender and three.js read).
    """
    path = Path(path)
    name = settings.take if name is None else name
    n_frames, n_vertices = len(sequence.frames), sequence.n_vertices
    rest = settings.space.points(sequence.rest)
    rest_normals = settings.space.directions(vertex_normals(sequence.rest, sequence.faces))

    # Pass 1: the bounds of every target's position deltas (glTF requires them).
    bounds = []
    for _, vertices in sequence:
        delta = settings.space.points(vertices) - rest
        bounds.append((delta.min(axis=0).astype(np.float32), delta.max(axis=0).astype(np.float32)))

    indices = np.ascontiguousarray(sequence.faces, dtype=np.uint32)
    vector_bytes = 12 * n_vertices
    sizes = [indices.nbytes, vector_bytes, vector_bytes] + [2 * vector_bytes] * n_frames + [4 * n_frames, 4 * n_frames * n_frames]
    offsets = np.concatenate([[0], np.cumsum(sizes)]).tolist()
    views = [gltf.BufferView(buffer=0, byteOffset=offsets[0], byteLength=sizes[0], target=_ELEMENT_ARRAY_BUFFER)]
    views += [gltf.BufferView(buffer=0, byteOffset=offsets[i], byteLength=sizes[i], target=_ARRAY_BUFFER) for i in range(1, 3 + n_frames)]
    views += [gltf.BufferView(buffer=0, byteOffset=offsets[i], byteLength=sizes[i]) for i in (3 + n_frames, 4 + n_frames)]
    rest32 = rest.astype(np.float32)

    def vec3(view: int, offset: int = 0, lo: NDArray[np.float32] | None = None, hi: NDArray[np.float32] | None = None) -> gltf.Accessor:
        accessor = gltf.Accessor(bufferView=view, byteOffset=offset, componentType=gltf.FLOAT, count=n_vertices, type=gltf.VEC3)
        if lo is not None and hi is not None:
            accessor.min, accessor.max = lo.tolist(), hi.tolist()
        else:
            accessor.min = accessor.max = None
        return accessor

    accessors = [
        gltf.Accessor(bufferView=0, componentType=gltf.UNSIGNED_INT, count=indices.size, type=gltf.SCALAR, min=None, max=None),
        vec3(1, lo=rest32.min(axis=0), hi=rest32.max(axis=0)),
        vec3(2),
    ]
    targets = []
    for f, (lo, hi) in enumerate(bounds):
        targets.append(gltf.Attributes(POSITION=len(accessors), NORMAL=len(accessors) + 1))
        accessors += [vec3(3 + f, 0, lo, hi), vec3(3 + f, vector_bytes)]
    times = ((np.asarray(sequence.frames) - sequence.frames[0]) / settings.fps).astype(np.float32)
    time_accessor = len(accessors)
    accessors.append(
        gltf.Accessor(bufferView=3 + n_frames, componentType=gltf.FLOAT, count=n_frames, type=gltf.SCALAR,
                      min=[float(times.min())], max=[float(times.max())])
    )
    accessors.append(
        gltf.Accessor(bufferView=4 + n_frames, componentType=gltf.FLOAT, count=n_frames * n_frames, type=gltf.SCALAR, min=None, max=None)
    )
    document = gltf.GLTF2(
        asset=gltf.Asset(version="2.0", generator="elastocap"),
        scene=0,
        scenes=[gltf.Scene(nodes=[0])],
        nodes=[gltf.Node(mesh=0, name=name)],
        meshes=[
            gltf.Mesh(
                name=name,
                primitives=[gltf.Primitive(attributes=gltf.Attributes(POSITION=1, NORMAL=2), indices=0, mode=gltf.TRIANGLES, targets=targets)],
                weights=[0.0] * n_frames,
                extras={"targetNames": [f"frame_{f:06d}" for f in sequence.frames]},
            )
        ],
        accessors=accessors,
        bufferViews=views,
        buffers=[gltf.Buffer(byteLength=offsets[-1])],
        animations=[
            gltf.Animation(
                name=f"{name} at {settings.fps:g} fps",
                samplers=[gltf.AnimationSampler(input=time_accessor, output=time_accessor + 1, interpolation=gltf.ANIM_STEP)],
                channels=[gltf.AnimationChannel(sampler=0, target=gltf.AnimationChannelTarget(node=0, path="weights"))],
            )
        ],
        extras={"fps": settings.fps, "frames": [sequence.frames[0], sequence.frames[-1]], "metres_per_unit": 1.0, "up": "+Y"},
    )
    text = document.to_json(separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary_length = offsets[-1]  # every part is a multiple of 4 bytes

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            f.write(struct.pack("<III", _MAGIC, _VERSION, 12 + 8 + len(text) + 8 + binary_length))
            f.write(struct.pack("<II", len(text), _JSON))
            f.write(text)
            f.write(struct.pack("<II", binary_length, _BIN))
            f.write(indices.tobytes())
            f.write(rest32.tobytes())
            f.write(rest_normals.astype(np.float32).tobytes())
            # Pass 2: the targets, one frame in memory at a time.
            for _, vertices in sequence:
                for delta in _frame_arrays(vertices, sequence, settings, rest, rest_normals):
                    f.write(delta.tobytes())
            f.write(times.tobytes())
            _write_one_hot_weights(f, n_frames)

    atomic_write(path, write)
    return path


def _write_one_hot_weights(f: BinaryIO, n: int) -> None:
    """Key ``k``'s weights: target ``k`` at 1, the others 0; a row at a time."""
    row = np.zeros(n, dtype=np.float32)
    for k in range(n):
        row[k] = 1.0
        f.write(row.tobytes())
        row[k] = 0.0
