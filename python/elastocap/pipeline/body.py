"""The body stage behind ``elastocap body``: track the default human through a capture's
silhouettes and stereo points, one shape for the take."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from elastocap._core import InvalidInputError
from elastocap._io import load_npz, save_bytes, save_image, save_mesh
from elastocap.body.fit import BodyObservations
from elastocap.body.model import Z_UP_TO_WORLD, BodyModel, BodyState
from elastocap.body.track import BodyTracker
from elastocap.body.tracks import SequentialAnchors
from elastocap.capture.folder import Capture
from elastocap.hull.grid import check_baseline
from elastocap.pipeline.hull import with_masks
from elastocap.pipeline.pictures import contact_sheet
from elastocap.render import render_silhouette
from elastocap.tracking.tracks import load_tracks

__all__ = ["run_body_stage"]



def _stereo_points(out: Path, frame: int) -> tuple[NDArray[np.float64], NDArray[np.float64] | None] | None:
    """Points of ``out/points/<frame>.npz`` (``points (N, 3)``, optional ``sigma (N,)``
    metres) and tracked points of ``out/tracks/<frame>.npz`` (``positions``, NaN where not
    tracked, ``covariances (N, 3, 3)``), world frame; None when neither exists."""
    found = []
    path = out / "points" / f"{frame:06d}.npz"
    if path.exists():
        data = load_npz(path, required=("points",))
        points = np.asarray(data["points"], dtype=np.float64).reshape(-1, 3)
        sigma = np.asarray(data["sigma"], dtype=np.float64).reshape(-1) if "sigma" in data else np.full(len(points), 0.005)
        found.append((points, sigma))
    path = out / "tracks" / f"{frame:06d}.npz"
    if path.exists():
        data = load_npz(path, required=("positions",))
        positions = np.asarray(data["positions"], dtype=np.float64).reshape(-1, 3)
        ok = np.isfinite(positions).all(axis=1)
        if "covariances" in data:
            cov = np.asarray(data["covariances"], dtype=np.float64).reshape(-1, 3, 3)
            sigma = np.sqrt(np.maximum(np.trace(cov, axis1=1, axis2=2) / 3, 1e-8))
        else:
            sigma = np.full(len(positions), 0.005)
        ok &= np.isfinite(sigma)
        found.append((positions[ok], sigma[ok]))
    if not found:
        return None
    return np.concatenate([p for p, _ in found]), np.concatenate([s for _, s in found])


def run_body_stage(
    capture: Capture | str | Path,
    out: str | Path,
    *,
    frames: Iterable[int] | None = None,
    max_rays_per_mask: int = 300,
    tracks: bool = True,
    progress: bool = True,
) -> Path:
    """Track the default human through a capture and write ``out/body/``: ``fit.json``
    (the take's one shape, joint angles per frame, fit quality), ``<frame>.ply`` (skin
    meshes, world units) and ``out/body_views.png`` (the first frame's skin over the camera
    images or masks). A finished ``fit.json`` makes a rerun a no-op.

    Observations: the silhouettes (``CAPTURE/masks``, else ``OUT/masks`` from
    ``elastocap silhouettes``), stereo points (``OUT/points``) and tracked points
    (``OUT/tracks``) when present, each weighted by its precision.
    :class:`~elastocap.body.track.BodyTracker` does the fitting: a global pose search on
    the first frame, constant-velocity prediction after it, one shape fitted over the first
    frames. A subject the model cannot explain is refused (``InvalidInputError``).

    With ``tracks`` (default) and ``OUT/tracks`` present, tracked points are also
    correspondences: each is attached to the body part it lies on at the first frame
    where it is tracked and pulls that part's point in the later frames
    (:class:`~elastocap.body.tracks.SequentialAnchors`); ``fit.json`` says how many
    (``tracks_attached``, 0 without).

    Each frame's state is saved as it finishes (``out/body/frames/<frame>.json``, written
    atomically), so a run that was stopped resumes after the last frame saved.
    """
    out = Path(out)
    cap = with_masks(capture if isinstance(capture, Capture) else Capture.open(capture), out)
    wanted = list(cap.frames if frames is None else frames)
    if not wanted:
        raise InvalidInputError(f"{cap} has no frames to fit (its masks/ or images/ folders hold no frame files)")
    check_baseline(cap.rig)
    has_points = (out / "points").is_dir() or (out / "tracks").is_dir()
    if not cap.has_masks and not has_points:
        raise InvalidInputError(f"{cap} has no masks/ folder, nor OUT/masks, OUT/points or OUT/tracks: the body stage needs silhouettes or points")
    result_file = out / "body" / "fit.json"
    if result_file.exists():
        return result_file
    # Before any fitting: an output folder that cannot be made stops the stage at once.
    result_file.parent.mkdir(parents=True, exist_ok=True)
    model = BodyModel.default_human()
    names = cap.rig.names
    cameras = {n: cap.rig[n].replace(R=cap.rig[n].R @ Z_UP_TO_WORLD) for n in names}
    tracker = BodyTracker(model, cameras=[cameras[n] for n in names], rays_per_mask=max_rays_per_mask)
    settings = {"max_rays_per_mask": max_rays_per_mask, "cameras": names, "model": model.to_dict(), "tracker": 1}
    anchors = None
    if tracks and any((out / "tracks").glob("[0-9]*.npz")):
        anchors = SequentialAnchors(model, load_tracks(out), Z_UP_TO_WORLD)
    picture_images: dict[str, NDArray[np.uint8]] | None = None
    attached = 0
    for frame in tqdm(wanted, desc="body", unit="frame", disable=not progress):
        masks = cap.masks(frame) if cap.has_masks else None
        if picture_images is None and cap.has_images:
            # The picture's images, read before any fitting (after the first masks, whose
            # errors come first): a bad image stops the stage at once, not after the fit.
            picture_images = {name: cap.image(name, wanted[0]) for name in names}
        stereo = _stereo_points(out, frame)
        observed = BodyObservations(
            masks=None if masks is None else [masks[n] for n in names],
            points=None if stereo is None else stereo[0] @ Z_UP_TO_WORLD,
            point_sigma=None if stereo is None else stereo[1],
            anchored=None if anchors is None else anchors.observations(frame),
        )
        saved = _load_frame_state(out, frame, settings, model)
        if saved is not None:
            tracker.resume(observed, saved)
            state = saved
        else:
            state = tracker.update(observed)
            _save_frame_state(out, frame, settings, state)
        if anchors is not None:
            attached += anchors.attach(frame, state)
    track = tracker.result()
    (out / "body").mkdir(parents=True, exist_ok=True)
    meshes = []
    for frame, state in zip(wanted, track.states):
        mesh = model.skin_mesh(state, spacing=0.015)
        mesh.vertices = mesh.vertices @ Z_UP_TO_WORLD.T
        save_mesh(out / "body" / f"{frame:06d}.ply", mesh)
        meshes.append(mesh)
    views = []
    for name in names:
        silhouette = render_silhouette(meshes[0], cap.rig[name])
        if picture_images is not None:
            base = picture_images[name]
        else:
            base = np.repeat((cap.mask(name, wanted[0]) * 160).astype(np.uint8)[..., None], 3, axis=2)
        view = base.astype(np.float64)
        view[silhouette] = 0.55 * view[silhouette] + 0.45 * np.array([40.0, 220.0, 90.0])
        views.append(view.round().astype(np.uint8))
    save_image(out / "body_views.png", contact_sheet(views, names))
    record = {
        "frames": wanted,
        "parts": model.part_names,
        "shape": model.shape_table(track.shape),
        "shape_vector": track.shape.tolist(),
        "motion_names": model.motion_names,
        "motion": track.motion.tolist(),
        "frame": "z-up body frame; world = R_body_to_world @ x",
        "R_body_to_world": Z_UP_TO_WORLD.tolist(),
        "quality": [{"median_distance": q.median_distance, "explained": q.explained, "observations": q.observations} for q in track.quality],
        "searched": track.searched,
        "observed": track.observed,
        "tracks_attached": attached,
    }
    save_bytes(result_file, json.dumps(record, indent=1).encode())
    return result_file


def _frame_state_path(out: Path, frame: int) -> Path:
    return out / "body" / "frames" / f"{frame:06d}.json"


def _save_frame_state(out: Path, frame: int, settings: dict[str, Any], state: BodyState) -> None:
    record = {"frame": frame, "settings": settings, "shape": state.shape.tolist(), "motion": state.motion.tolist()}
    path = _frame_state_path(out, frame)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_bytes(path, json.dumps(record).encode())


def _load_frame_state(out: Path, frame: int, settings: dict[str, Any], model: BodyModel) -> BodyState | None:
    """The state a previous run saved for ``frame`` with the same settings, else None."""
    path = _frame_state_path(out, frame)
    if not path.exists():
        return None
    try:
        record = json.loads(path.read_text())
        if record.get("settings") != json.loads(json.dumps(settings)):
            return None
        state = BodyState(np.array(record["shape"], dtype=float), np.array(record["motion"], dtype=float))
        model.check_state(state)
    except (ValueError, KeyError, TypeError, InvalidInputError):
        return None
    return state
