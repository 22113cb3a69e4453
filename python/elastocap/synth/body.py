"""Synthetic ground truth for the body model: the default human with a random shape in a
smooth random motion, for ``write_synthetic_capture(..., figure="body")``.

The capture's world is y-up (the floor is y = 0, as for the capsule figure); the body
model's frame is z-up and maps to the world by :data:`Z_UP_TO_WORLD`, the same rotation the
body stage (``elastocap body``) fits in, so the states written to ``ground_truth/body.json``
compare directly with the stage's ``fit.json``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.body.model import Z_UP_TO_WORLD, BodyModel, BodyState

__all__ = ["BODY_FORMAT", "BodyFigure"]

BODY_FORMAT = "elastocap synthetic body 1"
#: Shape coefficients are drawn in ``1 +- SHAPE_SPREAD``.
SHAPE_SPREAD = 0.04
#: Frames per motion cycle (as the capsule figure's walk cycle).
CYCLE = 30
_PELVIS_HEIGHT = 0.95
_SKIN = np.array([224.0, 180.0, 150.0])
_SHIRT = np.array([190.0, 60.0, 50.0])
_TROUSERS = np.array([50.0, 70.0, 150.0])


class BodyFigure:
    """The default human with a shape and a smooth motion drawn from ``seed``.

    Each joint angle swings sinusoidally (one cycle every :data:`CYCLE` frames) about an
    offset, both drawn within the middle of its limits (at most 25 degrees swing); the root
    turns slowly (6 degrees per 10 frames) and bobs by a centimetre. Shape coefficients are
    drawn in ``1 +- 0.04``.

    Parameters
    ----------
    seed : int
    """

    def __init__(self, seed: int = 0) -> None:
        if not isinstance(seed, (int, np.integer)) or seed < 0:
            raise InvalidInputError(f"seed must be a non-negative integer, got {seed!r}")
        self.seed = int(seed)
        self.model = BodyModel.default_human()
        rng = np.random.default_rng([self.seed, 0xB0D7])
        model = self.model
        # (length, width) per part drawn as before the depth and taper coefficients (depth =
        # width, taper 1): the generator's family (and every seeded scene) is unchanged.
        self.shape = model.as_shape(1.0 + rng.uniform(-SHAPE_SPREAD, SHAPE_SPREAD, 2 * len(model.part_names)))
        joints = slice(6, model.n_motion)
        lower, upper = model.lower[joints], model.upper[joints]
        middle, half = 0.5 * (lower + upper), 0.5 * (upper - lower)
        # Offsets near the neutral pose (zero when allowed), swings of 5-25 degrees.
        neutral = np.clip(0.0, lower + 0.2 * half, upper - 0.2 * half)
        self._offset = neutral + 0.15 * half * rng.uniform(-1, 1, len(middle))
        self._amplitude = np.minimum(np.radians(rng.uniform(5, 25, len(middle))), 0.5 * half)
        self._phase = rng.uniform(0, 2 * np.pi, len(middle))
        self._heading = float(rng.uniform(-np.pi, np.pi))
        self._lower, self._upper = lower + 0.05 * half, upper - 0.05 * half

    # -- description ----------------------------------------------------------------------

    def to_dict(self, frames: int = 0) -> dict[str, Any]:
        """JSON-ready: format, seed, the model description, the shape, and (``frames > 0``)
        per-frame motion with names and the body-to-world rotation."""
        model = self.model
        record: dict[str, Any] = {
            "format": BODY_FORMAT,
            "seed": self.seed,
            "model": model.to_dict(),
            "parts": model.part_names,
            "shape": self.shape.tolist(),
            "motion_names": model.motion_names,
            "frame": "z-up body frame; world = R_body_to_world @ x",
            "R_body_to_world": Z_UP_TO_WORLD.tolist(),
        }
        if frames > 0:
            record["motion"] = [self.state(n).motion.tolist() for n in range(frames)]
        return record

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> BodyFigure:
        """The figure :meth:`to_dict` (``ground_truth/body.json``) describes."""
        if data.get("format") != BODY_FORMAT:
            raise KeyError(f"format is not {BODY_FORMAT!r}")
        return cls(int(data["seed"]))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, BodyFigure) and other.seed == self.seed

    def __hash__(self) -> int:
        return hash(("BodyFigure", self.seed))

    def __repr__(self) -> str:
        return f"BodyFigure(seed={self.seed})"

    # -- states and surfaces --------------------------------------------------------------

    def state(self, frame: int) -> BodyState:
        """The true state at ``frame`` (body frame, z-up)."""
        t = 2 * np.pi * int(frame) / CYCLE
        motion = np.zeros(self.model.n_motion)
        motion[:3] = (0.0, 0.0, _PELVIS_HEIGHT + 0.01 * np.sin(2 * t))
        motion[3] = self._heading + np.radians(0.6) * int(frame)
        motion[6:] = np.clip(self._offset + self._amplitude * np.sin(t + self._phase), self._lower, self._upper)
        return BodyState(self.shape.copy(), motion)

    def mesh(self, frame: int, spacing: float = 0.01) -> trimesh.Trimesh:
        """The skin at ``frame`` in world coordinates (y-up), with vertex colours: skin
        above the neck, a shirt down to the hips, trousers below."""
        state = self.state(frame)
        mesh = self.model.skin_mesh(state, spacing=spacing)
        _, origins = self.model.pose(state)
        names = self.model.part_names
        height = np.asarray(mesh.vertices)[:, 2]
        colours = np.where(
            (height > origins[names.index("head")][2])[:, None],
            _SKIN,
            np.where((height > origins[names.index("pelvis")][2] - 0.06)[:, None], _SHIRT, _TROUSERS),
        )
        # Arms below the elbow in skin colour: nearest part origin is a forearm or hand.
        parts = np.array([names.index(n) for n in names if n.endswith(("forearm", "hand"))])
        others = np.array([i for i in range(len(names)) if i not in set(parts.tolist())])
        vertices = np.asarray(mesh.vertices)
        near_arm = _nearest_distance(vertices, origins[parts] + 0.1 * _limb_direction(self.model, state, parts))
        near_other = _nearest_distance(vertices, origins[others])
        colours = np.where((near_arm < near_other)[:, None], _SKIN, colours)
        rgba = np.concatenate([colours.round().astype(np.uint8), np.full((len(colours), 1), 255, np.uint8)], axis=1)
        world = trimesh.Trimesh(vertices @ Z_UP_TO_WORLD.T, np.asarray(mesh.faces), vertex_colors=rgba, process=False)
        return world


def _nearest_distance(points: NDArray[np.float64], centres: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray(np.linalg.norm(points[:, None, :] - centres[None, :, :], axis=2).min(axis=1))


def _limb_direction(model: BodyModel, state: BodyState, parts: NDArray[np.int64]) -> NDArray[np.float64]:
    """Each part's frame z axis (the limb's direction), world."""
    rotations, _ = model.pose(state)
    return np.asarray(rotations[parts][:, :, 2])
