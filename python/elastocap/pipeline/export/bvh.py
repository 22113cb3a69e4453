"""BVH (Biovision hierarchy) of the body fit: the body model's parts as joints with fixed
bone offsets (one shape for the take), the root's position and every joint's rotation per
frame, in metres with +Y up.

The BVH rest pose is the body model's rest pose (every joint angle zero) with every joint
frame aligned to the export axes, as BVH readers expect: a joint's channels rotate its
bones away from that pose. Rotation channels are ``Zrotation Xrotation Yrotation``
(intrinsic, ``R = Rz Rx Ry``), degrees. Frames are written one at a time.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from elastocap._io import atomic_write
from elastocap.pipeline.export.sequence import frame_step
from elastocap.pipeline.export.settings import ExportSettings
from elastocap.pipeline.export.skeleton import SkeletonTake

__all__ = ["write_bvh"]

_ORDER = "ZXY"
_ROTATION_CHANNELS = "Zrotation Xrotation Yrotation"


def _hierarchy(take: SkeletonTake, settings: ExportSettings) -> str:
    names, parents = take.names, take.parents
    _, rest_origins = take.rest_pose(settings.space)
    ends = take.end_sites(settings.space)
    children: dict[int, list[int]] = {i: [] for i in range(len(names))}
    for i, p in enumerate(parents):
        if p >= 0:
            children[p].append(i)
    lines = ["HIERARCHY"]

    def joint(i: int, depth: int) -> None:
        pad = "\t" * depth
        if parents[i] < 0:
            lines.append(f"{pad}ROOT {names[i]}")
            offset = np.zeros(3)
            channels = f"6 Xposition Yposition Zposition {_ROTATION_CHANNELS}"
        else:
            lines.append(f"{pad}JOINT {names[i]}")
            offset = rest_origins[i] - rest_origins[parents[i]]
            channels = f"3 {_ROTATION_CHANNELS}"
        lines.extend([f"{pad}{{", f"{pad}\tOFFSET {offset[0]:.6f} {offset[1]:.6f} {offset[2]:.6f}", f"{pad}\tCHANNELS {channels}"])
        for child in children[i]:
            joint(child, depth + 1)
        if i in ends:
            end = ends[i]
            lines.extend([f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {end[0]:.6f} {end[1]:.6f} {end[2]:.6f}", f"{pad}\t}}"])
        lines.append(f"{pad}}}")

    for root in (i for i, p in enumerate(parents) if p < 0):
        joint(root, 0)
    return "\n".join(lines) + "\n"


def _depth_first(parents: list[int]) -> list[int]:
    """Joint order of the hierarchy as written (BVH channels follow it)."""
    order: list[int] = []

    def visit(i: int) -> None:
        order.append(i)
        for child in (c for c, p in enumerate(parents) if p == i):
            visit(child)

    for root in (i for i, p in enumerate(parents) if p < 0):
        visit(root)
    return order


def _channels(rotations: NDArray[np.float64], origins: NDArray[np.float64], rest: NDArray[np.float64],
              parents: list[int], order: list[int]) -> NDArray[np.float64]:
    """One frame's channel values: root position, then each joint's local Euler angles."""
    # Joint frames aligned with the export axes at rest: B = R R_rest^T.
    bone = rotations @ np.swapaxes(rest, 1, 2)
    parent_bone = np.stack([np.eye(3) if p < 0 else bone[p] for p in parents])
    local = np.swapaxes(parent_bone, 1, 2) @ bone
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # gimbal lock: any decomposition is exact
        angles = Rotation.from_matrix(local[order]).as_euler(_ORDER, degrees=True)
    root = order[0]
    return np.concatenate([origins[root], angles.reshape(-1)])


def write_bvh(path: str | Path, take: SkeletonTake, settings: ExportSettings) -> Path:
    """Write the body fit ``take`` as BVH; returns ``path`` (written atomically).

    Raises
    ------
    InvalidInputError
        The frames are not evenly spaced (BVH has one frame time).
    """
    path = Path(path)
    step = frame_step(take.frames, "BVH")
    rest, _ = take.rest_pose(settings.space)
    parents = take.parents
    order = _depth_first(parents)
    header = _hierarchy(take, settings) + f"MOTION\nFrames: {len(take.frames)}\nFrame Time: {step / settings.fps:.8f}\n"

    def write(tmp: Path) -> None:
        with open(tmp, "w", encoding="ascii", newline="\n") as f:
            f.write(header)
            for _, rotations, origins in take.poses(settings.space):
                row = io.StringIO()
                np.savetxt(row, _channels(rotations, origins, rest, parents, order)[None], fmt="%.6f")
                f.write(row.getvalue())

    atomic_write(path, write)
    return path
