"""The fit stage of a capture, behind ``elastocap fit``: hulls (run if missing) -> an elastic
model of the rest frame's hull -> every frame fitted -> files.

Writes ``OUT/model/rest.npz`` (nodes, volumes, neighbours, surface nodes and faces, rest
frame, options), ``OUT/fit/<frame:06d>.ply`` (the fitted surface: the same vertices and
faces every frame) and ``.npz`` (node positions, the frame's metrics and the reprojection
IoU per camera), and ``OUT/metrics.json``. The reprojection IoU (the fitted surface's
silhouette against each mask, :mod:`elastocap.pipeline.reprojection`) is the failure
signal that needs no ground truth: frames where a camera's IoU drops are listed in
``metrics.json`` (``summary.iou_drops``) and named in a :class:`ReprojectionWarning`. Every write is atomic and each frame is written as soon as it is
fitted, so an interrupted run resumes without refitting finished frames (they are read
back and their neighbours start from them).
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from elastocap._core import InvalidInputError
from elastocap._io import load_npz, save_bytes, save_mesh, save_npz
from elastocap.capture.folder import Capture
from elastocap.elastic.model import ElasticModel
from elastocap.elastic.fit import FrameFit, SequenceFit, fit_sequence
from elastocap.elastic.fit_options import SilhouetteTerm
from elastocap.elastic.rest import least_volume_frame
from elastocap.elastic.tracks import select_frames
from elastocap.tracking.tracks import load_tracks
from elastocap.pipeline.hull import load_hull, run_hull_stage
from elastocap.pipeline.reprojection import CORE_IOU_FLOOR, ReprojectionWarning, iou_drops, reprojection_iou

__all__ = ["load_model", "run_fit_stage"]


def _model_path(out: Path) -> Path:
    return out / "model" / "rest.npz"


def _fit_files(out: Path, frame: int) -> tuple[Path, Path]:
    return out / "fit" / f"{frame:06d}.ply", out / "fit" / f"{frame:06d}.npz"


def load_model(out: str | Path) -> tuple[ElasticModel, int]:
    """The model written by :func:`run_fit_stage` and its rest frame (capture frame number)."""
    file = _model_path(Path(out))
    data = load_npz(file, required=("nodes", "volumes", "k", "youngs", "poisson", "rotation", "surface_nodes",
                                    "surface_faces", "rest_frame"))
    try:
        model = ElasticModel(
            data["nodes"],
            data["volumes"],
            k=int(data["k"]),
            youngs=float(data["youngs"]),
            poisson=float(data["poisson"]),
            rotation=str(data["rotation"]),
            # Models written before the penalty existed had none.
            stabilization=float(data["stabilization"]) if "stabilization" in data else 0.0,
            surface_nodes=data["surface_nodes"],
            surface_faces=data["surface_faces"],
        )
        return model, int(data["rest_frame"])
    except (ValueError, TypeError) as error:  # InvalidInputError is a ValueError too
        raise InvalidInputError(f"{file}: not an elastic model written by elastocap ({error})") from None


def run_fit_stage(
    capture: Capture | str | Path,
    out: str | Path,
    *,
    rest_frame: int | None = None,
    n_nodes: int = 2500,
    k: int = 20,
    rotation: str = "warped",
    stiffness: float = 1.0,
    silhouette: float = 0.0,
    resolution: int = 128,
    reprojection: bool = True,
    tracks: bool = True,
    progress: bool = True,
) -> SequenceFit:
    """Fit every frame of a capture; returns the fit (finished frames read back).

    Parameters
    ----------
    capture : Capture or path
        The capture folder (with masks).
    out : path
        Output folder; ``hull/`` is filled first when frames are missing there.
    rest_frame : int, optional
        Capture frame number the model is built from. Default: the frame whose hull
        encloses the least volume (:func:`~elastocap.elastic.rest.least_volume_frame`: a
        carved hull only adds phantom volume, and the model keeps its rest hull's for the
        whole sequence). Ignored when ``out/model/rest.npz`` exists (a resumed run keeps
        its model).
    n_nodes, k, rotation
        As in :meth:`ElasticModel.from_mesh`.
    stiffness, silhouette : float
        The fit's stiffness (:func:`~elastocap.elastic.fit.fit_sequence`) and the silhouette
        term's weight (:class:`~elastocap.elastic.fit_options.SilhouetteTerm`, >= 0; 0: off);
        the silhouette term uses the capture's cameras and masks. Off by default here for time, not accuracy: its
        refinement makes the fit stage about 1.55x slower (the demo's 30 frames of 8
        cameras at 1024 x 768: mean fit-to-truth 8.2 -> 7.4 mm, CPU +25%), which the
        demo's 60 s cannot take (benches/README.md, branch limbs3). Its fits are
        reproducible (two runs give the same positions bit for bit).
    resolution : int
        Voxels along the longest side of each hull.
    reprojection : bool
        Measure each fitted frame's silhouette against the masks (IoU per camera, in the
        frame's ``.npz`` and ``metrics.json``) and warn (:class:`ReprojectionWarning`)
        naming the frames where a camera's IoU drops.
    tracks : bool
        Use the tracks of ``out/tracks/`` (``elastocap track``) when there are any
        (:func:`~elastocap.elastic.fit.fit_sequence`'s ``tracks``); ``metrics.json`` says
        whether they were used (``summary.tracks``: the number of tracks, 0 without).
    progress : bool
        Show progress bars.
    """
    # Checked before the hull stage runs (a negative weight is refused by name).
    term = SilhouetteTerm(weight=silhouette)
    cap = capture if isinstance(capture, Capture) else Capture.open(capture)
    out = Path(out)
    frames = list(cap.frames)
    run_hull_stage(cap, out, resolution=resolution, progress=progress)
    if _model_path(out).exists():
        model, rest = load_model(out)
    else:
        rest = least_volume_frame(_LazyHulls(out, frames)) if rest_frame is None else int(rest_frame)
        if rest not in frames:
            raise InvalidInputError(f"rest frame {rest} is not in the capture (it has {frames[0]}..{frames[-1]})")
        model = ElasticModel.from_mesh(load_hull(out, rest).mesh(), n_nodes=n_nodes, k=k, rotation=rotation)
        save_npz(
            _model_path(out),
            nodes=model.nodes,
            volumes=model.volumes,
            neighbors=model.neighbors,
            surface_nodes=model.surface_nodes,
            surface_faces=model.surface_faces,
            rest_frame=np.int64(rest),
            k=np.int64(model.k),
            youngs=np.float64(model.youngs),
            poisson=np.float64(model.poisson),
            rotation=np.str_(model.rotation),
            stabilization=np.float64(model.stabilization),
        )
    done: dict[int, np.ndarray] = {}
    done_metrics: dict[int, dict[str, Any]] = {}
    for frame in frames:
        ply, npz = _fit_files(out, frame)
        if ply.exists() and npz.exists():
            data = load_npz(npz, required=("positions",))
            positions = data["positions"]
            if positions.shape != model.nodes.shape or not np.isfinite(positions).all():
                raise InvalidInputError(
                    f"{npz}: positions {positions.shape} are not the {model.nodes.shape} finite node positions of "
                    f"the model in {_model_path(out)}: remove it (or the output folder) to refit"
                )
            done[frame] = positions
            done_metrics[frame] = {key: value.item() for key, value in data.items() if value.ndim == 0}
    bar = tqdm(total=len(frames), initial=len(done), desc="fit", unit="frame", disable=not progress)

    def write(fit: FrameFit) -> None:
        ply, npz = _fit_files(out, fit.frame)
        surface = model.surface_at(fit.positions)
        figures = {key: np.asarray(value) for key, value in fit.metrics.items()}
        if reprojection:
            found = reprojection_iou(surface, cap.rig, cap.masks(fit.frame))
            figures["reprojection_iou"] = np.array([found[name].iou for name in cap.rig.names])
            figures["reprojection_core_iou"] = np.array([found[name].core_iou for name in cap.rig.names])
        save_npz(npz, positions=fit.positions, **figures)
        save_mesh(ply, surface)
        bar.update(1)

    targets = _LazyHulls(out, frames)
    masks = _LazyMasks(cap) if term.weight else None
    tracked = None
    if tracks and any((out / "tracks").glob("[0-9]*.npz")):
        tracked = select_frames(load_tracks(out), frames)
    result = fit_sequence(model, targets, rest_frame=rest, stiffness=stiffness, silhouette=term,
                          cameras=cap.rig.cameras, masks=masks, done=done, callback=write, tracks=tracked)
    bar.close()
    # Frames fitted before an interruption come back with their positions only: their
    # figures are in their files, so a resumed run reports what an uninterrupted one does.
    for frame, metrics in done_metrics.items():
        result.fits[frame].metrics.update(metrics)
    drops = _write_metrics(out, result, cap.rig.names, 0 if tracked is None else len(tracked.ids))
    if drops:
        listed = "; ".join(f"frame {frame}: {', '.join(names)}" for frame, names in drops.items())
        warnings.warn(
            f"the fitted surface's silhouette drops away from the masks (core reprojection IoU below "
            f"{CORE_IOU_FLOOR}) in {len(drops)} frame(s), a limb lost most likely: {listed}",
            ReprojectionWarning,
            stacklevel=2,
        )
    return result


class _LazyHulls(Mapping[int, Any]):
    """The capture's hulls by frame number, loaded when the fit reaches them."""

    def __init__(self, out: Path, frames: list[int]) -> None:
        self._out, self._frames = out, frames

    def __len__(self) -> int:
        return len(self._frames)

    def __iter__(self) -> Iterator[int]:
        return iter(self._frames)

    def __getitem__(self, frame: int) -> Any:
        if frame not in self._frames:
            raise KeyError(frame)
        return load_hull(self._out, frame)


class _LazyMasks(Mapping[int, list[Any]]):
    """A capture's masks, read frame by frame, one per camera in the rig's order."""

    def __init__(self, cap: Capture) -> None:
        self._cap = cap

    def __len__(self) -> int:
        return len(self._cap.frames)

    def __iter__(self) -> Iterator[int]:
        return iter(self._cap.frames)

    def __getitem__(self, frame: int) -> list[Any]:
        masks = self._cap.masks(frame)
        # A camera without this frame (a capture read with missing="present") is left out.
        return [masks.get(name) for name in self._cap.rig.names]


def _write_metrics(out: Path, result: SequenceFit, cameras: list[str], tracks: int = 0) -> dict[int, list[str]]:
    """``OUT/metrics.json`` from the frames' files; returns the frames whose reprojection
    IoU drops (:func:`iou_drops`)."""
    per_frame = []
    cores: dict[int, dict[str, float]] = {}
    for frame in result.frames:
        _, npz = _fit_files(out, frame)
        data = load_npz(npz)
        figures: dict[str, Any] = {key: value.item() for key, value in data.items() if value.ndim == 0}
        if "reprojection_core_iou" in data and len(data["reprojection_core_iou"]) == len(cameras):
            figures["reprojection_iou"] = dict(zip(cameras, data["reprojection_iou"].tolist()))
            cores[frame] = figures["reprojection_core_iou"] = dict(zip(cameras, data["reprojection_core_iou"].tolist()))
        per_frame.append({"frame": frame, **figures})
    summary: dict[str, Any] = {"frames": len(per_frame), "rest_frame": result.rest_frame, "tracks": tracks}
    for key in ("mean_distance", "max_distance", "volume_ratio", "seconds", "iterations", "penetrating"):
        values = [f[key] for f in per_frame if key in f]
        if values:
            summary[f"{key}_mean"] = float(np.mean(values))
            summary[f"{key}_max"] = float(np.max(values))
            summary[f"{key}_min"] = float(np.min(values))
    drops = iou_drops(cores)
    if cores:
        for key in ("reprojection_iou", "reprojection_core_iou"):
            values = [x for f in per_frame if key in f for x in f[key].values()]
            summary[f"{key}_min"] = float(np.min(values))
            summary[f"{key}_median"] = float(np.median(values))
        summary["iou_drops"] = {str(frame): names for frame, names in drops.items()}
    text = json.dumps({"summary": summary, "frames": per_frame}, indent=2)
    save_bytes(out / "metrics.json", text.encode())
    return drops
