"""A rig at a glance: a table of its cameras, sanity checks, and a picture of the camera
frusta and the volume they all see (three orthographic views, drawn with OpenCV)."""

from __future__ import annotations

import warnings
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.cameras.checks import CalibrationWarning
from elastocap.cameras.rig import Rig

__all__ = ["check_rig", "describe_rig", "draw_rig", "shared_volume"]

# Horizontal fields of view outside this range (degrees) are not a lens a capture rig uses:
# the focal length is probably in millimetres, or for another image size.
PLAUSIBLE_FOV_DEG = (2.0, 150.0)
# fx / fy beyond this ratio (either way) means non-square pixels no real camera has.
PLAUSIBLE_ASPECT = 1.5
# Samples per axis of the box in which the shared view volume is sought.
VOLUME_SAMPLES = 40
PANEL = 420  # pixels per view
_COLOURS = [(66, 133, 244), (219, 68, 55), (244, 180, 0), (15, 157, 88), (171, 71, 188),
            (0, 172, 193), (255, 112, 67), (124, 179, 66)]


def _sample_box(rig: Rig) -> NDArray[np.float64]:
    centres = np.array([camera.center for camera in rig.cameras])
    middle = centres.mean(axis=0)
    reach = max(float(np.linalg.norm(centres - middle, axis=1).max()), 1e-9) * 1.5
    if len(rig) == 1:
        camera = rig.cameras[0]
        middle = camera.center + camera.R[2] * max(1.0, float(np.linalg.norm(camera.t)))
        reach = float(np.linalg.norm(middle - camera.center))
    axis = np.linspace(-reach, reach, VOLUME_SAMPLES)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    return np.asarray(middle + grid)


def shared_volume(rig: Rig) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Sample points around the rig ``(N, 3)`` and which cameras see each ``(C, N)``."""
    points = _sample_box(rig)
    return points, np.array([camera.visible(points) for camera in rig.cameras])


def describe_rig(rig: Rig) -> str:
    """One line per camera: size, focal lengths and field of view, principal point, skew,
    non-zero distortion, centre and viewing direction (world units)."""
    lines = [f"{len(rig)} cameras"]
    for camera in rig.cameras:
        fx, s, cx = camera.K[0]
        fy, cy = camera.K[1, 1], camera.K[1, 2]
        fov = np.degrees(2 * np.arctan2(camera.width / 2, fx))
        names = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")
        dist = " ".join(f"{n}={v:.4g}" for n, v in zip(names, camera.dist) if v != 0) or "none"
        centre = ", ".join(f"{v:.4g}" for v in camera.center)
        look = ", ".join(f"{v:.3f}" for v in camera.R[2])
        lines.append(
            f"  {camera.name}: {camera.width}x{camera.height} px, f = ({fx:.6g}, {fy:.6g}) px "
            f"(horizontal FOV {fov:.1f} deg), c = ({cx:.6g}, {cy:.6g}), skew {s:.3g}, "
            f"distortion {dist}; centre ({centre}), looking along ({look})"
        )
    return "\n".join(lines)


def check_rig(rig: Rig) -> list[str]:
    """Sanity checks, each problem also issued as a :class:`CalibrationWarning`: an
    implausible focal length for the image size (horizontal field of view outside
    PLAUSIBLE_FOV_DEG, or fx / fy beyond PLAUSIBLE_ASPECT), and a camera that sees none of
    the volume the other cameras all see (looking away: often a transposed rotation or a
    camera-to-world pose read as world-to-camera)."""
    problems = []
    for camera in rig.cameras:
        fx, fy = camera.K[0, 0], camera.K[1, 1]
        fov = float(np.degrees(2 * np.arctan2(camera.width / 2, fx)))
        if not PLAUSIBLE_FOV_DEG[0] <= fov <= PLAUSIBLE_FOV_DEG[1]:
            problems.append(
                f"camera {camera.name!r}: fx = {fx:.6g} px gives a horizontal field of view of {fov:.3g} deg "
                f"for a {camera.width} px wide image: is the focal length in pixels, for this image size?"
            )
        if max(fx / fy, fy / fx) > PLAUSIBLE_ASPECT:
            problems.append(f"camera {camera.name!r}: fx = {fx:.6g} and fy = {fy:.6g} px differ by more than {PLAUSIBLE_ASPECT}x")
    if len(rig) >= 3:
        points, seen = shared_volume(rig)
        for index, camera in enumerate(rig.cameras):
            others = np.delete(seen, index, axis=0).all(axis=0)
            if others.any() and not seen[index, others].any():
                target = points[others].mean(axis=0)
                depth = float(camera.to_camera(target[None])[0, 2])
                where = "behind it" if depth <= 0 else "outside its image"
                problems.append(
                    f"camera {camera.name!r} looks away from the volume the other cameras all see (its middle, "
                    f"({', '.join(f'{v:.3g}' for v in target)}), is {where}): is its rotation transposed, or "
                    "its pose camera-to-world?"
                )
    for problem in problems:
        warnings.warn(problem, CalibrationWarning, stacklevel=2)
    return problems


def draw_rig(rig: Rig, file: str | Path) -> Path:
    """Draw the rig to a PNG: three orthographic views (world x-y, x-z, z-y) of each
    camera's frustum (its image corners at a depth of a quarter of the rig's size) and name,
    and the sample points every camera sees (grey) or at least two see (light grey)."""
    points, seen = shared_volume(rig)
    counts = seen.sum(axis=0)
    centres = np.array([camera.center for camera in rig.cameras])
    size = max(float(np.ptp(centres, axis=0).max()), float(np.ptp(points, axis=0).max()) / 3, 1e-9)
    depth = 0.25 * size
    frusta = []
    for camera in rig.cameras:
        corners = np.array([[-0.5, -0.5], [camera.width - 0.5, -0.5], [camera.width - 0.5, camera.height - 0.5],
                            [-0.5, camera.height - 0.5]])
        _, directions = camera.rays(corners)
        cosine = directions @ camera.R[2]
        ends = camera.center + directions * (depth / np.where(np.isfinite(cosine) & (cosine > 0), cosine, np.inf))[:, None]
        frusta.append(np.vstack([camera.center, np.nan_to_num(ends, nan=0.0)]))
    everything = np.vstack([centres, *frusta, points[counts >= 2] if (counts >= 2).any() else centres])
    lower, upper = everything.min(axis=0), everything.max(axis=0)
    views = [(0, 1, "x right, y up"), (0, 2, "x right, z up"), (2, 1, "z right, y up")]
    panels = [_panel(rig, frusta, points, counts, lower, upper, a, b, label) for a, b, label in views]
    picture = np.hstack(panels)
    path = Path(file)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), picture):
        raise InvalidInputError(f"could not write the picture {path} (a .png path?)")
    return path


def _panel(rig: Rig, frusta: list[NDArray[np.float64]], points: NDArray[np.float64], counts: NDArray[np.int64],
           lower: NDArray[np.float64], upper: NDArray[np.float64], a: int, b: int, label: str) -> NDArray[np.uint8]:
    image = np.full((PANEL, PANEL, 3), 255, np.uint8)
    span = max(upper[a] - lower[a], upper[b] - lower[b], 1e-12)
    scale = (PANEL - 60) / span
    middle = 0.5 * (lower + upper)

    def pixel(p: NDArray[np.float64]) -> NDArray[np.int32]:
        u = PANEL / 2 + (p[..., a] - middle[a]) * scale
        v = PANEL / 2 - (p[..., b] - middle[b]) * scale
        return np.round(np.stack([u, v], axis=-1) * 16).astype(np.int32)

    for threshold, colour in ((2, (225, 225, 225)), (len(rig), (150, 150, 150))):
        for u, v in pixel(points[counts >= threshold]) // 16:
            cv2.circle(image, (int(u), int(v)), 2, colour, -1)
    for index, (camera, frustum) in enumerate(zip(rig.cameras, frusta)):
        colour = _COLOURS[index % len(_COLOURS)]
        p = pixel(frustum)
        for corner in range(1, 5):
            cv2.line(image, tuple(p[0]), tuple(p[corner]), colour, 1, cv2.LINE_AA, shift=4)
            cv2.line(image, tuple(p[corner]), tuple(p[1 + corner % 4]), colour, 1, cv2.LINE_AA, shift=4)
        u, v = p[0] // 16
        cv2.putText(image, camera.name[:12], (int(u) + 3, int(v) - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.35, colour, 1,
                    cv2.LINE_AA)
    cv2.putText(image, label, (8, PANEL - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.rectangle(image, (0, 0), (PANEL - 1, PANEL - 1), (200, 200, 200), 1)
    return image
