"""Run by tests/test_thread_count.py in a subprocess (the Rust pool's size is fixed when a
process first uses it): an elastic fit and a body fit, their results written to an .npz."""

from __future__ import annotations

import sys

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from body_scenes import perturbed, scene
from elastocap import ElasticModel, fit_sequence
from elastocap.body import BodyModel, BodyObservations, fit_body

# Enough nodes that the system matrix's product splits into several tasks (> 16,384 upper
# blocks) and the energy's sum into several chunks.
NODES = 2500


def elastic_fit() -> dict[str, np.ndarray]:
    capsule = trimesh.creation.capsule(height=1.0, radius=0.25, count=[24, 24])
    model = ElasticModel.from_mesh(capsule, n_nodes=NODES, rotation="warped")
    targets = []
    for step in range(3):
        moved = capsule.copy()
        transform = np.eye(4)
        transform[:3, :3] = Rotation.from_euler("xz", [15 * step, 10 * step], degrees=True).as_matrix()
        transform[:3, 3] = [0.05 * step, -0.03 * step, 0.02 * step]
        moved.apply_transform(transform)
        targets.append(moved)
    fit = fit_sequence(model, targets)
    return {f"elastic_{f}": fit.fits[f].positions for f in fit.frames} | {
        "elastic_iterations": np.array([fit.fits[f].metrics.get("iterations", -1) for f in fit.frames], float)
    }


def body_fit() -> dict[str, np.ndarray]:
    model = BodyModel.default_human()
    sc = scene(model, 2, n_points=4000, n_cameras=6)
    init = perturbed(model, sc.truth, np.random.default_rng(102))
    fit = fit_body(model, [BodyObservations(points=sc.points, masks=sc.masks)], cameras=sc.cameras, init=init, sigma_ray=0.3)
    return {"body_motion": fit.motion, "body_shape": fit.shape, "body_cost": np.array([fit.final_cost])}


if __name__ == "__main__":
    np.savez(sys.argv[1], **elastic_fit(), **body_fit())
