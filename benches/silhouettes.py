"""Model-based silhouettes in clutter (issue 16) against the peers a user would pick
without a background plate, on the same frames in the same run.

The scene is :class:`elastocap.synth.clutter.ClutterScene` (the capsule figure in clutter,
moving distractors, a lighting change). Per frame and view: elastocap's
``SilhouetteTracker`` (snakes on the disparity-filtered gradient + the body model), and as
peers ``cv2.grabCut`` initialised from the box of elastocap's projected model, OpenCV's
MOG2 fed the sequence (no plate), and subtraction of the sequence's median image. Prints
one JSON line per frame (IoU per method and view, times, body errors) and a summary line.

Run: ``python benches/silhouettes.py --frames 300 --seed 3`` (seed 1 was used to tune the
snake and loop settings; report the others).
"""

from __future__ import annotations

import argparse
import json
import time

import cv2
import numpy as np

from elastocap.body.model import Z_UP_TO_WORLD
from elastocap.geometry._distance import distance_to_mesh
from elastocap.silhouettes import clean_mask
from elastocap.silhouettes.model_based import SilhouetteTracker
from elastocap.synth.clutter import ClutterScene

#: Body part whose origin is each ground-truth joint.
JOINT_PARTS = {
    "l_elbow": "l_forearm", "r_elbow": "r_forearm", "l_wrist": "l_hand", "r_wrist": "r_hand",
    "l_knee": "l_shin", "r_knee": "r_shin", "l_ankle": "l_foot", "r_ankle": "r_foot",
}  # fmt: skip


def iou(a: np.ndarray, b: np.ndarray) -> float:
    union = (a | b).sum()
    return float((a & b).sum() / union) if union else 1.0


def grabcut(image: np.ndarray, model_mask: np.ndarray) -> np.ndarray:
    rows, cols = np.nonzero(model_mask)
    if len(rows) == 0:
        return np.zeros_like(model_mask)
    h, w = model_mask.shape
    x0, y0 = max(cols.min() - 10, 0), max(rows.min() - 10, 0)
    x1, y1 = min(cols.max() + 10, w - 1), min(rows.max() + 10, h - 1)
    mask = np.zeros((h, w), np.uint8)
    bgd, fgd = np.zeros((1, 65)), np.zeros((1, 65))
    cv2.grabCut(cv2.cvtColor(image, cv2.COLOR_RGB2BGR), mask, (int(x0), int(y0), int(x1 - x0), int(y1 - y0)), bgd, fgd, 3, cv2.GC_INIT_WITH_RECT)
    return (mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--run-frames", type=int, default=None, help="process only the first N frames of the --frames scene (its lighting schedule spans --frames)")
    parser.add_argument("--cameras", type=int, default=6)
    parser.add_argument("--size", default="480x360")
    parser.add_argument("--tracker", default="{}", help="BodyTracker options, JSON")
    parser.add_argument("--band", default="{}", help="refine_in_band options, JSON; 'false': contours only")
    parser.add_argument("--consistency", default="{}", help="consistent_silhouettes options, JSON; 'false': no multi-view check")
    parser.add_argument("--appearance", default="{}", help="appearance_silhouette options, JSON; 'false': no colour model over frames")
    parser.add_argument("--background", default="{}", help="background_outline options, JSON; 'false': no learned background")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    scene = ClutterScene(args.seed, cameras=args.cameras, size=(width, height), frames=args.frames)
    names = scene.rig.names
    started = time.perf_counter()
    frames = [scene.frame(f) for f in range(args.frames if args.run_frames is None else min(args.run_frames, args.frames))]
    render_s = time.perf_counter() - started
    median = {n: np.median(np.stack([fr.images[n] for fr in frames]), axis=0).astype(np.int16) for n in names}
    mog = {n: cv2.createBackgroundSubtractorMOG2(history=100, detectShadows=False) for n in names}
    tracker = SilhouetteTracker(scene.rig, tracker=json.loads(args.tracker), band=json.loads(args.band), consistency=json.loads(args.consistency), appearance=json.loads(args.appearance), background=json.loads(args.background))
    model = tracker.model
    rows = []
    for f, fr in enumerate(frames):
        before = dict(tracker.timings)
        before_cpu = dict(tracker.cpu_timings)
        t0 = time.perf_counter()
        ours = tracker.step(fr.images, disparity_masks=fr.disparity_masks, points=fr.points)
        step_s = time.perf_counter() - t0
        snake_s = tracker.timings["snakes"] - before["snakes"]
        body_s = tracker.timings["body"] - before["body"]
        band_s = tracker.timings["band"] - before["band"]
        snake_cpu = tracker.timings["snakes_cpu"] - before["snakes_cpu"]
        consistency_s = tracker.timings["consistency"] - before["consistency"]
        appearance_s = tracker.timings["appearance"] - before["appearance"]
        background_s = tracker.timings["background"] - before["background"]
        result: dict[str, object] = {"frame": f, "step_s": round(step_s, 3), "snakes_ms_per_view": round(1000 * snake_s / len(names), 1), "snakes_cpu_ms_per_view": round(1000 * snake_cpu / len(names), 1), "band_ms_per_view": round(1000 * band_s / len(names), 1), "consistency_ms_per_view": round(1000 * consistency_s / len(names), 1), "appearance_ms_per_view": round(1000 * appearance_s / len(names), 1), "background_ms_per_view": round(1000 * background_s / len(names), 1), "body_s": round(body_s, 3)}
        result["cpu_ms_per_view"] = {k: round(1000 * (v - before_cpu[k]) / len(names), 1) for k, v in tracker.cpu_timings.items()}
        methods = {"ours": ours, "first_pass": tracker.first_pass, "model": tracker.model_masks}
        t0 = time.perf_counter()
        methods["grabcut"] = {n: grabcut(fr.images[n], tracker.model_masks[n]) for n in names}
        result["grabcut_s"] = round(time.perf_counter() - t0, 3)
        methods["mog2"] = {n: clean_mask(mog[n].apply(cv2.cvtColor(fr.images[n], cv2.COLOR_RGB2BGR)) > 0) for n in names}
        methods["median"] = {n: clean_mask(np.abs(fr.images[n].astype(np.int16) - median[n]).sum(axis=2) > 40) for n in names}
        for method, masks in methods.items():
            result[method] = [round(iou(masks[n], fr.masks[n]), 4) for n in names]
        state = tracker.states[-1]
        _, origins = model.pose(state)
        world = origins @ Z_UP_TO_WORLD.T
        errors = [np.linalg.norm(world[model.part_names.index(p)] - fr.joints[j]) for j, p in JOINT_PARTS.items()]
        result["joint_rms_mm"] = round(1000 * float(np.sqrt(np.mean(np.square(errors)))), 1)
        skin = model.skin_mesh(state, spacing=0.01)
        skin.vertices = skin.vertices @ Z_UP_TO_WORLD.T
        d_fit = distance_to_mesh(np.asarray(skin.vertices), fr.surface)
        d_true = distance_to_mesh(np.asarray(fr.surface.vertices), skin)
        result["skin_mean_mm"] = round(1000 * 0.5 * (d_fit.mean() + d_true.mean()), 1)
        rows.append(result)
        print(json.dumps(result), flush=True)
    summary: dict[str, object] = {"case": "silhouettes_clutter", "seed": args.seed, "frames": len(frames), "scene_frames": args.frames, "cameras": args.cameras, "size": args.size, "render_s": round(render_s, 1)}
    for method in ("ours", "first_pass", "model", "grabcut", "mog2", "median"):
        values = np.array([r[method] for r in rows], dtype=float)
        summary[f"{method}_iou_median"] = round(float(np.median(values)), 4)
        summary[f"{method}_share_iou_ge_0.95"] = round(float((values >= 0.95).mean()), 4)
    summary["snakes_ms_per_view_median"] = float(np.median([r["snakes_ms_per_view"] for r in rows]))
    summary["snakes_cpu_ms_per_view_median"] = float(np.median([r["snakes_cpu_ms_per_view"] for r in rows]))
    summary["snakes_cpu_ms_per_view_max"] = float(np.max([r["snakes_cpu_ms_per_view"] for r in rows]))
    summary["consistency_ms_per_view_median"] = float(np.median([r["consistency_ms_per_view"] for r in rows]))
    summary["appearance_ms_per_view_median"] = float(np.median([r["appearance_ms_per_view"] for r in rows]))
    summary["background_ms_per_view_median"] = float(np.median([r["background_ms_per_view"] for r in rows]))
    for stage in tracker.cpu_timings:
        summary[f"{stage}_cpu_ms_per_view_median"] = float(np.median([r["cpu_ms_per_view"][stage] for r in rows]))  # type: ignore[index]
    summary["band_ms_per_view_median"] = float(np.median([r["band_ms_per_view"] for r in rows]))
    summary["body_s_median"] = float(np.median([r["body_s"] for r in rows]))
    summary["step_s_median"] = float(np.median([r["step_s"] for r in rows]))
    summary["joint_rms_mm_median"] = float(np.median([r["joint_rms_mm"] for r in rows]))
    summary["skin_mean_mm_median"] = float(np.median([r["skin_mean_mm"] for r in rows]))
    print(json.dumps(summary), flush=True)


if __name__ == "__main__":
    main()
