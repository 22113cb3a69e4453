"""A textured scene for the tracking tests, until the textured synthetic capture lands: a
textured ball (the body) that drifts and turns, and a smaller textured ball (a limb) that
orbits it and passes in front of it in some cameras (self-occlusion). Ray-cast through
``ring_rig`` cameras (distortion and skew), texture painted in each ball's rest frame so
that it moves with the ball, sensor noise; ground-truth surface points with per-camera
visibility. Written as a capture folder (images, masks, intri/extri)."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from elastocap._io import save_image
from elastocap.cameras import Rig
from elastocap.synth.capture import ring_rig

CENTRE = np.array([0.0, 0.9, 0.0])


class SceneTruth(NamedTuple):
    """positions (F, N, 3) world; visible (F, C, N); part (N,) 0 body, 1 limb."""

    positions: NDArray[np.float64]
    visible: NDArray[np.bool_]
    part: NDArray[np.int64]
    rig: Rig


def _rotation_y(angle: float) -> NDArray[np.float64]:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _poses(frame: int, speed: float) -> list[tuple[NDArray[np.float64], NDArray[np.float64], float]]:
    """(rotation rest -> world, centre, radius) of the body and the limb at a frame."""
    t = float(frame)
    body_r = _rotation_y(0.03 * speed * t) @ np.array([[1, 0, 0], [0, np.cos(0.01 * t), -np.sin(0.01 * t)], [0, np.sin(0.01 * t), np.cos(0.01 * t)]])
    body_c = CENTRE + np.array([0.006 * speed * t, 0.02 * np.sin(0.2 * t), 0.0])
    angle = 0.09 * speed * t
    limb_c = body_c + np.array([0.62 * np.cos(angle), 0.05, 0.62 * np.sin(angle)])
    return [(body_r, body_c, 0.35), (_rotation_y(-2.0 * angle), limb_c, 0.16)]


def _texture(rest: NDArray[np.float64], part: NDArray[np.int64], seed: int, contrast: float = 1.0) -> NDArray[np.float64]:
    """Grey level 0..255 of rest-frame points: random 3-D sinusoids, 1.5-9 cm wavelengths,
    their amplitudes times ``contrast``."""
    rng = np.random.default_rng([seed, 7])
    out = np.full(len(rest), 128.0)
    for _ in range(24):
        k = rng.normal(size=3)
        k *= 2 * np.pi / rng.uniform(0.015, 0.09) / np.linalg.norm(k)
        phase = rng.uniform(0, 2 * np.pi, size=2)
        out += contrast * rng.uniform(8, 16) * np.sin(rest @ k + phase[part])
    return np.clip(out, 0, 255)


def _hits(origins: NDArray[np.float64], dirs: NDArray[np.float64], balls: list) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Nearest ray parameter and ball index (-1 none)."""
    best = np.full(len(dirs), np.inf)
    which = np.full(len(dirs), -1)
    for b, (_, c, r) in enumerate(balls):
        oc = origins - c
        bq = np.einsum("ij,ij->i", oc, dirs)
        disc = bq * bq - (np.einsum("ij,ij->i", oc, oc) - r * r)
        t = -bq - np.sqrt(np.where(disc > 0, disc, np.nan))
        closer = np.isfinite(t) & (t > 0) & (t < best)
        best[closer] = t[closer]
        which[closer] = b
    return best, which


def write_scene(out: Path, *, frames: int = 12, cameras: int = 6, size: tuple[int, int] = (320, 240),
                seed: int = 0, noise: float = 2.0, speed: float = 1.0, points: int = 400,
                fade: float = 1.0) -> SceneTruth:
    """Render the scene into the capture folder ``out``; return the truth. The texture's
    contrast is ``fade ** frame`` of frame 0's (the sensor noise stays)."""
    width, height = size
    rig = ring_rig(cameras, width=width, height=height, fov=28.0, seed=seed)
    rng = np.random.default_rng([seed, 3])
    out.mkdir(parents=True, exist_ok=True)
    rig.save(out)
    # Surface points on both balls (rest frame unit directions).
    dirs = rng.normal(size=(points, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    part = (np.arange(points) >= int(0.75 * points)).astype(np.int64)
    positions = np.zeros((frames, points, 3))
    visible = np.zeros((frames, cameras, points), bool)
    vv, uu = np.mgrid[0:height, 0:width]
    pixels = np.column_stack([uu.ravel(), vv.ravel()]).astype(float)
    for f in range(frames):
        balls = _poses(f, speed)
        for b, (rot, c, r) in enumerate(balls):
            sel = part == b
            positions[f, sel] = c + (r * dirs[sel]) @ rot.T
        for k, cam in enumerate(rig.cameras):
            origins, rays = cam.rays(pixels)
            t, which = _hits(origins, np.nan_to_num(rays), balls)
            grey = np.full(len(pixels), 0.0)
            bg = 100 + 40 * np.sin(pixels[:, 0] * 0.21 + k) * np.cos(pixels[:, 1] * 0.17)
            grey[:] = bg
            for b, (rot, c, r) in enumerate(balls):
                sel = which == b
                hit = origins[sel] + t[sel, None] * rays[sel]
                rest = (hit - c) @ rot
                shade = 0.6 + 0.4 * np.abs(np.einsum("ij,ij->i", (hit - c) / r, -rays[sel]))
                grey[sel] = _texture(rest, np.full(sel.sum(), b), seed, fade**f) * shade
            grey += rng.normal(0, noise, size=grey.shape)
            image = np.clip(np.round(grey), 0, 255).astype(np.uint8).reshape(height, width)
            stem = f"{f:06d}"
            save_image(out / "images" / cam.name / f"{stem}.png", np.repeat(image[..., None], 3, axis=2))
            save_image(out / "masks" / cam.name / f"{stem}.png", ((which >= 0).reshape(height, width) * 255).astype(np.uint8))
            # Visibility: in the image and the first hit along the ray is the point.
            x = positions[f]
            uv, _ = cam.project(x)
            inside = cam.visible(x)
            o = np.broadcast_to(cam.center, x.shape)
            d = x - o
            dist = np.linalg.norm(d, axis=1)
            th, _ = _hits(o, d / dist[:, None], balls)
            visible[f, k] = inside & (np.abs(th - dist) < 1e-6)
    return SceneTruth(positions, visible, part, rig)


def blank_band(root: Path, names: list[str], frames: tuple[int, ...], *, half: int = 15, seed: int = 0) -> None:
    """Blank a vertical band down the middle of every camera's image (flat grey under
    noise) on ``frames``: the points seen only inside it lose every view there."""
    import cv2

    rng = np.random.default_rng(seed)
    for name in names:
        for f in frames:
            path = root / "images" / name / f"{f:06d}.png"
            image = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB).astype(float)
            middle = image.shape[1] // 2
            band = image[:, middle - half:middle + half]
            image[:, middle - half:middle + half] = 110 + rng.normal(0, 2, band.shape)
            save_image(path, np.clip(np.round(image), 0, 255).astype(np.uint8))
