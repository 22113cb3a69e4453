"""The body fit as the skeleton exports see it (BVH, .trc, .c3d): the body model's parts as
joints, one shape for the take, and per frame each part's position and orientation in
export space (metres, +Y up).

Read from ``OUT/body/fit.json`` (the body stage's record: shape per part, joint angles per
frame in the body's z-up frame, ``R_body_to_world``). A part's origin is the joint at its
proximal end (the pelvis: the root).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.body.model import Z_UP_TO_WORLD, BodyModel, BodyState
from elastocap.pipeline.export.settings import ExportSpace

__all__ = ["SkeletonTake", "load_body_take"]


@dataclass(frozen=True)
class SkeletonTake:
    """A body model with one shape and its motion over the frames of a take.

    Attributes
    ----------
    model : BodyModel
    shape : (4 P,) float64
        ``(length, width, depth, taper)`` coefficients per part, for every frame.
    frames : list of int
        Frame numbers.
    motion : (N, n_motion) float64
        Per frame: root translation (metres, body frame), root and joint angles (radians).
    body_to_world : (3, 3) float64
        Body frame (z up) -> the capture's world.
    """

    model: BodyModel
    shape: NDArray[np.float64]
    frames: list[int]
    motion: NDArray[np.float64]
    body_to_world: NDArray[np.float64]

    @property
    def names(self) -> list[str]:
        """Part (joint) names, parents before children."""
        return list(self.model.part_names)

    @property
    def parents(self) -> list[int]:
        """Index of each part's parent (-1 for the root)."""
        index = {name: i for i, name in enumerate(self.names)}
        return [-1 if p["parent"] is None else index[p["parent"]] for p in self.model.to_dict()["parts"]]

    def _to_export(self, space: ExportSpace) -> NDArray[np.float64]:
        return space.rotation @ self.body_to_world

    def rest_pose(self, space: ExportSpace) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Part rotations ``(P, 3, 3)`` (body frame -> export axes) and origins ``(P, 3)``
        (export space) with this take's shape and every angle and the root at zero."""
        return self._pose(np.zeros(self.model.n_motion), space)

    def poses(self, space: ExportSpace) -> Iterator[tuple[int, NDArray[np.float64], NDArray[np.float64]]]:
        """Per frame ``(frame, rotations (P, 3, 3), origins (P, 3))`` as :meth:`rest_pose`."""
        for frame, motion in zip(self.frames, self.motion):
            yield (frame, *self._pose(motion, space))

    def _pose(self, motion: NDArray[np.float64], space: ExportSpace) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        rotations, origins = self.model.pose(BodyState(self.shape, np.ascontiguousarray(motion)))
        to_export = self._to_export(space)
        return to_export @ rotations, space.scale * (origins @ to_export.T)

    def end_sites(self, space: ExportSpace) -> dict[int, NDArray[np.float64]]:
        """For each part without children, the end of its bone in its rest frame rotated to
        export axes (``(3,)``, metres): the metaball centre farthest from the part's origin,
        scaled by the part's shape."""
        rotations, _ = self.rest_pose(space)
        has_child = set(self.parents)
        ends = {}
        for i, part in enumerate(self.model.to_dict()["parts"]):
            if i in has_child or not part["balls"]:
                continue
            centres = np.array([b["center"] for b in part["balls"]], dtype=np.float64)
            length, width, depth, taper = self.shape[4 * i : 4 * i + 4]
            section = 1.0 + (taper - 1.0) * self.model.taper_weight[self.model.ball_part == i]
            scaled = centres * np.stack([width * section, depth * section, np.full(len(centres), length)], axis=1)
            far = scaled[np.argmax(np.linalg.norm(scaled, axis=1))]
            ends[i] = space.scale * (rotations[i] @ far)
        return ends


def load_body_take(out: str | Path) -> SkeletonTake:
    """The body fit written by the body stage into ``out`` (``out/body/fit.json``).

    The model is the record's ``model`` description when it has one, else the default
    human, whose part and motion names must then match the record's.

    Raises
    ------
    FileNotFoundError
        No ``out/body/fit.json``.
    InvalidInputError
        A record that does not fit its model (other parts, other joint angles).
    """
    path = Path(out) / "body" / "fit.json"
    if not path.exists():
        raise FileNotFoundError(f"no body fit in {out} ({path} is missing): run the body stage first")
    try:
        record: dict[str, Any] = json.loads(path.read_text())
        model = BodyModel.from_dict(record["model"]) if "model" in record else BodyModel.default_human()
        if record["parts"] != model.part_names or record["motion_names"] != model.motion_names:
            raise InvalidInputError(f"{path}: its parts and joint angles are not those of the body model")
        # Records written before the depth and taper coefficients: the width scaled both
        # axes, no taper.
        shape = np.array([[(s := record["shape"][n])["length"], s["width"], s.get("depth", s["width"]), s.get("taper", 1.0)] for n in model.part_names],
                         dtype=np.float64).reshape(-1)
        motion = np.array(record["motion"], dtype=np.float64).reshape(len(record["frames"]), model.n_motion)
        body_to_world = np.array(record.get("R_body_to_world", Z_UP_TO_WORLD), dtype=np.float64).reshape(3, 3)
        frames = [int(f) for f in record["frames"]]
    except (KeyError, TypeError, ValueError, json.JSONDecodeError) as error:
        raise InvalidInputError(f"{path}: not a body fit record ({type(error).__name__}: {error})") from None
    if not np.isfinite(motion).all() or not np.isfinite(shape).all():
        raise InvalidInputError(f"{path}: the shape or the motion is not finite")
    return SkeletonTake(model=model, shape=shape, frames=frames, motion=motion, body_to_world=body_to_world)
