"""Which frame the elastic model is built from, chosen without ground truth.

The model is its rest frame's target (a visual hull) and keeps that target's errors for the
whole sequence. A carved hull only ever errs outwards: it is the intersection of the masks'
cones, so every voxel of the true body is in it and what it adds is phantom volume, the
concavities no camera sees into (an arm against the chest, the space between the legs).
Of the frames of a sequence, the one whose hull encloses the least volume therefore holds
the least phantom volume (the body keeps its volume; the phantom changes with the pose),
and its hull is the most trustworthy rest shape. Measured on the synthetic fast-motion
capture (benches/README.md, branch limbs3).

The argument needs masks that do not cut into the body: a frame whose masks miss part of it
(a hole, a limb cut off) carves a hull with less than the body's volume and would be chosen;
give the rest frame explicitly then.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import trimesh

from elastocap._core import InvalidInputError
from elastocap.hull.carve import Hull
from elastocap.hull.sdf import SDF

__all__ = ["least_volume_frame", "target_volume"]


def target_volume(target: Any) -> float:
    """The volume a 3-D target encloses, world units cubed: a :class:`Hull`'s occupied
    voxels, an :class:`SDF`'s voxels with a negative distance, a closed trimesh's volume.

    Raises
    ------
    InvalidInputError
        Another kind of target.
    """
    if isinstance(target, Hull):
        return float(np.count_nonzero(target.occupancy)) * float(target.grid.spacing) ** 3
    if isinstance(target, SDF):
        return float(np.count_nonzero(target.values < 0)) * float(target.grid.spacing) ** 3
    if isinstance(target, trimesh.Trimesh):
        return abs(float(target.volume))
    raise InvalidInputError(f"a target must be an SDF, a Hull or a trimesh.Trimesh, got {type(target).__name__}")


def least_volume_frame(targets: Sequence[Any] | Mapping[int, Any]) -> int:
    """The frame whose target encloses the least volume (the earliest of equals).

    Parameters
    ----------
    targets : sequence, or mapping of int frame number -> target
        As :func:`~elastocap.elastic.fit.fit_sequence` takes them (3-D targets); a mapping's
        keys are the frame numbers, a sequence's positions.

    Returns
    -------
    int
        A frame number of ``targets``: the rest frame with the least phantom volume (see
        the module's note).

    Raises
    ------
    InvalidInputError
        No targets; a target that is not 3-D.
    """
    frames = sorted(targets.keys()) if isinstance(targets, Mapping) else list(range(len(targets)))
    if not frames:
        raise InvalidInputError("targets is empty")
    volumes = [target_volume(targets[frame]) for frame in frames]
    return int(frames[int(np.argmin(volumes))])
