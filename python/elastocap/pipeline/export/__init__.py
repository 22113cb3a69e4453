"""Animation files of a capture's output folder, behind ``elastocap export OUT --format F``:
``OUT/export/<take>.<ext>``, in metres with +Y up at the capture's frame rate.

========  ==============================================  =============================
format    what                                            from
========  ==============================================  =============================
glb       rest mesh, one morph target per frame, weights  the elastic fit (``fit/``)
pc2       point cache + ``<take>.obj`` rest mesh          the elastic fit
usd       time-sampled points (value clips), usd-core     the elastic fit
bvh       skeleton and joint rotations per frame          the body fit (``body/fit.json``)
trc, c3d  joint trajectories                              the body fit
========  ==============================================  =============================

Every writer but GLB's and C3D's streams (one frame in memory at a time); the GLB writer
streams too, but a viewer holds every target (see :mod:`.gltf`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

from elastocap._core import InvalidInputError
from elastocap.pipeline.export.bvh import write_bvh
from elastocap.pipeline.export.c3d import write_c3d
from elastocap.pipeline.export.gltf import write_glb
from elastocap.pipeline.export.pc2 import write_obj, write_pc2
from elastocap.pipeline.export.sequence import MeshSequence, load_fitted_sequence
from elastocap.pipeline.export.settings import ExportSettings, ExportSpace, FrameRateWarning, export_settings
from elastocap.pipeline.export.skeleton import SkeletonTake, load_body_take
from elastocap.pipeline.export.trc import write_trc
from elastocap.pipeline.export.usd import write_usd

__all__ = [
    "BODY_FORMATS",
    "FORMATS",
    "MESH_FORMATS",
    "ExportSettings",
    "ExportSpace",
    "FrameRateWarning",
    "MeshSequence",
    "SkeletonTake",
    "export_settings",
    "export_take",
    "load_body_take",
    "load_fitted_sequence",
]

#: Formats of the elastic fit's mesh sequence.
MESH_FORMATS = ("glb", "pc2", "usd")
#: Formats of the body fit's skeleton.
BODY_FORMATS = ("bvh", "trc", "c3d")
FORMATS = MESH_FORMATS + BODY_FORMATS
_MESH_WRITERS: dict[str, Callable[[Path, MeshSequence, ExportSettings], Path]] = {"glb": write_glb, "pc2": write_pc2, "usd": write_usd}
_BODY_WRITERS: dict[str, Callable[[Path, SkeletonTake, ExportSettings], Path]] = {"bvh": write_bvh, "trc": write_trc, "c3d": write_c3d}


def export_take(out: str | Path, formats: Iterable[str], settings: ExportSettings | None = None) -> list[Path]:
    """Write the animation files of the output folder ``out`` into ``out/export/``.

    Parameters
    ----------
    out : path
        An output folder of the capture stages (``fit/`` and ``model/`` for the mesh
        formats, ``body/fit.json`` for the skeleton formats).
    formats : iterable of str
        Any of :data:`FORMATS`.
    settings : ExportSettings, optional
        Default: :func:`export_settings` of ``out``.

    Returns
    -------
    list of Path
        The files written (``pc2`` writes the ``.obj`` rest mesh too).

    Raises
    ------
    InvalidInputError
        An unknown format; frames a format cannot hold (uneven steps for a cache).
    FileNotFoundError
        The stage a format needs has not run.
    """
    out = Path(out)
    wanted = list(dict.fromkeys(formats))
    unknown = [f for f in wanted if f not in FORMATS]
    if unknown:
        raise InvalidInputError(f"unknown export format(s) {unknown}: choose from {', '.join(FORMATS)}")
    settings = export_settings(out) if settings is None else settings
    folder = out / "export"
    written: list[Path] = []
    if any(f in MESH_FORMATS for f in wanted):
        sequence = load_fitted_sequence(out)
        for fmt in (f for f in wanted if f in MESH_FORMATS):
            if fmt == "pc2":
                written.append(write_obj(folder / f"{settings.take}.obj", sequence, settings))
            written.append(_MESH_WRITERS[fmt](folder / f"{settings.take}.{fmt}", sequence, settings))
    if any(f in BODY_FORMATS for f in wanted):
        take = load_body_take(out)
        for fmt in (f for f in wanted if f in BODY_FORMATS):
            written.append(_BODY_WRITERS[fmt](folder / f"{settings.take}.{fmt}", take, settings))
    return written
