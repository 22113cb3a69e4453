"""Calibration files: one module per format, and the one place that tells them apart.

================  =========================================  ==============================
format            files                                      module
================  =========================================  ==============================
``easymocap``     ``intri.yml`` + ``extri.yml``              :mod:`.easymocap`
``json``          ``rig.json`` (elastocap's own)             :mod:`.rig_json`
``middlebury``    ``*_par.txt``                              :mod:`.middlebury`
``colmap``        ``cameras.txt`` + ``images.txt``           :mod:`.colmap`
``colmap-binary`` ``cameras.bin`` + ``images.bin``           :mod:`.colmap_binary`
``anipose``       ``calib.toml`` (Anipose, Pose2Sim)         :mod:`.anipose`
``opencv-stereo`` ``*.yml|yaml|xml`` with M1 D1 M2 D2 R T    :mod:`.opencv_stereo`
``nerf``          ``transforms.json`` (NeRF, nerfstudio)     :mod:`.nerf`
================  =========================================  ==============================

Readers return unvalidated :class:`CameraRecord` s, which :class:`elastocap.Rig` turns
into cameras (validating them, with ``where`` in the message). :meth:`elastocap.Rig.load`
and :meth:`elastocap.Rig.save` are the public entry points.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

from elastocap._core import InvalidInputError
from elastocap.cameras.formats import (
    anipose,
    colmap,
    colmap_binary,
    easymocap,
    middlebury,
    nerf,
    opencv_stereo,
    rig_json,
)
from elastocap.cameras.formats.common import IMAGE_SUFFIXES, CameraRecord

if TYPE_CHECKING:
    from elastocap.cameras.camera import Camera

__all__ = ["FORMATS", "IMAGE_SUFFIXES", "CameraRecord", "detect", "read", "write"]

# name -> (reader, writer, what the reader takes: "folder" or "file", the file a folder gets)
FORMATS: dict[str, tuple[Callable[..., list[CameraRecord]], Callable[..., None], str, str]] = {
    "easymocap": (easymocap.read, easymocap.write, "folder", ""),
    "json": (rig_json.read, rig_json.write, "file", "rig.json"),
    "middlebury": (middlebury.read, middlebury.write, "file", "rig_par.txt"),
    "colmap": (colmap.read, colmap.write, "folder", ""),
    "colmap-binary": (colmap_binary.read, colmap_binary.write, "folder", ""),
    "anipose": (anipose.read, anipose.write, "file", "calib.toml"),
    "opencv-stereo": (opencv_stereo.read, opencv_stereo.write, "file", "stereo.yml"),
    "nerf": (nerf.read, nerf.write, "file", "transforms.json"),
}

_YAML_SUFFIXES = (".yml", ".yaml", ".xml")


def _folder_format(folder: Path) -> tuple[str, Path]:
    """The calibration in a folder, by the first of these found: EasyMocap, rig.json,
    COLMAP text, COLMAP binary (also in ``sparse/0/`` or ``sparse/``), calib.toml (or a
    single ``Calib*.toml``), transforms.json, a single ``*_par.txt``, OpenCV's
    intrinsics.yml + extrinsics.yml."""
    if (folder / "intri.yml").exists() or (folder / "extri.yml").exists():
        return "easymocap", folder
    if (folder / "rig.json").exists():
        return "json", folder / "rig.json"
    for sub in (folder, folder / "sparse" / "0", folder / "sparse"):
        if (sub / "cameras.txt").exists() and (sub / "images.txt").exists():
            return "colmap", sub
        if (sub / "cameras.bin").exists() and (sub / "images.bin").exists():
            return "colmap-binary", sub
    tomls = [folder / "calib.toml"] if (folder / "calib.toml").exists() else sorted(folder.glob("[Cc]alib*.toml"))
    if len(tomls) > 1:
        raise InvalidInputError(f"{folder} holds several calibration files ({', '.join(p.name for p in tomls)}): pass one")
    if tomls:
        return "anipose", tomls[0]
    if (folder / "transforms.json").exists():
        return "nerf", folder / "transforms.json"
    par = sorted(folder.glob("*_par.txt"))
    if len(par) > 1:
        raise InvalidInputError(
            f"{folder} holds several Middlebury files ({', '.join(p.name for p in par)}): pass one of them"
        )
    if par:
        return "middlebury", par[0]
    if all((folder / name).exists() for name in opencv_stereo.SAMPLE_FILES):
        return "opencv-stereo", folder
    raise FileNotFoundError(
        f"no calibration in {folder}: expected intri.yml + extri.yml, rig.json, a COLMAP model "
        "(cameras.txt + images.txt, or .bin), calib.toml, transforms.json, a *_par.txt or "
        "intrinsics.yml + extrinsics.yml"
    )


def _file_format(path: Path) -> tuple[str, Path]:
    """The format of an existing calibration file."""
    name, suffix = path.name, path.suffix.lower()
    if name in ("intri.yml", "extri.yml"):
        return "easymocap", path.parent
    if name in ("cameras.txt", "images.txt", "points3D.txt"):
        return "colmap", path.parent
    if suffix == ".bin":
        return "colmap-binary", path.parent
    if name in opencv_stereo.SAMPLE_FILES:
        return "opencv-stereo", path.parent
    if suffix == ".json":
        if "transforms" in name:
            return "nerf", path
        return "json", path
    if suffix == ".txt":
        return "middlebury", path
    if suffix == ".toml":
        return "anipose", path
    if suffix in _YAML_SUFFIXES:
        return "opencv-stereo", path
    raise InvalidInputError(
        f"path {path}: not a calibration this reads (a folder, intri.yml / extri.yml, rig.json, "
        "transforms.json, a COLMAP cameras.txt / .bin, calib.toml, a stereo .yml, or a *_par.txt)"
    )


def detect(path: Path, fmt: str | None = None) -> tuple[str, Path]:
    """``(format, what its reader takes)`` for an existing ``path``; ``fmt`` forces the
    format."""
    if not path.exists():
        raise FileNotFoundError(f"calibration not found: {path} does not exist")
    if fmt is not None:
        _check_format(fmt)
        kind, default = FORMATS[fmt][2], FORMATS[fmt][3]
        if kind == "folder":
            return fmt, path if path.is_dir() else path.parent
        return fmt, path / default if path.is_dir() else path
    return _folder_format(path) if path.is_dir() else _file_format(path)


def _check_format(fmt: Any) -> None:
    if fmt not in FORMATS:
        raise InvalidInputError(f"format must be one of {', '.join(FORMATS)}, got {fmt!r}")


def read(path: Path, size: tuple[int, int] | None, fmt: str | None = None) -> list[CameraRecord]:
    """The cameras of the calibration at ``path`` (see :meth:`elastocap.Rig.load`)."""
    found, target = detect(path, fmt)
    if found == "json" and target.is_file() and _looks_like_nerf(target):
        found = "nerf"
    return FORMATS[found][0](target, size)


def _looks_like_nerf(file: Path) -> bool:
    head = file.read_text(errors="replace")[:100_000]
    return '"frames"' in head and '"cameras"' not in head


def output_format(path: Path, fmt: str | None = None) -> tuple[str, Path]:
    """``(format, what its writer takes)`` for writing to ``path``: ``fmt`` when given,
    else from the name (see :meth:`elastocap.Rig.save`)."""
    if fmt is not None:
        _check_format(fmt)
        kind, default = FORMATS[fmt][2], FORMATS[fmt][3]
        if kind == "folder":
            return fmt, path.parent if path.suffix in (".txt", ".bin", ".yml") else path
        return fmt, path / default if not path.suffix else path
    name, suffix = path.name, path.suffix.lower()
    if name in ("intri.yml", "extri.yml"):
        return "easymocap", path.parent
    if name in ("cameras.txt", "images.txt"):
        return "colmap", path.parent
    if name in ("cameras.bin", "images.bin"):
        return "colmap-binary", path.parent
    if suffix == ".json":
        return ("nerf" if "transforms" in name else "json"), path
    if suffix == ".txt":
        return "middlebury", path
    if suffix == ".toml":
        return "anipose", path
    if suffix in _YAML_SUFFIXES:
        return "opencv-stereo", path
    # Anything else is a folder (whose name may hold a dot) for EasyMocap's pair of files.
    return "easymocap", path


def write(path: Path, cameras: Sequence[Camera], fmt: str | None = None, **options: Any) -> tuple[str, Path]:
    """Write ``cameras`` to ``path``; returns ``(format, what was written)``."""
    found, target = output_format(path, fmt)
    if options and found not in ("colmap", "colmap-binary"):
        raise InvalidInputError(f"options {sorted(options)} apply to the COLMAP formats only, not {found}")
    FORMATS[found][1](target, cameras, **options)
    return found, target
