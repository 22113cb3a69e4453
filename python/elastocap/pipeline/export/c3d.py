"""Joint trajectories as a .c3d file (the biomechanics standard) through ezc3d: one point
per body part at its joint, metres (``POINT:UNITS = "m"``), +Y up.

ezc3d builds the whole file in memory: ``32 P`` bytes per frame (``P`` parts, 16 for the
default human), small next to the meshes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from elastocap._core import InvalidInputError
from elastocap._io import atomic_write
from elastocap.pipeline.export.sequence import frame_step
from elastocap.pipeline.export.settings import ExportSettings
from elastocap.pipeline.export.skeleton import SkeletonTake

__all__ = ["write_c3d"]


def write_c3d(path: str | Path, take: SkeletonTake, settings: ExportSettings) -> Path:
    """Write the joint positions of every frame of ``take``; returns ``path`` (atomic).

    Raises
    ------
    InvalidInputError
        The frames are not evenly spaced (a .c3d file has one point rate), or ezc3d is
        not installed.
    """
    try:
        import ezc3d
    except ImportError:
        raise InvalidInputError("C3D export needs ezc3d: pip install ezc3d") from None
    path = Path(path)
    step = frame_step(take.frames, "a .c3d file")
    points = np.ones((4, len(take.names), len(take.frames)))
    for k, (_, _, origins) in enumerate(take.poses(settings.space)):
        points[:3, :, k] = origins.T
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [settings.fps / step]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = list(take.names)
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["m"]
    c3d["header"]["points"]["first_frame"] = take.frames[0]
    c3d["data"]["points"] = points

    def write(tmp: Path) -> None:
        # ezc3d adds ".c3d" to a name that does not end with it.
        named = tmp.with_name(tmp.name + ".c3d")
        try:
            c3d.write(str(named))
            named.replace(tmp)
        finally:
            named.unlink(missing_ok=True)

    atomic_write(path, write)
    return path
