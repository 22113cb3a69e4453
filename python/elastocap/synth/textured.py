"""The textured synthetic capture: the capsule figure with a per-pixel texture fixed to its
body, seen by short-baseline stereo groups, with ground-truth depth and surface points.

For stereo matching, tracking and their scores (issue 14 item 7). The capture folder is the
one of :func:`~elastocap.synth.capture.write_synthetic_capture` plus::

    CAPTURE/
      stereo.json                              {"format": "elastocap.stereo/1",
                                                "stereo_pairs": [["cam00", "cam01"], ...]}
                                               the camera groups (pairs or triplets) that
                                               match with each other; names from the rig
      images/<camera>/<frame:06d>.png          lossless RGB (no JPEG blocks to match)
      ground_truth/depth/<camera>/<frame:06d>.npz
                                               "depth" (H, W) float32: z in the camera
                                               frame (metres, along the optical axis) of the
                                               figure's surface at each pixel centre; NaN
                                               where the figure is not (the background has
                                               no ground truth)
      ground_truth/surface_points.npz          "frames" (F,) int64, "positions" (F, N, 3)
                                               float64 world metres, "visible" (F, C, N)
                                               bool, "cameras" (C,) str, "part" (N,) int64,
                                               "material" (F, N) bool (the point shows the
                                               texture it was seeded on: false near joints,
                                               where the blended surface slides under it)
      ground_truth/figure.json                 the figure, settings, frames and groups

``stereo.json`` is the capture format's one addition: any capture may carry it (a user
writes it by hand for their rig), and the stereo stage uses it when present.
"""

from __future__ import annotations

import json
import math
import os
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from elastocap._core import InvalidInputError
from elastocap._io import load_npz, save_bytes, save_image, save_npz
from elastocap._validate import as_count, as_positive
from elastocap.cameras import Camera, Rig
from elastocap.synth.capsules import CapsuleFigure
from elastocap.synth.capture import _check_resumable, _look_at_rotation, _save_rig, render_background
from elastocap.synth.textured_render import (
    material_mask,
    material_points,
    render_textured,
    seed_material_points,
    visible_points,
)

__all__ = ["STEREO_FORMAT", "TexturedTruth", "load_textured_truth", "stereo_rig", "write_textured_capture"]

STEREO_FORMAT = "elastocap.stereo/1"


def stereo_rig(
    n_cameras: int = 8,
    *,
    width: int = 1024,
    height: int = 768,
    radius: float = 3.0,
    baseline: float = 0.3,
    look_at: Any = (0.0, 0.9, 0.0),
    fov: float = 50.0,
    seed: int = 0,
) -> tuple[Rig, list[list[str]]]:
    """Stereo groups on a ring: pairs side by side, a triplet when the count is odd.

    Parameters
    ----------
    n_cameras : int, default 8
        At least 2. ``n // 2`` groups; the last has three cameras when ``n`` is odd.
    width, height : int, keyword-only
        Image size, pixels.
    radius : float, default 3.0, keyword-only
        Horizontal distance of each group's centre from the y axis, metres.
    baseline : float, default 0.3, keyword-only
        Distance between the cameras of a pair (side by side, horizontal); a triplet's
        third camera sits ``baseline`` above the pair's midpoint. Metres.
    look_at : (3,) array_like, keyword-only
        Every optical axis passes through it (the cameras of a group converge).
    fov : float, default 50, keyword-only
        Horizontal field of view, degrees.
    seed : int, default 0, keyword-only
        The ring's azimuth offset and small perturbations of the principal points and
        aspect.

    Returns
    -------
    rig : Rig
        ``cam00``, ``cam01``, ...; groups at heights alternating 1.3 m and 2.2 m. Lenses as
        :func:`~elastocap.synth.capture.ring_rig`: every third camera from ``cam01`` barrel
        distortion, every third from ``cam02`` pincushion with tangential terms, ``cam01``
        a skew of ``1.5 * width / 1024`` pixels.
    groups : list of list of str
        Camera names per group, left camera first (as seen from the group).
    """
    n = as_count("n_cameras", n_cameras, minimum=2)
    width, height = as_count("width", width), as_count("height", height)
    radius, baseline, fov = as_positive("radius", radius), as_positive("baseline", baseline), as_positive("fov", fov)
    if fov >= 170:
        raise InvalidInputError(f"fov must be below 170 degrees, got {fov}")
    target = np.asarray(look_at, dtype=np.float64).reshape(-1)
    if target.shape != (3,) or not np.isfinite(target).all():
        raise InvalidInputError(f"look_at must be 3 finite numbers, got {look_at!r}")
    rng = np.random.default_rng([as_count("seed", seed, minimum=0), 0x57E])
    count = n // 2
    sizes = [2] * count
    sizes[-1] += n % 2
    offset = rng.uniform(0, 2 * np.pi / count)
    focal = (width / 2) / math.tan(math.radians(fov) / 2)
    cameras: list[Camera] = []
    groups: list[list[str]] = []
    for g, size in enumerate(sizes):
        azimuth = offset + 2 * math.pi * g / count
        middle = np.array([radius * math.cos(azimuth), 1.3 if g % 2 == 0 else 2.2, radius * math.sin(azimuth)])
        forward = target - middle
        # The group's right, seen from the group looking at the target.
        right = np.cross(forward, [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        centres = [middle - 0.5 * baseline * right, middle + 0.5 * baseline * right]
        if size == 3:
            centres.append(middle + np.array([0.0, baseline, 0.0]))
        names = []
        for centre in centres:
            i = len(cameras)
            R = _look_at_rotation(centre, target)
            skew = 1.5 * width / 1024 if i == 1 else 0.0
            K = np.array([
                [focal, skew, (width - 1) / 2 + rng.uniform(-0.01, 0.01) * width],
                [0.0, focal * (1 + rng.uniform(-0.003, 0.003)), (height - 1) / 2 + rng.uniform(-0.01, 0.01) * height],
                [0.0, 0.0, 1.0],
            ])
            dist = [(0.0, 0.0, 0.0, 0.0, 0.0), (-0.05, 0.01, 0.0, 0.0, 0.0), (0.03, 0.0, 2e-4, -1e-4, 0.0)][i % 3]
            cameras.append(Camera(f"cam{i:02d}", K, dist, R, -R @ centre, width, height))
            names.append(f"cam{i:02d}")
        groups.append(names)
    return Rig(cameras), groups


def write_textured_capture(
    out: str | Path,
    *,
    frames: int = 60,
    cameras: int = 8,
    seed: int = 0,
    motion: str = "walk",
    image_size: tuple[int, int] = (1024, 768),
    supersample: int = 3,
    noise: float = 2.0,
    points: int = 2000,
    workers: int | None = None,
    progress: bool = True,
) -> Path:
    """Write a textured synthetic capture folder with its ground truth (module docstring).

    Parameters
    ----------
    out : str or Path
        The capture folder; created if missing. A folder written before with the same
        settings is resumed: frames whose files all exist are skipped.
    frames : int, default 60, keyword-only
        Frames ``0 .. frames - 1``.
    cameras : int, default 8, keyword-only
        At least 2, in stereo groups (:func:`stereo_rig`).
    seed : int, default 0, keyword-only
        The figure (:class:`CapsuleFigure`), its texture, the rig's perturbations, the
        surface points and the sensor noise.
    motion : {"walk", "fast"}, default "walk", keyword-only
        The figure's motion.
    image_size : (width, height), default (1024, 768), keyword-only
    supersample : int, default 3, keyword-only
        Sub-pixels per pixel along each axis; each is coloured by the texture at its own
        surface point.
    noise : float, default 2.0, keyword-only
        Gaussian sensor noise, grey levels (standard deviation; 0 for none).
    points : int, default 2000, keyword-only
        Material surface points in ``ground_truth/surface_points.npz``, seeded uniformly by
        area on frame 0's surface and moved with their body part.
    workers : int, optional, keyword-only
        Frames rendered at once in threads; default the number of CPUs, at most 4.
    progress : bool, default True, keyword-only

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    InvalidInputError
        Bad counts or sizes; ``out`` is a file or holds another capture.

    Notes
    -----
    Surfaces are the marching cubes of the figure at 1 cm (``ground_truth/<frame>.ply``);
    images and depth are rendered from those meshes, so depth and surface points agree with
    the PLY files. Every file is written atomically; ``surface_points.npz`` last, from the
    depth maps, once every frame is complete.
    """
    frames = as_count("frames", frames, minimum=1)
    n_cameras = as_count("cameras", cameras, minimum=2)
    seed = as_count("seed", seed, minimum=0)
    supersample = as_count("supersample", supersample)
    n_points = as_count("points", points)
    if not isinstance(noise, (int, float)) or not math.isfinite(noise) or noise < 0:
        raise InvalidInputError(f"noise must be a finite number >= 0, got {noise!r}")
    try:
        width, height = image_size
    except (TypeError, ValueError):
        raise InvalidInputError(f"image_size must be (width, height), got {image_size!r}") from None
    width, height = as_count("width", width), as_count("height", height)
    workers = min(os.cpu_count() or 1, 4) if workers is None else as_count("workers", workers)
    root = Path(out)
    if root.exists() and not root.is_dir():
        raise InvalidInputError(f"out must be a folder, got the existing file {root}")

    figure = CapsuleFigure(seed, motion=motion)
    rig, groups = stereo_rig(n_cameras, width=width, height=height, seed=seed)
    description = root / "ground_truth" / "figure.json"
    settings = {
        "kind": "textured", "spacing": _SPACING, "image_size": [width, height], "cameras": n_cameras,
        "supersample": supersample, "noise": float(noise), "points": n_points,
    }
    written = _check_resumable(root, description, figure, rig, settings)
    description.parent.mkdir(parents=True, exist_ok=True)
    total = max(frames, written)
    record = figure.to_dict()
    record.update(frames=total, settings=settings, stereo_pairs=groups)
    text = (json.dumps(record, indent=2) + "\n").encode()
    if not description.exists() or description.read_bytes() != text:
        save_bytes(description, text)
    for name in rig.names:
        for folder in (root / "images" / name, root / "masks" / name, root / "ground_truth" / "depth" / name):
            folder.mkdir(parents=True, exist_ok=True)
    (root / "background").mkdir(exist_ok=True)
    if not (root / "intri.yml").exists() or not (root / "extri.yml").exists():
        _save_rig(rig, root)
    stereo = (json.dumps({"format": STEREO_FORMAT, "stereo_pairs": groups}, indent=2) + "\n").encode()
    if not (root / "stereo.json").exists() or (root / "stereo.json").read_bytes() != stereo:
        save_bytes(root / "stereo.json", stereo)
    for camera in rig.cameras:
        path = root / "background" / f"{camera.name}.png"
        if not path.exists():
            save_image(path, render_background(camera))

    todo = [n for n in range(frames) if not _frame_complete(root, rig, n)]
    executor = ThreadPoolExecutor(max_workers=workers)
    try:
        with tqdm(total=frames, initial=frames - len(todo), desc="elastocap synth (textured)", unit="frame",
                  disable=not progress) as bar:
            pending = [executor.submit(_write_frame, root, figure, rig, n, seed, supersample, float(noise)) for n in todo]
            for done in as_completed(pending):
                done.result()
                bar.update(1)
    finally:
        executor.shutdown(wait=True, cancel_futures=True)
    _write_surface_points(root, figure, rig, total, n_points, seed)
    return root


# Marching-cubes voxel of the ground-truth surfaces, metres.
_SPACING = 0.01


def _frame_complete(root: Path, rig: Rig, frame: int) -> bool:
    stem = f"{frame:06d}"
    files = [root / "ground_truth" / f"{stem}.ply"]
    for name in rig.names:
        files += [root / "images" / name / f"{stem}.png", root / "masks" / name / f"{stem}.png",
                  root / "ground_truth" / "depth" / name / f"{stem}.npz"]
    return all(path.exists() for path in files)


def _write_frame(root: Path, figure: CapsuleFigure, rig: Rig, frame: int, seed: int, supersample: int, noise: float) -> None:
    mesh = figure.mesh(frame, _SPACING)
    stem = f"{frame:06d}"
    for index, camera in enumerate(rig.cameras):
        rng = np.random.default_rng([seed, frame, index, 0x7E5])
        image, mask, depth = render_textured(
            mesh, figure, frame, camera, render_background(camera), supersample=supersample, noise=noise, rng=rng
        )
        save_npz(root / "ground_truth" / "depth" / camera.name / f"{stem}.npz", depth=depth)
        save_image(root / "masks" / camera.name / f"{stem}.png", mask.astype(np.uint8) * 255)
        save_image(root / "images" / camera.name / f"{stem}.png", image)
    ply = mesh.export(file_type="ply")
    assert isinstance(ply, bytes)
    save_bytes(root / "ground_truth" / f"{stem}.ply", ply)


def _write_surface_points(root: Path, figure: CapsuleFigure, rig: Rig, frames: int, count: int, seed: int) -> None:
    path = root / "ground_truth" / "surface_points.npz"
    if path.exists():
        if len(load_npz(path, required=["frames"])["frames"]) == frames:
            return
    if not all(_frame_complete(root, rig, n) for n in range(frames)):
        return
    part, local = seed_material_points(figure, count, spacing=_SPACING, seed=seed)
    positions = np.empty((frames, count, 3))
    visible = np.zeros((frames, len(rig.cameras), count), dtype=bool)
    material = np.zeros((frames, count), dtype=bool)
    for n in range(frames):
        positions[n] = material_points(figure, n, part, local)
        if n == 0:
            # The texture coordinates the points show in frame 0 (on the field's zero level,
            # a fraction of a millimetre from the mesh they were sampled on).
            pose = figure.capsules(0)
            local = np.einsum("nji,nj->ni", pose.frames[part], positions[0] - pose.starts[part])
        material[n] = material_mask(figure, n, part, local, positions[n])
        for c, camera in enumerate(rig.cameras):
            depth = load_npz(root / "ground_truth" / "depth" / camera.name / f"{n:06d}.npz", required=["depth"])["depth"]
            visible[n, c] = visible_points(positions[n], camera, depth)
    save_npz(path, frames=np.arange(frames, dtype=np.int64), positions=positions, visible=visible,
             cameras=np.array(rig.names), part=part, material=material)


@dataclass(frozen=True)
class TexturedTruth:
    """The ground truth of a textured capture (:func:`load_textured_truth`).

    Attributes
    ----------
    figure : CapsuleFigure
    rig : Rig
    stereo_pairs : list of list of str
        The camera groups of ``stereo.json``.
    frames : (F,) int64
    positions : (F, N, 3) float64
        Material surface points, world metres.
    visible : (F, C, N) bool
        Whether camera ``c`` sees point ``n`` in frame ``f`` (depth-tested, inside the image).
    cameras : tuple of str
        The ``C`` camera names, rig order.
    part : (N,) int64
        Body part of each point (index into ``elastocap.synth.capsules.PARTS``).
    root : Path
    material : (F, N) bool
        Whether point ``n`` shows, in frame ``f``, the texture it was seeded on
        (:func:`~elastocap.synth.textured_render.material_mask`): measures of tracking
        (which follows the texture) use only material points.
    """

    figure: CapsuleFigure
    rig: Rig
    stereo_pairs: list[list[str]]
    frames: NDArray[np.int64]
    positions: NDArray[np.float64]
    visible: NDArray[np.bool_]
    cameras: tuple[str, ...]
    part: NDArray[np.int64]
    root: Path
    material: NDArray[np.bool_]

    def depth(self, camera: str, frame: int) -> NDArray[np.float32]:
        """``(H, W) float32``: the ground-truth depth of ``camera`` at ``frame`` (NaN off
        the figure)."""
        path = self.root / "ground_truth" / "depth" / camera / f"{frame:06d}.npz"
        if not path.exists():
            raise InvalidInputError(f"no ground-truth depth for camera {camera!r}, frame {frame}: {path}")
        return load_npz(path, required=["depth"])["depth"]

    def mesh_path(self, frame: int) -> Path:
        """The ground-truth surface of ``frame`` (PLY, world metres)."""
        return self.root / "ground_truth" / f"{frame:06d}.ply"


def load_textured_truth(folder: str | Path) -> TexturedTruth:
    """Read the ground truth of a capture written by :func:`write_textured_capture`.

    Raises
    ------
    InvalidInputError
        Not a textured capture, or one whose surface points are not written yet (an
        interrupted run: rerun the writer to finish it).
    """
    root = Path(folder)
    description = root / "ground_truth" / "figure.json"
    try:
        record = json.loads(description.read_text())
    except (OSError, ValueError) as error:
        raise InvalidInputError(f"{root}: not a textured synthetic capture ({error})") from None
    if record.get("settings", {}).get("kind") != "textured":
        raise InvalidInputError(f"{root}: not a textured synthetic capture (no textured settings in {description})")
    path = root / "ground_truth" / "surface_points.npz"
    if not path.exists():
        raise InvalidInputError(f"{path} is missing: the capture is incomplete, rerun write_textured_capture")
    data = load_npz(path, required=["frames", "positions", "visible", "cameras", "part"])
    figure = CapsuleFigure.from_dict(record)
    positions = data["positions"].astype(np.float64)
    part = data["part"].astype(np.int64)
    if "material" in data:
        material = data["material"].astype(bool)
    else:
        # Captures written before the field: recovered from frame 0, where every point is
        # exactly on its part.
        pose = figure.capsules(int(data["frames"][0]))
        local = np.einsum("nji,nj->ni", pose.frames[part], positions[0] - pose.starts[part])
        material = np.stack([material_mask(figure, int(f), part, local, x) for f, x in zip(data["frames"], positions)])
    return TexturedTruth(
        figure=figure,
        rig=Rig.load(root),
        stereo_pairs=[list(group) for group in record["stereo_pairs"]],
        frames=data["frames"].astype(np.int64),
        positions=positions,
        visible=data["visible"].astype(bool),
        cameras=tuple(str(name) for name in data["cameras"]),
        part=part,
        root=root,
        material=material,
    )
