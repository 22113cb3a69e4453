"""How close the body model's shape family can come to the capsule figure: the "floor" of
issue 16's skin lines.

For frames of :class:`elastocap.synth.clutter.ClutterScene`, the body model is fitted with
the pose pinned by the true elbows, wrists, knees and ankles (joint observations, sigma
1 mm) to 3000 exact points of the true surface and the 8 true silhouettes, the shape free
(left and right tied, as the tracker's ``symmetric=True``). Each fit is run with the shape
family restricted four ways, in the same run:

- ``unit``: the shape held at 1 (the described human);
- ``width``: length and width per part, the depth tied to the width, the taper held at 1
  (the family before the depth and taper coefficients: SPEC 6's one width for both axes);
- ``depth``: length, width and depth per part, the taper held at 1;
- ``taper``: length, width, depth and taper per part, each free.

The taper is held by bounds (lower = upper = 1): the fit removes a shape unknown whose
bounds meet from its normal equations, so it stays exactly at 1 and the family converges
as one without the coefficient would (seed 0, ``width``: 12.16 mm, as 12.2 mm at the
commit before the taper existed; clamping after each step instead gave 15.0 mm;
``benches/README.md``, branches body4 and body5).

Prints one JSON line per frame and family: skin mean distance (both directions, mm, as
``eval_body_capsule.py``), joints RMS (mm), silhouette IoU (min over views), and the shape
coefficients at their bounds.

Run: ``python -W ignore benches/body_shape_floor.py --seeds 0 1 2 --frames 0``.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from elastocap.body.fit import BodyObservations, fit_body
from elastocap.body.model import SHAPE_NAMES, Z_UP_TO_WORLD, BodyModel, BodyState
from elastocap.geometry._distance import distance_to_mesh
from elastocap.render.mesh import render_silhouette
from elastocap.synth.clutter import ClutterScene

#: The figure's joints and the model part whose origin each is.
JOINT_PARTS = {
    "l_elbow": "l_forearm", "r_elbow": "r_forearm", "l_wrist": "l_hand", "r_wrist": "r_hand",
    "l_knee": "l_shin", "r_knee": "r_shin", "l_ankle": "l_foot", "r_ankle": "r_foot",
}  # fmt: skip
#: Joints also used to find the starting pose (shoulders and hips place the trunk).
START_PARTS = JOINT_PARTS | {"l_shoulder": "l_upperarm", "r_shoulder": "r_upperarm", "l_hip": "l_thigh", "r_hip": "r_thigh"}


def shape_groups(model: BodyModel, family: str) -> np.ndarray:
    """Left-right tied groups; for ``width`` also each part's depth tied to its width."""
    mirrored = model.mirrored_shape_groups()
    if family != "width":
        return mirrored
    per_part = mirrored.reshape(-1, len(SHAPE_NAMES)).copy()
    per_part[:, 2] = per_part[:, 1]
    _, numbered = np.unique(per_part.reshape(-1), return_inverse=True)
    return numbered.astype(np.int64)


def shape_bounds(model: BodyModel, family: str, upper: float) -> tuple[np.ndarray, np.ndarray]:
    """0.5 to ``upper``; the taper held at 1 unless the family has it."""
    lower, high = np.full(model.n_shape, 0.5), np.full(model.n_shape, upper)
    if family != "taper":
        taper = np.arange(model.n_shape) % len(SHAPE_NAMES) == SHAPE_NAMES.index("taper")
        lower[taper] = high[taper] = 1.0
    return lower, high


def start_pose(model: BodyModel, joints: dict[str, np.ndarray]) -> BodyState:
    """The best of 8 headings fitted to the 12 true joints alone (unit shape)."""
    pelvis = 0.5 * (joints["l_hip"] + joints["r_hip"])
    best = None
    for heading in np.linspace(-np.pi, np.pi, 8, endpoint=False):
        init = model.rest_state(position=pelvis)
        init.motion[3] = heading
        fit = fit_body(model, [BodyObservations(joints={p: joints[j] for j, p in START_PARTS.items()})], init=init,
                       shape=np.ones(model.n_shape), sigma_joint=0.001, max_iterations=60)  # fmt: skip
        if best is None or fit.final_cost < best.final_cost:
            best = fit
    assert best is not None
    return best.states[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--frames", type=int, nargs="+", default=[0])
    parser.add_argument("--families", nargs="+", default=["unit", "width", "depth", "taper"])
    parser.add_argument("--upper", type=float, default=2.0, help="upper shape bound (lower: 0.5)")
    args = parser.parse_args()
    model = BodyModel.default_human()
    for seed in args.seeds:
        scene = ClutterScene(seed, cameras=8, size=(480, 360))
        cameras = [c.replace(R=c.R @ Z_UP_TO_WORLD) for c in scene.rig.cameras]
        rng = np.random.default_rng([seed, 0xF100])
        for f in args.frames:
            surface = scene.figure.mesh(f, 0.01)
            masks = [render_silhouette(surface, c) for c in scene.rig.cameras]
            points = np.asarray(surface.sample(3000, seed=int(rng.integers(2**31))), dtype=np.float64) @ Z_UP_TO_WORLD
            truth = {k: v @ Z_UP_TO_WORLD for k, v in scene.joints(f).items()}
            init = start_pose(model, truth)
            obs = BodyObservations(points=points, masks=masks, joints={p: truth[j] for j, p in JOINT_PARTS.items()})
            for family in args.families:
                t0 = time.process_time()
                bounds = shape_bounds(model, family, args.upper)
                if family == "unit":
                    fit = fit_body(model, [obs], cameras=cameras, init=init, shape=np.ones(model.n_shape), sigma_joint=0.001, max_iterations=80)
                else:
                    fit = fit_body(model, [obs], cameras=cameras, init=init, sigma_joint=0.001, max_iterations=80,
                                   shape_groups=shape_groups(model, family), shape_bounds=bounds)  # fmt: skip
                state = fit.states[0]
                _, origins = model.pose(state)
                errors = [np.linalg.norm(origins[model.part_names.index(p)] - truth[j]) for j, p in JOINT_PARTS.items()]
                skin = model.skin_mesh(state, spacing=0.01)
                skin.vertices = skin.vertices @ Z_UP_TO_WORLD.T
                d_fit = distance_to_mesh(np.asarray(skin.vertices), surface)
                d_true = distance_to_mesh(np.asarray(surface.vertices), skin)
                ious = []
                for c, m in zip(cameras, masks):
                    s = model.silhouette(state, c)
                    ious.append(float((s & m).sum() / max((s | m).sum(), 1)))
                table = state.shape.reshape(-1, len(SHAPE_NAMES))
                at_bound = {f"{model.part_names[b]}.{SHAPE_NAMES[k]}": round(float(table[b, k]), 2)
                            for b, k in zip(*np.nonzero(((table <= 0.51) | (table >= args.upper - 0.01)) & (bounds[0] < bounds[1]).reshape(table.shape)))}  # fmt: skip
                print(json.dumps({
                    "seed": seed, "frame": f, "family": family, "skin_mean_mm": round(1000 * 0.5 * float(d_fit.mean() + d_true.mean()), 2),
                    "skin_fit_to_true_mm": round(1000 * float(d_fit.mean()), 2), "skin_true_to_fit_mm": round(1000 * float(d_true.mean()), 2),
                    "joint_rms_mm": round(1000 * float(np.sqrt(np.mean(np.square(errors)))), 1), "iou_min": round(min(ious), 3),
                    "at_bound": at_bound, "cpu_s": round(time.process_time() - t0, 1),
                }), flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
