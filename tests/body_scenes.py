"""Synthetic body scenes for the body tests: random states, cameras, observations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import elastocap
from elastocap import Camera
from elastocap.synth import ring_rig
from elastocap.body import BodyModel, BodyState


def random_state(model: BodyModel, rng: np.random.Generator, *, spread: float = 0.6) -> BodyState:
    """A random state, body frame z up near (0, 0, 1): joint angles uniform within
    ``spread`` times their limits, shape coefficients in [0.9, 1.1], any heading."""
    motion = np.zeros(model.n_motion)
    motion[:3] = rng.normal(0, 0.05, 3) + [0.0, 0.0, 0.95]
    motion[3] = rng.uniform(-np.pi, np.pi)
    motion[4:6] = rng.uniform(-0.1, 0.1, 2)
    lower, upper = model.lower[6:], model.upper[6:]
    centre, half = (lower + upper) / 2, (upper - lower) / 2
    motion[6:] = centre + spread * half * rng.uniform(-1, 1, model.n_motion - 6)
    # (length, width) drawn per part, depth = width and taper 1, as before those
    # coefficients: the seeded scenes stay the ones the tolerances were set on.
    return BodyState(model.as_shape(rng.uniform(0.9, 1.1, 2 * len(model.part_names))), motion)


def perturbed(model: BodyModel, state: BodyState, rng: np.random.Generator, *, degrees: float = 8.0, unit_shape: bool = True) -> BodyState:
    """A starting guess: angles off by ``degrees`` (normal, per angle), root off by 3 cm
    and 3 degrees, shape reset to 1."""
    motion = state.motion.copy()
    motion[:3] += rng.normal(0, 0.03, 3)
    motion[3:6] += rng.normal(0, np.radians(3), 3)
    motion[6:] = np.clip(motion[6:] + rng.normal(0, np.radians(degrees), model.n_motion - 6), model.lower[6:], model.upper[6:])
    return BodyState(np.ones(model.n_shape) if unit_shape else state.shape.copy(), motion)


def z_up_cameras(n: int, *, width: int = 400, height: int = 300) -> list[Camera]:
    """``ring_rig`` cameras (a y-up world) re-expressed for a z-up world."""
    to_y_up = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    rig = ring_rig(n, width=width, height=height, radius=3.5, look_at=(0.0, 0.95, 0.0), fov=45.0)
    return [c.replace(R=c.R @ to_y_up) for c in rig.cameras]


@dataclass
class Scene:
    truth: BodyState
    points: np.ndarray
    cameras: list[Camera]
    masks: list[np.ndarray]


def scene(model: BodyModel, seed: int, *, n_points: int = 2000, n_cameras: int = 6) -> Scene:
    rng = np.random.default_rng(seed)
    truth = random_state(model, rng)
    cameras = z_up_cameras(n_cameras)
    return Scene(
        truth,
        model.skin_points(truth, n_points, seed=seed, spacing=0.015),
        cameras,
        [model.silhouette(truth, c) for c in cameras],
    )


def angle_rms_degrees(model: BodyModel, fit: np.ndarray, truth: np.ndarray) -> float:
    return float(np.degrees(np.sqrt(np.mean((fit[6:] - truth[6:]) ** 2))))


def shape_error(fit: np.ndarray, truth: np.ndarray) -> float:
    return float(np.abs(fit / truth - 1).max())
