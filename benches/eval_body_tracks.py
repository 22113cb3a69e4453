"""Issue 15, item 4 measured with the tracker's own tracks: the body stage on a textured
capture (the capsule figure, :mod:`elastocap.synth.textured`), masks alone, with the
pipeline's tracks as points, and with them as points and anchored correspondences.

The body is fitted as ``elastocap body`` fits it (:func:`elastocap.pipeline.body.run_body_stage`'s
loop, repeated here so that the tracks' use can be switched per mode and each frame timed):
one :class:`~elastocap.body.track.BodyTracker` with the stage's settings, the capture's
masks, the tracks' per-frame positions as stereo points (``_stereo_points``) and, in mode
``tracks``, :class:`~elastocap.body.tracks.SequentialAnchors` attached frame by frame to
the fitted states. ``--check-stage`` runs ``run_body_stage`` itself on the first frames and
checks the loop gives the same motion.

Modes:

- ``masks``: the silhouettes alone (what the body stage does without ``OUT/tracks``);
- ``points``: masks + the tracked positions as points (``elastocap body --no-tracks`` with
  ``OUT/tracks`` present: the stage reads them as stereo points but does not anchor them);
- ``tracks``: masks + points + anchors (``elastocap body`` with ``OUT/tracks``).

Figures per frame against the figure's truth (``eval_body_capsule.py``'s definitions):
joints RMS over elbows, wrists, knees and ankles (figure joint -> model part origin: elbow =
forearm, wrist = hand, knee = shin, ankle = foot), skin mean distance (mean of both
directions, point to triangle, against ``ground_truth/<frame>.ply``), and each limb
segment's angle error (degrees between the true and the fitted segment direction: upper arm
shoulder->elbow, forearm elbow->wrist, thigh hip->knee, shin knee->ankle; model-independent,
so no joint-angle convention is compared), CPU s per frame (``time.process_time``). A frame
"confuses a limb" when a segment is more than :data:`CONFUSED_DEGREES` off.

Run (the fit roots of ``eval_tracks_fit.py``, their tracks from ``track_points`` with the
pipeline's options spacing 5, seed_margin 3, reseed_bare 2)::

    RAYON_NUM_THREADS=1 python -W ignore benches/eval_body_tracks.py \\
        --root /tmp/lead19/fit/s1 --tracks /tmp/trackfit10/s1/tracks --modes masks,points,tracks

``--tracks OUT`` is a folder holding ``OUT/tracks/<frame>.npz`` (read only).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from elastocap.body.fit import BodyObservations
from elastocap.body.model import Z_UP_TO_WORLD, BodyModel
from elastocap.body.track import BodyTracker
from elastocap.body.tracks import SequentialAnchors
from elastocap.capture.folder import Capture
from elastocap.geometry._distance import distance_to_mesh
from elastocap.pipeline.body import _stereo_points, run_body_stage
from elastocap.synth.clutter import JOINTS
from elastocap.synth.textured import load_textured_truth
from elastocap.tracking.tracks import load_tracks

#: Body part whose origin is each ground-truth joint of the figure (eval_body_capsule.py).
JOINT_PARTS = {
    "l_elbow": "l_forearm", "r_elbow": "r_forearm", "l_wrist": "l_hand", "r_wrist": "r_hand",
    "l_knee": "l_shin", "r_knee": "r_shin", "l_ankle": "l_foot", "r_ankle": "r_foot",
}  # fmt: skip
#: Limb segments: (true start joint, true end joint, model part at the start, at the end).
SEGMENTS = {
    "l_upperarm": ("l_shoulder", "l_elbow", "l_upperarm", "l_forearm"),
    "r_upperarm": ("r_shoulder", "r_elbow", "r_upperarm", "r_forearm"),
    "l_forearm": ("l_elbow", "l_wrist", "l_forearm", "l_hand"),
    "r_forearm": ("r_elbow", "r_wrist", "r_forearm", "r_hand"),
    "l_thigh": ("l_hip", "l_knee", "l_thigh", "l_shin"),
    "r_thigh": ("r_hip", "r_knee", "r_thigh", "r_shin"),
    "l_shin": ("l_knee", "l_ankle", "l_shin", "l_foot"),
    "r_shin": ("r_knee", "r_ankle", "r_shin", "r_foot"),
}  # fmt: skip
#: A segment this far (degrees) from its true direction counts as a confused limb.
CONFUSED_DEGREES = 30.0
MODES = ("masks", "points", "tracks")


def true_joints(figure: Any, frame: int) -> dict[str, np.ndarray]:
    """The figure's joints (world metres), as ``ClutterScene.joints``."""
    capsules = figure.capsules(frame)
    index = {n: i for i, n in enumerate(capsules.names)}
    return {name: (capsules.starts if end == "start" else capsules.ends)[index[part]].copy() for name, (part, end) in JOINTS.items()}


def frame_figures(model: BodyModel, state: Any, truth_joints: dict[str, np.ndarray], surface: trimesh.Trimesh) -> dict[str, Any]:
    """Joint errors, skin distance and segment angle errors of one fitted state."""
    _, origins = model.pose(state)
    world = origins @ Z_UP_TO_WORLD.T
    at = {p: world[model.part_names.index(p)] for p in model.part_names}
    errors = [np.linalg.norm(at[p] - truth_joints[j]) for j, p in JOINT_PARTS.items()]
    skin = model.skin_mesh(state, spacing=0.01)
    skin.vertices = skin.vertices @ Z_UP_TO_WORLD.T
    d_fit = distance_to_mesh(np.asarray(skin.vertices), surface)
    d_true = distance_to_mesh(np.asarray(surface.vertices), skin)
    angles = {}
    for name, (j0, j1, p0, p1) in SEGMENTS.items():
        a, b = truth_joints[j1] - truth_joints[j0], at[p1] - at[p0]
        cos = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
        angles[name] = round(float(np.degrees(np.arccos(np.clip(cos, -1, 1)))), 1)
    return {
        "joint_rms_mm": round(1000 * float(np.sqrt(np.mean(np.square(errors)))), 1),
        "joint_max_mm": round(1000 * float(np.max(errors)), 1),
        "skin_mean_mm": round(1000 * 0.5 * float(d_fit.mean() + d_true.mean()), 2),
        "angle_deg": angles,
    }


#: The figure's capsule -> the body model's part (the figure's neck counts as the chest).
FIGURE_PARTS = {
    "pelvis": "pelvis", "abdomen": "abdomen", "chest": "chest", "neck": "chest", "head": "head",
    "upper_arm_l": "l_upperarm", "forearm_l": "l_forearm", "hand_l": "l_hand",
    "upper_arm_r": "r_upperarm", "forearm_r": "r_forearm", "hand_r": "r_hand",
    "thigh_l": "l_thigh", "shin_l": "l_shin", "foot_l": "l_foot", "thigh_r": "r_thigh", "shin_r": "r_shin", "foot_r": "r_foot",
}  # fmt: skip


def limb_of(part: str) -> str:
    """``l_arm``, ``r_leg``, ... or ``trunk``."""
    if part[:2] in ("l_", "r_"):
        return part[:2] + ("arm" if part[2:] in ("upperarm", "forearm", "hand") else "leg")
    return "trunk"


def attachment_figures(model: BodyModel, anchors: SequentialAnchors, figure: Any, frames: list[int]) -> dict[str, Any]:
    """How the attached tracks' parts compare with the figure's: each attached track's
    true part is the capsule nearest its tracked position (world) at its first tracked
    frame among ``frames`` (where it was attached). Counts by limb: tracks attached to a
    limb that lie on another limb or the trunk (``wrong``), per attached limb."""
    attached = np.flatnonzero(anchors.attached)
    rows = np.array([anchors.frames.index(f) for f in frames])
    first = rows[anchors.tracked[rows][:, attached].argmax(axis=0)]
    true_part = np.empty(len(attached), dtype=object)
    for row in np.unique(first):
        which = first == row
        world = anchors.positions[row, attached[which]] @ Z_UP_TO_WORLD.T
        names = figure.capsules(anchors.frames[row]).names
        true_part[which] = [FIGURE_PARTS[names[k]] for k in figure.part_distances(world, anchors.frames[row]).argmin(axis=1)]
    fitted = np.array([limb_of(model.part_names[p]) for p in anchors.part[attached]])
    truth = np.array([limb_of(p) for p in true_part])
    result: dict[str, Any] = {}
    for limb in ("trunk", "l_arm", "r_arm", "l_leg", "r_leg"):
        on = fitted == limb
        result[limb] = {"attached": int(on.sum()), "wrong": int((on & (truth != limb)).sum()),
                        "from": {k: int(v) for k, v in zip(*np.unique(truth[on & (truth != limb)], return_counts=True))}}
    return result


def fit_take(cap: Capture, tracks_out: Path | None, frames: list[int], mode: str, options: dict[str, Any]) -> tuple[Any, ...]:
    """``run_body_stage``'s loop (no files written): the states, CPU s per frame, the
    tracks attached, the tracker's result and the anchors (None but in mode ``tracks``)."""
    model = BodyModel.default_human()
    names = cap.rig.names
    cameras = [cap.rig[n].replace(R=cap.rig[n].R @ Z_UP_TO_WORLD) for n in names]
    tracker = BodyTracker(model, cameras=cameras, rays_per_mask=300)
    anchors = None
    if mode == "tracks":
        anchors = SequentialAnchors(model, load_tracks(tracks_out), Z_UP_TO_WORLD, **options.get("anchors", {}))
    cpu, attached = [], 0
    for frame in frames:
        masks = cap.masks(frame)
        stereo = None if mode == "masks" else _stereo_points(tracks_out, frame)  # type: ignore[arg-type]
        observed = BodyObservations(
            masks=[masks[n] for n in names],
            points=None if stereo is None else stereo[0] @ Z_UP_TO_WORLD,
            point_sigma=None if stereo is None else stereo[1],
            anchored=None if anchors is None else anchors.observations(frame),
        )
        t0 = time.process_time()
        state = tracker.update(observed)
        cpu.append(time.process_time() - t0)
        if anchors is not None:
            attached += anchors.attach(frame, state)
        print(f"# {mode} frame {frame}: {cpu[-1]:.1f} CPU s", file=sys.stderr, flush=True)
    track = tracker.result()
    return track.states, cpu, attached, track, anchors


def check_stage(root: Path, tracks_out: Path, frames: list[int]) -> None:
    """``run_body_stage`` on a scratch OUT whose tracks/ links to ``tracks_out``'s: the same
    motion as :func:`fit_take` in mode ``tracks``."""
    cap = Capture.open(root)
    scratch = Path(tempfile.mkdtemp(prefix="eval_body_tracks_"))
    try:
        (scratch / "tracks").symlink_to((tracks_out / "tracks").resolve())
        # The stage reads every frame file of OUT/tracks; the loop gets the same tracks.
        result = json.loads(run_body_stage(cap, scratch, frames=frames, progress=False).read_text())
        _, _, attached, track, _ = fit_take(cap, tracks_out, frames, "tracks", {})
        same = np.allclose(np.asarray(result["motion"]), track.motion, atol=1e-9)
        print(json.dumps({"check_stage": bool(same), "attached_stage": result["tracks_attached"], "attached_loop": attached,
                          "max_motion_difference": float(np.abs(np.asarray(result["motion"]) - track.motion).max())}), flush=True)
    finally:
        shutil.rmtree(scratch)


def run(root: Path, tracks_out: Path | None, frames: list[int], mode: str, options: dict[str, Any], label: str,
        save: Path | None = None) -> dict[str, Any]:
    cap = Capture.open(root)
    figure = load_textured_truth(root).figure
    model = BodyModel.default_human()
    states, cpu, attached, track, anchors = fit_take(cap, tracks_out, frames, mode, options)
    rows = []
    for f, state, seconds, searched in zip(frames, states, cpu, track.searched):
        surface = trimesh.load(root / "ground_truth" / f"{f:06d}.ply", process=False)
        row = {"label": label, "mode": mode, "frame": f, "fit_cpu_s": round(seconds, 2), "searched": searched}
        row |= frame_figures(model, state, true_joints(figure, f), surface)
        rows.append(row)
        print(json.dumps(row), flush=True)
    if save is not None:
        save.mkdir(parents=True, exist_ok=True)
        np.savez(save / f"{label}.npz", frames=np.array(frames), motion=track.motion, shape=track.shape, searched=np.array(track.searched),
                 attached=np.zeros(0, bool) if anchors is None else anchors.attached,
                 part=np.zeros(0, np.int64) if anchors is None else anchors.part, offset=np.zeros((0, 3)) if anchors is None else anchors.offset)
    joint = np.array([r["joint_rms_mm"] for r in rows])
    skin = np.array([r["skin_mean_mm"] for r in rows])
    angles = np.array([[r["angle_deg"][s] for s in SEGMENTS] for r in rows])
    worst = int(joint.argmax())
    summary = {
        "summary": label, "mode": mode, "root": str(root), "seed": figure.seed, "motion": figure.motion, "frames": len(frames),
        "joint_rms_mm": round(float(np.sqrt(np.mean(joint**2))), 1),
        "joint_worst_frame": [frames[worst], float(joint[worst])],
        "skin_mean_mm": round(float(skin.mean()), 2), "skin_worst_frame": [frames[int(skin.argmax())], float(skin.max())],
        "angle_mean_deg": {s: round(float(v), 1) for s, v in zip(SEGMENTS, angles.mean(axis=0))},
        "angle_max_deg": {s: float(v) for s, v in zip(SEGMENTS, angles.max(axis=0))},
        "frames_confused": int((angles > CONFUSED_DEGREES).any(axis=1).sum()),
        "frames_searched_after_first": int(sum(track.searched[1:])),
        "tracks_attached": attached,
        "cpu_s_first": round(cpu[0], 1), "cpu_s_median_tracked": round(float(np.median(cpu[1:])), 2) if len(cpu) > 1 else None,
        "cpu_s_total": round(float(np.sum(cpu)), 1), "options": options,
    }  # fmt: skip
    if anchors is not None:
        summary["attachment"] = attachment_figures(model, anchors, figure, frames)
    print(json.dumps(summary), flush=True)
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--root", type=Path, required=True, help="a textured capture (ground_truth/ with figure.json and <frame>.ply)")
    parser.add_argument("--tracks", type=Path, default=None, help="OUT folder holding OUT/tracks/<frame>.npz (read only)")
    parser.add_argument("--modes", default="masks,tracks", help=f"comma-separated, of {MODES}")
    parser.add_argument("--frames", type=int, default=None, help="the first N frames (default all)")
    parser.add_argument("--options", default="{}", help='JSON: {"anchors": {...}} keyword options of SequentialAnchors')
    parser.add_argument("--label", default="")
    parser.add_argument("--save", type=Path, default=None, help="write each mode's motion, shape and anchors to SAVE/<label>.npz")
    parser.add_argument("--check-stage", type=int, default=0, help="first run run_body_stage on this many frames and compare")
    args = parser.parse_args()
    cap = Capture.open(args.root)
    frames = list(cap.frames)[: args.frames]
    if args.check_stage:
        check_stage(args.root, args.tracks, frames[: args.check_stage])
    for mode in args.modes.split(","):
        if mode not in MODES:
            raise SystemExit(f"unknown mode {mode!r}; modes are {MODES}")
        run(args.root, args.tracks, frames, mode, json.loads(args.options), f"{args.label}{mode}", args.save)


if __name__ == "__main__":
    main()
