"""The body stage behind ``elastocap body``: fit the default human to a capture's
silhouettes, frame by frame, then all frames with one shared shape."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from elastocap._core import InvalidInputError
from elastocap._io import save_bytes, save_image, save_mesh
from elastocap.body.fit import BodyObservations, fit_body
from elastocap.body.model import Z_UP_TO_WORLD, BodyModel, BodyState
from elastocap.cameras import Camera, Rig
from elastocap.capture.folder import Capture
from elastocap.pipeline.pictures import contact_sheet

__all__ = ["run_body_stage"]



def _centre(masks: dict[str, NDArray[np.bool_]], cameras: Rig | dict[str, Camera]) -> NDArray[np.float64]:
    """The point nearest (least squares) to the rays through the masks' centroids."""
    a, b = np.zeros((3, 3)), np.zeros(3)
    for name, mask in masks.items():
        rows, cols = np.nonzero(mask)
        if len(rows) == 0:
            continue
        origin, direction = cameras[name].rays(np.array([[cols.mean(), rows.mean()]]))
        projector = np.eye(3) - np.outer(direction[0], direction[0])
        a += projector
        b += projector @ origin[0]
    if np.linalg.matrix_rank(a) < 3:
        raise InvalidInputError("the masks do not locate the body: fewer than two cameras see it")
    return np.asarray(np.linalg.solve(a, b), dtype=np.float64)


def run_body_stage(
    capture: Capture | str | Path,
    out: str | Path,
    *,
    frames: Iterable[int] | None = None,
    max_rays_per_mask: int = 800,
    progress: bool = True,
) -> Path:
    """Fit the default human to every frame's silhouettes and write ``out/body/``:
    ``fit.json`` (shape per part, joint angles per frame, fit status), ``<frame>.ply``
    (skin meshes, world units) and ``out/body_views.png`` (the first frame's skin over the
    camera images or masks). A finished ``fit.json`` makes a rerun a no-op.

    Each frame's own fit is saved as it finishes (``out/body/frames/<frame>.json``, written
    atomically), so a run that was stopped resumes at the first frame without one; the
    joint fit over all frames runs again from the saved states.

    The fit is local: the root starts at the point nearest to the rays through the mask
    centroids, upright, at the best of eight headings; each later frame starts from the one
    before; a last fit shares the shape over all frames.
    """
    cap = capture if isinstance(capture, Capture) else Capture.open(capture)
    if not cap.has_masks:
        raise InvalidInputError(f"{cap} has no masks/ folder: the body stage needs silhouettes")
    wanted = list(cap.frames if frames is None else frames)
    out = Path(out)
    result_file = out / "body" / "fit.json"
    if result_file.exists():
        return result_file
    model = BodyModel.default_human()
    names = cap.rig.names
    cameras = {n: cap.rig[n].replace(R=cap.rig[n].R @ Z_UP_TO_WORLD) for n in names}
    camera_list = [cameras[n] for n in names]
    frames_obs: list[BodyObservations] = []
    states: list[BodyState] = []
    options: dict[str, Any] = {"cameras": camera_list, "max_rays_per_mask": max_rays_per_mask, "sigma_ray": 0.1}
    settings = {"max_rays_per_mask": max_rays_per_mask, "cameras": names, "model": model.to_dict()}
    for i, frame in enumerate(tqdm(wanted, desc="body (per frame)", unit="frame", disable=not progress)):
        masks = cap.masks(frame)
        observed = BodyObservations(masks=[masks[n] for n in names])
        frames_obs.append(observed)
        saved = _load_frame_state(out, frame, settings, model)
        if saved is not None:
            states.append(saved)
            continue
        if i == 0:
            centre = Z_UP_TO_WORLD.T @ _centre(masks, cap.rig)
            best = None
            for heading in np.linspace(-np.pi, np.pi, 8, endpoint=False):
                start = model.rest_state(position=centre)
                start.motion[3] = heading
                trial = fit_body(model, [observed], init=start, shape=start.shape, max_iterations=30, **options)
                if best is None or trial.final_cost < best.final_cost:
                    best = trial
            assert best is not None
            fit = fit_body(model, [observed], init=best.states[0], **options)
        else:
            fit = fit_body(model, [observed], init=states[-1], shape=states[-1].shape, **options)
        states.append(fit.states[0])
        _save_frame_state(out, frame, settings, fit.states[0])
    if progress:
        print(f"body: joint fit of {len(wanted)} frame(s) with one shape", flush=True)
    joint = fit_body(model, frames_obs, init=states, **options)
    (out / "body").mkdir(parents=True, exist_ok=True)
    for frame, state in zip(wanted, joint.states):
        mesh = model.skin_mesh(state, spacing=0.015)
        mesh.vertices = mesh.vertices @ Z_UP_TO_WORLD.T
        save_mesh(out / "body" / f"{frame:06d}.ply", mesh)
    first = joint.states[0]
    views = []
    for name in names:
        silhouette = model.silhouette(first, cameras[name])
        if cap.has_images:
            base = cap.image(name, wanted[0])
        else:
            base = np.repeat((cap.mask(name, wanted[0]) * 160).astype(np.uint8)[..., None], 3, axis=2)
        view = base.astype(np.float64)
        view[silhouette] = 0.55 * view[silhouette] + 0.45 * np.array([40.0, 220.0, 90.0])
        views.append(view.round().astype(np.uint8))
    save_image(out / "body_views.png", contact_sheet(views, names))
    record = {
        "frames": wanted,
        "parts": model.part_names,
        "shape": {name: {"length": float(joint.shape[2 * b]), "width": float(joint.shape[2 * b + 1])} for b, name in enumerate(model.part_names)},
        "motion_names": model.motion_names,
        "motion": joint.motion.tolist(),
        "frame": "z-up body frame; world = R_body_to_world @ x",
        "R_body_to_world": Z_UP_TO_WORLD.tolist(),
        "status": joint.status,
        "iterations": joint.iterations,
        "final_cost": joint.final_cost,
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
