"""Joint angles per frame as a BVH motion file: :func:`write_bvh`.

BVH (Biovision hierarchy) holds one skeleton with fixed bone offsets and, per frame, the
root position and every joint's rotation as Euler angles. The body model maps onto it
directly: a BVH joint per body part, the offset of a part from its parent scaled by the
parent's shape coefficients (one shape for the whole take, as BVH requires), and each
part's local rotation (its rest rotation times its chain of 1-DoF joints) written as
``Zrotation Xrotation Yrotation`` angles in degrees. The file is y-up (the capture's world,
``Z_UP_TO_WORLD``), in metres unless ``scale`` says otherwise.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from elastocap._core import InvalidInputError
from elastocap._io import save_bytes
from elastocap._validate import as_float_array, as_positive
from elastocap.body.model import Z_UP_TO_WORLD, BodyModel, BodyState

__all__ = ["write_bvh"]

# Intrinsic z, then x, then y: BVH's ``Zrotation Xrotation Yrotation`` channel order.
_EULER = "ZXY"


def _local_rotations(model: BodyModel, state: BodyState) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per part the rotation relative to its parent (the root: relative to the y-up world)
    ``(P, 3, 3)``, and the root's world position ``(3,)``."""
    rotations, origins = model.pose(state)
    parent = model.parent
    local = np.empty_like(rotations)
    root = parent < 0
    local[root] = Z_UP_TO_WORLD @ rotations[root]
    child = ~root
    local[child] = np.einsum("pji,pjk->pik", rotations[parent[child]], rotations[child])
    return local, Z_UP_TO_WORLD @ origins[np.flatnonzero(root)[0]]


def _offsets(model: BodyModel, state: BodyState) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each part's offset in its parent's frame ``(P, 3)`` (metres, shape applied) and the
    end site of each part ``(P, 3)`` in its own frame (the far end of its farthest ball)."""
    rotations, origins = model.pose(state)
    parent = model.parent
    offsets = np.zeros_like(origins)
    child = parent >= 0
    offsets[child] = np.einsum("pji,pj->pi", rotations[parent[child]], origins[child] - origins[parent[child]])
    centres, reach = model.ball_centers(state)
    part = model.ball_part
    ends = np.zeros_like(origins)
    for p in range(len(origins)):
        local = (centres[part == p] - origins[p]) @ rotations[p]
        if len(local):
            k = int(np.argmax(local[:, 2]))
            ends[p] = local[k] + np.array([0.0, 0.0, 0.6 * reach[part == p][k]])
    return offsets, ends


def write_bvh(path: str | Path, model: BodyModel, shape: Any, states: Sequence[BodyState] | Any, fps: float, *, scale: float = 1.0) -> Path:
    """Writes a body motion as a BVH file.

    Parameters
    ----------
    path : str or Path
        The ``.bvh`` file (written atomically).
    model : BodyModel
    shape : (4 P,) array_like
        The take's one shape (BVH bones have fixed lengths); per-frame states' own shapes
        are ignored.
    states : sequence of BodyState, or (F, n_motion) array_like
        One per frame: the motion (root translation, root angles, joint angles) in the
        body stage's z-up frame.
    fps : float
        Frames per second.
    scale : float, keyword-only
        Length unit per metre (100: centimetres, what many BVH readers assume).

    Returns
    -------
    Path

    Raises
    ------
    InvalidInputError
        Wrong shape or motion lengths, no frames, non-positive ``fps`` or ``scale``.

    Notes
    -----
    Joint positions of the written file equal ``model.pose`` (mapped to the y-up world) to
    rounding: ``tests/test_body_tracker.py`` reads it back with ``bvhio``.
    """
    if not isinstance(model, BodyModel):
        raise InvalidInputError(f"model must be a BodyModel, got {type(model).__name__}")
    frame_time = 1.0 / as_positive("fps", fps)
    unit = as_positive("scale", scale)
    shape_array = model.as_shape(shape)
    if isinstance(states, np.ndarray) or (isinstance(states, Sequence) and states and not isinstance(states[0], BodyState)):
        motion = as_float_array("states", states)
        if motion.ndim != 2:
            raise InvalidInputError(f"states must be BodyStates or an (F, {model.n_motion}) array, got shape {motion.shape}")
        states = [BodyState(shape_array, m) for m in motion]
    states = [BodyState(shape_array, s.motion) for s in states]
    if not states:
        raise InvalidInputError("states must hold at least one frame")
    for s in states:
        model.check_state(s)
    offsets, ends = _offsets(model, states[0])
    names, parent = model.part_names, model.parent
    children: dict[int, list[int]] = {p: [] for p in range(len(names))}
    for p, q in enumerate(parent):
        if q >= 0:
            children[int(q)].append(p)

    lines: list[str] = ["HIERARCHY"]
    order: list[int] = []

    def number(v: float) -> str:
        return f"{v:.6f}"

    def joint(p: int, depth: int) -> None:
        pad = "  " * depth
        order.append(p)
        if parent[p] < 0:
            lines.append(f"{pad}ROOT {names[p]}")
        else:
            lines.append(f"{pad}JOINT {names[p]}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}  OFFSET {' '.join(number(unit * v) for v in offsets[p])}")
        if parent[p] < 0:
            lines.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation")
        else:
            lines.append(f"{pad}  CHANNELS 3 Zrotation Xrotation Yrotation")
        for c in children[p]:
            joint(c, depth + 1)
        if not children[p]:
            lines.append(f"{pad}  End Site")
            lines.append(f"{pad}  {{")
            lines.append(f"{pad}    OFFSET {' '.join(number(unit * v) for v in ends[p])}")
            lines.append(f"{pad}  }}")
        lines.append(f"{pad}}}")

    roots = [p for p in range(len(names)) if parent[p] < 0]
    if len(roots) != 1:
        raise InvalidInputError(f"BVH needs a model with one root part, this one has {len(roots)}")
    joint(roots[0], 0)
    lines += ["MOTION", f"Frames: {len(states)}", f"Frame Time: {frame_time:.8f}"]
    for s in states:
        local, position = _local_rotations(model, s)
        angles = Rotation.from_matrix(local[order]).as_euler(_EULER, degrees=True)
        values = [unit * v for v in position] + angles.ravel().tolist()
        lines.append(" ".join(number(v) for v in values))
    out = Path(path)
    save_bytes(out, ("\n".join(lines) + "\n").encode())
    return out
