"""USD of a fitted sequence: a mesh whose points are time-sampled, one sample per frame,
written through ``usd-core`` (the optional extra ``elastocap[usd]``).

USD keeps a layer in memory until it is saved, so a long take is written as value clips
(USD's own answer to long caches): the frames go into clip layers of
:data:`CLIP_FRAMES` frames each (``<take>_clips/<first frame>.usdc``), each saved and
dropped before the next, and ``<take>.usd`` holds the topology, the stage
metadata (metres, +Y up, the frame rate) and the clip set that stitches them. Memory does
not grow with the take's length. Time codes are frame numbers;
``timeCodesPerSecond`` is the capture's frame rate. ``usdcat --flatten <take>.usd``
gives a single file when wanted.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np

from elastocap._core import InvalidInputError
from elastocap._io import atomic_write
from elastocap.pipeline.export.sequence import MeshSequence
from elastocap.pipeline.export.settings import ExportSettings

__all__ = ["CLIP_FRAMES", "write_usd"]

#: Frames per clip layer: what one layer holds in memory while it is written.
CLIP_FRAMES = 100
_MESH = "surface"


def _pxr() -> Any:
    try:
        from pxr import Sdf, Usd, UsdGeom, Vt
    except ImportError:
        raise InvalidInputError("USD export needs usd-core: pip install 'elastocap[usd]'") from None
    return Sdf, Usd, UsdGeom, Vt


def write_usd(path: str | Path, sequence: MeshSequence, settings: ExportSettings) -> Path:
    """Write ``sequence`` as ``path`` (``.usd``) plus its clip layers in
    ``<stem>_clips/``; returns ``path``.

    Raises
    ------
    InvalidInputError
        usd-core is not installed.
    """
    Sdf, Usd, UsdGeom, Vt = _pxr()
    path = Path(path)
    root = Sdf.Path(f"/{_prim_name(settings.take)}")
    mesh_path = root.AppendChild(_MESH)
    clips_dir = path.with_name(f"{path.stem}_clips")
    # A rerun replaces the clips; the top layer, renamed into place last, names only these.
    staging = path.with_name(f".{path.stem}_clips.tmp")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)

    manifest = Sdf.Layer.CreateNew(str(staging / "manifest.usda"))
    _declare(Sdf, manifest, mesh_path)
    manifest.Save()
    chunks: list[tuple[int, str]] = []
    layer, first = None, None
    for index, (frame, vertices) in enumerate(sequence):
        if index % CLIP_FRAMES == 0:
            if layer is not None:
                layer.Save()
            first = frame
            name = f"{frame:06d}.usdc"
            layer = Sdf.Layer.CreateNew(str(staging / name))
            points_attr, extent_attr = _declare(Sdf, layer, mesh_path)
            chunks.append((frame, name))
        assert layer is not None and first is not None
        points = settings.space.points(vertices).astype(np.float32)
        layer.SetTimeSample(points_attr, float(frame), Vt.Vec3fArray.FromNumpy(points))
        layer.SetTimeSample(extent_attr, float(frame), Vt.Vec3fArray.FromNumpy(np.stack([points.min(axis=0), points.max(axis=0)])))
    assert layer is not None
    layer.Save()
    del layer

    def write(tmp: Path) -> None:
        stage = Usd.Stage.CreateNew(str(tmp.with_suffix(".usda")))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        stage.SetTimeCodesPerSecond(settings.fps)
        stage.SetFramesPerSecond(settings.fps)
        stage.SetStartTimeCode(float(sequence.frames[0]))
        stage.SetEndTimeCode(float(sequence.frames[-1]))
        xform = UsdGeom.Xform.Define(stage, root)
        stage.SetDefaultPrim(xform.GetPrim())
        mesh = UsdGeom.Mesh.Define(stage, mesh_path)
        faces = np.asarray(sequence.faces, dtype=np.int32)
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, dtype=np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1)))
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
        # No default points or extent here: opinions in this layer would be stronger than
        # the clips' time samples (USD's value resolution) and hide them.
        clips = Usd.ClipsAPI(mesh.GetPrim())
        relative = f"./{clips_dir.name}"
        clips.SetClipAssetPaths(Sdf.AssetPathArray([Sdf.AssetPath(f"{relative}/{name}") for _, name in chunks]))
        clips.SetClipPrimPath(str(mesh_path))
        clips.SetClipActive([(float(start), float(i)) for i, (start, _) in enumerate(chunks)])
        # Stage time = clip time (frame numbers in both).
        clips.SetClipTimes([(float(sequence.frames[0]), float(sequence.frames[0])), (float(sequence.frames[-1]), float(sequence.frames[-1]))])
        clips.SetClipManifestAssetPath(Sdf.AssetPath(f"{relative}/manifest.usda"))
        stage.GetRootLayer().Save()
        # The layer was written as text under a .usda name; .usd accepts either encoding.
        tmp.with_suffix(".usda").replace(tmp)

    # The clips go in place first: composing the clip set while it is authored opens them,
    # and a clip that is missing then stays missing for the process.
    shutil.rmtree(clips_dir, ignore_errors=True)
    staging.replace(clips_dir)
    try:
        atomic_write(path, write)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return path


def _declare(Sdf: Any, layer: Any, mesh_path: Any) -> tuple[Any, Any]:
    """The mesh's time-varying attributes in ``layer`` (an ``over``): points and extent."""
    prim = Sdf.CreatePrimInLayer(layer, mesh_path)
    prim.specifier = Sdf.SpecifierOver
    points = Sdf.AttributeSpec(prim, "points", Sdf.ValueTypeNames.Point3fArray)
    extent = Sdf.AttributeSpec(prim, "extent", Sdf.ValueTypeNames.Float3Array)
    return points.path, extent.path


def _prim_name(take: str) -> str:
    """``take`` as a USD prim name (letters, digits, underscores, not starting with a digit)."""
    name = "".join(c if c.isalnum() or c == "_" else "_" for c in take)
    return name if name and not name[0].isdigit() else f"take_{name}"
