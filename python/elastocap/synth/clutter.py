"""A synthetic capture in clutter (issue 16): the capsule figure (not the body model, so the
body fit does not meet its own generator) walking in front of a cluttered, textured scene
with moving distractors and a lighting change, so that no median of the sequence is a
clean background plate.

Everything a model-based silhouette extractor needs and nothing it should not have: the
colour images, a rig, and per view the stereo stage's outputs as they come in practice
(a binarised disparity mask restricted to the reconstruction volume: fattened at the
outline, with holes where texture is poor, and holding a distractor that stands as near as
the subject; 3-D points with noise and outliers); beside them the ground truth (masks,
joint positions, the surface).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import trimesh
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._validate import as_count
from elastocap.cameras import Camera, Rig
from elastocap.render.mesh import render_mesh
from elastocap.synth.capsules import CapsuleFigure
from elastocap.synth.capture import ring_rig

__all__ = ["ClutterFrame", "ClutterScene", "JOINTS", "write_clutter_capture"]

#: Ground-truth joints: name -> (capsule part, "start" or "end").
JOINTS = {
    "l_shoulder": ("upper_arm_l", "start"), "r_shoulder": ("upper_arm_r", "start"),
    "l_elbow": ("forearm_l", "start"), "r_elbow": ("forearm_r", "start"),
    "l_wrist": ("forearm_l", "end"), "r_wrist": ("forearm_r", "end"),
    "l_hip": ("thigh_l", "start"), "r_hip": ("thigh_r", "start"),
    "l_knee": ("shin_l", "start"), "r_knee": ("shin_r", "start"),
    "l_ankle": ("shin_l", "end"), "r_ankle": ("shin_r", "end"),
}  # fmt: skip


@dataclass(frozen=True)
class ClutterFrame:
    """One frame of a :class:`ClutterScene`.

    Attributes
    ----------
    images : dict of str to (H, W, 3) uint8
        RGB per camera.
    disparity_masks : dict of str to (H, W) bool
        What stereo marks as inside the reconstruction volume, per camera.
    points : (N, 3) float64
        Stereo points, world metres (noise 3 mm, 5% outliers in the volume).
    masks : dict of str to (H, W) bool
        Ground-truth silhouettes.
    joints : dict of str to (3,) float64
        Ground-truth joint positions (:data:`JOINTS`), world metres.
    surface : trimesh.Trimesh
        Ground-truth surface, world.
    """

    images: dict[str, NDArray[np.uint8]]
    disparity_masks: dict[str, NDArray[np.bool_]]
    points: NDArray[np.float64]
    masks: dict[str, NDArray[np.bool_]]
    joints: dict[str, NDArray[np.float64]]
    surface: trimesh.Trimesh


class ClutterScene:
    """The capsule figure in clutter, seen by a ring of cameras.

    Parameters
    ----------
    seed : int
        The figure, the rig's perturbations, the clutter, distractors and noise.
    cameras : int, keyword-only
    size : (width, height), keyword-only
    frames : int, keyword-only
        Length of the take: the lighting falls to 60% over it and the distractors cross the
        views within it.

    Notes
    -----
    Per camera the backdrop is a clutter of textured rectangles and ellipses over a noise
    texture (edges everywhere). Six distractors per view move across it (two of them slowly,
    so that they sit long enough to enter a median); one of them stands as near as the
    subject, so stereo keeps it in the disparity mask. The light dims over the take and a
    bright band sweeps across the views. The disparity mask is the true silhouette grown by
    3 pixels (stereo's foreground fattening) with holes (poorly textured patches), speckle,
    and the near distractor.
    """

    def __init__(self, seed: int = 0, *, cameras: int = 6, size: tuple[int, int] = (480, 360), frames: int = 300) -> None:
        self.seed = as_count("seed", seed, minimum=0)
        self.n_frames = as_count("frames", frames)
        width, height = (as_count("width", size[0]), as_count("height", size[1]))
        self.rig: Rig = ring_rig(as_count("cameras", cameras, minimum=2), width=width, height=height, radius=3.5, look_at=(0.0, 0.9, 0.0), fov=45.0, seed=self.seed)
        self.figure = CapsuleFigure(self.seed)
        self._rng_root = np.random.SeedSequence([self.seed, 0xC1A7])

    @cached_property
    def _backdrops(self) -> dict[str, Any]:
        out = {}
        for k, camera in enumerate(self.rig.cameras):
            rng = np.random.default_rng([self.seed, 0xBAC, k])
            h, w = camera.height, camera.width
            noise = cv2.resize(rng.uniform(60, 200, (h // 8 + 1, w // 8 + 1, 3)).astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
            image = cv2.GaussianBlur(noise, (0, 0), 1.0) + rng.normal(0, 10, (h, w, 3)).astype(np.float32)
            for _ in range(40):
                colour = tuple(float(c) for c in rng.uniform(20, 235, 3))
                x, y = int(rng.uniform(0, w)), int(rng.uniform(0, h))
                a, b = int(rng.uniform(8, w / 6)), int(rng.uniform(8, h / 4))
                if rng.random() < 0.5:
                    cv2.rectangle(image, (x - a, y - b), (x + a, y + b), colour, -1)
                else:
                    cv2.ellipse(image, (x, y), (a, b), float(rng.uniform(0, 180)), 0, 360, colour, -1)
                if rng.random() < 0.5:
                    cv2.line(image, (x - a, y + b), (x + a, y - b), tuple(255 - c for c in colour), 2)
            out[camera.name] = np.clip(image, 0, 255)
        return out

    @cached_property
    def _distractors(self) -> dict[str, list[dict[str, Any]]]:
        out = {}
        for k, camera in enumerate(self.rig.cameras):
            rng = np.random.default_rng([self.seed, 0xD15, k])
            w, h = camera.width, camera.height
            items = []
            for i in range(6):
                slow = i < 2
                items.append({
                    "x0": float(rng.uniform(0, w)), "y0": float(rng.uniform(0.2 * h, 0.8 * h)),
                    "vx": float(rng.uniform(-1, 1) * (0.2 if slow else 2.0) * w / 480),
                    "vy": float(rng.uniform(-0.3, 0.3) * w / 480),
                    "a": float(rng.uniform(0.05, 0.12) * w), "b": float(rng.uniform(0.08, 0.25) * h),
                    "colour": tuple(float(c) for c in rng.uniform(30, 230, 3)),
                    "near": float(i == 2),
                    "stripes": float(rng.uniform(4, 12)),
                })  # fmt: skip
            out[camera.name] = items
        return out

    def _draw_distractors(self, image: NDArray[np.float32], camera: Camera, frame: int) -> NDArray[np.bool_]:
        """Draws the moving distractors; returns the pixels of the near one."""
        near = np.zeros(image.shape[:2], dtype=np.uint8)
        w = camera.width
        for item in self._distractors[camera.name]:
            period = 2 * w
            x = (float(item["x0"]) + float(item["vx"]) * frame) % period - 0.5 * w  # type: ignore[arg-type]
            y = float(item["y0"]) + float(item["vy"]) * np.sin(frame / 20.0) * 20  # type: ignore[arg-type]
            shape = np.zeros(image.shape[:2], dtype=np.uint8)
            cv2.ellipse(shape, (int(x), int(y)), (int(item["a"]), int(item["b"])), 0, 0, 360, 1, -1)  # type: ignore[arg-type]
            inside = shape != 0
            if not inside.any():
                continue
            colour = np.array(item["colour"], dtype=np.float32)
            rows = np.arange(image.shape[0], dtype=np.float32)[:, None]
            stripe = (np.sin(rows / float(item["stripes"])) > 0).astype(np.float32)  # type: ignore[arg-type]
            texture = colour[None, None, :] * (0.7 + 0.3 * stripe[..., None])
            image[inside] = np.broadcast_to(texture, image.shape)[inside]
            if item["near"]:
                near |= shape
        return near != 0

    def _lighting(self, camera: Camera, frame: int) -> NDArray[np.float32]:
        h, w = camera.height, camera.width
        gain = 1.0 - 0.4 * frame / max(self.n_frames - 1, 1)
        centre = (frame * 7.0) % (2 * w) - 0.5 * w
        columns = np.arange(w, dtype=np.float32)
        band = 0.35 * np.exp(-((columns - centre) / (0.12 * w)) ** 2)
        return (gain * (1.0 + band))[None, :, None] * np.ones((h, 1, 1), dtype=np.float32)

    def joints(self, frame: int) -> dict[str, NDArray[np.float64]]:
        """Ground-truth joint positions (world metres) at ``frame``."""
        capsules = self.figure.capsules(frame)
        index = {n: i for i, n in enumerate(capsules.names)}
        return {name: (capsules.starts if end == "start" else capsules.ends)[index[part]].copy() for name, (part, end) in JOINTS.items()}

    def frame(self, frame: int, *, spacing: float = 0.015) -> ClutterFrame:
        """Renders ``frame`` (0 <= frame < frames)."""
        if not 0 <= int(frame) < self.n_frames:
            raise InvalidInputError(f"frame must be in 0..{self.n_frames - 1}, got {frame}")
        frame = int(frame)
        surface = self.figure.mesh(frame, spacing)
        rng = np.random.default_rng([self.seed, 0xF4A, frame])
        images, disparity, masks = {}, {}, {}
        for camera in self.rig.cameras:
            backdrop = self._backdrops[camera.name].copy()
            near = self._draw_distractors(backdrop, camera, frame)
            mask, image = render_mesh(surface, camera, background=np.clip(backdrop, 0, 255).astype(np.uint8))
            lit = image.astype(np.float32) * self._lighting(camera, frame) + rng.normal(0, 3.0, image.shape).astype(np.float32)
            images[camera.name] = np.clip(np.rint(lit), 0, 255).astype(np.uint8)
            masks[camera.name] = mask
            disparity[camera.name] = self._disparity(mask, near, rng)
        points = np.asarray(surface.sample(4000, seed=int(rng.integers(2**31))), dtype=np.float64)
        points += rng.normal(0, 0.003, points.shape)
        lower, upper = surface.bounds
        outliers = rng.uniform(lower - 0.3, upper + 0.3, (len(points) // 19, 3))
        return ClutterFrame(images, disparity, np.concatenate([points, outliers]), masks, self.joints(frame), surface)

    @staticmethod
    def _disparity(mask: NDArray[np.bool_], near: NDArray[np.bool_], rng: np.random.Generator) -> NDArray[np.bool_]:
        h, w = mask.shape
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))
        fat = cv2.dilate(mask.astype(np.uint8), kernel) != 0
        holes = np.zeros((h, w), dtype=np.uint8)
        rows, cols = np.nonzero(mask)
        for k in rng.integers(0, max(len(rows), 1), 6 if len(rows) else 0):
            cv2.circle(holes, (int(cols[k]), int(rows[k])), int(rng.uniform(2, 0.02 * w)), 1, -1)
        speckle = rng.random((h, w)) < 0.002
        return (fat & (holes == 0)) | near | speckle


def write_clutter_capture(scene: ClutterScene, capture: str | Path, out: str | Path, frames: range | list[int]) -> None:
    """Writes ``frames`` of ``scene`` as a capture folder without masks (``capture``:
    calibration, ``images/``, and the truth in ``ground_truth/masks/`` and
    ``ground_truth/joints.json``) and the stereo stage's outputs into ``out``
    (``disparity/<camera>/<frame>.png``, ``points/<frame>.npz``), the inputs of
    ``elastocap silhouettes``."""
    import json

    from elastocap._io import save_bytes, save_image, save_npz

    capture, out = Path(capture), Path(out)
    scene.rig.save(capture)
    joints = {}
    for f in frames:
        data = scene.frame(f)
        stem = f"{f:06d}"
        for name in scene.rig.names:
            save_image(capture / "images" / name / f"{stem}.png", data.images[name])
            save_image(capture / "ground_truth" / "masks" / name / f"{stem}.png", data.masks[name].astype(np.uint8) * 255)
            save_image(out / "disparity" / name / f"{stem}.png", data.disparity_masks[name].astype(np.uint8) * 255)
        save_npz(out / "points" / f"{stem}.npz", points=data.points)
        joints[stem] = {k: v.tolist() for k, v in data.joints.items()}
    save_bytes(capture / "ground_truth" / "joints.json", json.dumps(joints).encode())
