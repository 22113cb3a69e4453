"""Joint trajectories as a .trc file (the tab-separated marker format of OpenSim and
Motion Analysis): one virtual marker per body part at its joint, metres, +Y up, written a
frame at a time."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from elastocap._io import atomic_write
from elastocap.pipeline.export.sequence import frame_step
from elastocap.pipeline.export.settings import ExportSettings
from elastocap.pipeline.export.skeleton import SkeletonTake

__all__ = ["write_trc"]


def write_trc(path: str | Path, take: SkeletonTake, settings: ExportSettings) -> Path:
    """Write the joint positions of every frame of ``take``; returns ``path`` (atomic).

    The ``Frame#`` column is the capture's frame number plus one (TRC counts from 1),
    ``Time`` is seconds from the first frame.

    Raises
    ------
    InvalidInputError
        The frames are not evenly spaced (a .trc file has one data rate).
    """
    path = Path(path)
    step = frame_step(take.frames, "a .trc file")
    rate = settings.fps / step
    names = take.names
    n = len(take.frames)
    header = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{rate:.6g}\t{rate:.6g}\t{n}\t{len(names)}\tm\t{rate:.6g}\t{take.frames[0] + 1}\t{n}",
        "Frame#\tTime\t" + "\t".join(f"{name}\t\t" for name in names).rstrip("\t"),
        "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, len(names) + 1)),
        "",
    ]

    def write(tmp: Path) -> None:
        with open(tmp, "w", encoding="ascii", newline="\n") as f:
            f.write("\n".join(header) + "\n")
            for frame, _, origins in take.poses(settings.space):
                row = io.StringIO()
                np.savetxt(row, origins.reshape(1, -1), fmt="%.6f", delimiter="\t")
                time = (frame - take.frames[0]) / settings.fps
                f.write(f"{frame + 1}\t{time:.6f}\t{row.getvalue()}")

    atomic_write(path, write)
    return path
