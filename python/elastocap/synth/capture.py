"""A synthetic capture: an articulated figure in motion, seen by a ring of cameras.

The figure is a smooth union of capsules on a small human skeleton (metres, **y up**, the
figure facing +z at yaw 0, its left on +x), walking in place with large arm and leg swings,
turning slowly, and clapping its hands once per walk cycle (the hands touch). A ring of
cameras, some higher up looking down, with skew and lens distortion, sees it whole in every
frame. Silhouettes and shaded colour images are rasterised from the ground-truth surface
(marching cubes of the signed distance), and :func:`write_synthetic_capture` writes the
capture folder of DESIGN.md with the ground truth beside it::

    CAPTURE/
      intri.yml, extri.yml                   the rig (Rig.save)
      images/<camera>/<frame:06d>.jpg        shaded colour frames
      masks/<camera>/<frame:06d>.png         exact silhouettes, 0 / 255
      background/<camera>.png                the empty scene
      ground_truth/<frame:06d>.ply           the surface (world units, vertex colours)
      ground_truth/figure.json               skeleton, motion parameters, seed, frames
      ground_truth/body.json                 (figure="body") body model, shape, states

This is the demo's input and the tests' ground truth.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor, as_completed
from functools import lru_cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import trimesh
from numpy.typing import NDArray
from tqdm import tqdm

from elastocap.render.mesh import render_mesh
from elastocap._core import InvalidInputError
from elastocap.synth.capsules import FIGURE_FORMAT, CapsuleFigure
from elastocap._io import save_bytes, save_image
from elastocap._validate import as_count, as_float_array, as_positive
from elastocap.cameras import Camera, Rig

__all__ = [
    "render_background",
    "ring_rig",
    "write_synthetic_capture",
]

# ------------------------------------------------------------------------------------------
# The camera ring
# ------------------------------------------------------------------------------------------


def ring_rig(
    n_cameras: int = 8,
    *,
    width: int = 1024,
    height: int = 768,
    radius: float = 4.0,
    height_above: float = 1.3,
    look_at: Any = (0.0, 0.9, 0.0),
    fov: float = 50.0,
    seed: int = 0,
) -> Rig:
    """Cameras on a ring around the origin, and (from 6 cameras on) some higher up.

    Parameters
    ----------
    n_cameras : int, default 8
        At least 1. From 6 on, ``max(2, n_cameras // 4)`` of them are elevated: at
        ``height_above + 1.9`` m on a ring of ``0.7 radius``, between the low cameras'
        azimuths, looking down at ``look_at`` (about 40 degrees down by default).
    width, height : int, default 1024, 768, keyword-only
        Image size, pixels.
    radius : float, default 4.0, keyword-only
        Horizontal distance of the low ring from the y axis, metres.
    height_above : float, default 1.3, keyword-only
        Height of the low ring above the floor (y = 0), metres.
    look_at : (3,) array_like, default (0, 0.9, 0), keyword-only
        The world point every camera's optical axis passes through, metres.
    fov : float, default 50, keyword-only
        Horizontal field of view, degrees (focal length ``(width / 2) / tan(fov / 2)``).
    seed : int, default 0, keyword-only
        Draws small perturbations (azimuth offset, principal points within 1% of the
        size, aspect within 0.3%) so that the rig has no exact symmetry.

    Returns
    -------
    Rig
        Cameras ``cam00``, ``cam01``, ... (low ring first), world -> camera as OpenCV.
        Every third camera, from ``cam01``, has barrel distortion (``k1 = -0.05``,
        ``k2 = 0.01``); every third from ``cam02`` pincushion with tangential terms
        (``k1 = 0.03``, ``p1 = 2e-4``, ``p2 = -1e-4``); ``cam01`` also has a skew of
        ``1.5 * width / 1024`` pixels.
    """
    n = as_count("n_cameras", n_cameras, minimum=1)
    width = as_count("width", width)
    height = as_count("height", height)
    radius = as_positive("radius", radius)
    height_above = as_positive("height_above", height_above)
    fov = as_positive("fov", fov)
    if fov >= 170:
        raise InvalidInputError(f"fov must be below 170 degrees, got {fov}")
    target = as_float_array("look_at", look_at).reshape(-1)
    if target.shape != (3,) or not np.isfinite(target).all():
        raise InvalidInputError(f"look_at must be 3 finite numbers, got {look_at!r}")
    rng = np.random.default_rng([as_count("seed", seed, minimum=0), 0xCA3])
    elevated = max(2, n // 4) if n >= 6 else 0
    low = n - elevated
    offset = rng.uniform(0, 2 * np.pi / low)
    centres = [
        (radius * math.cos(offset + 2 * math.pi * i / low), height_above, radius * math.sin(offset + 2 * math.pi * i / low))
        for i in range(low)
    ]
    centres += [
        (0.7 * radius * math.cos(offset + 2 * math.pi * (i + 0.5) / elevated), height_above + 1.9,
         0.7 * radius * math.sin(offset + 2 * math.pi * (i + 0.5) / elevated))
        for i in range(elevated)
    ]
    focal = (width / 2) / math.tan(math.radians(fov) / 2)
    cameras = []
    for i, centre in enumerate(centres):
        R = _look_at_rotation(np.array(centre), target)
        skew = 1.5 * width / 1024 if i == 1 else 0.0
        K = np.array([
            [focal, skew, (width - 1) / 2 + rng.uniform(-0.01, 0.01) * width],
            [0.0, focal * (1 + rng.uniform(-0.003, 0.003)), (height - 1) / 2 + rng.uniform(-0.01, 0.01) * height],
            [0.0, 0.0, 1.0],
        ])
        dist = [(0.0, 0.0, 0.0, 0.0, 0.0), (-0.05, 0.01, 0.0, 0.0, 0.0), (0.03, 0.0, 2e-4, -1e-4, 0.0)][i % 3]
        cameras.append(Camera(f"cam{i:02d}", K, dist, R, -R @ np.array(centre), width, height))
    return Rig(cameras)


def _look_at_rotation(centre: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray[np.float64]:
    """World -> camera rotation (OpenCV: x right, y down, z forward) of a camera at
    ``centre`` looking at ``target`` with the world's y axis up in the image."""
    forward = target - centre
    norm = np.linalg.norm(forward)
    if norm == 0:
        raise InvalidInputError("a camera sits on its look_at point")
    forward = forward / norm
    right = np.cross(forward, [0.0, 1.0, 0.0])
    if np.linalg.norm(right) < 1e-9:
        raise InvalidInputError("a camera looks straight up or down: no image 'up' direction")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([right, down, forward])


# ------------------------------------------------------------------------------------------
# The empty scene
# ------------------------------------------------------------------------------------------


def render_background(camera: Camera) -> NDArray[np.uint8]:
    """The empty scene: a mid-grey chequered floor (0.5 m tiles, y = 0) inside a panelled
    grey cylindrical wall (radius 8 m, centred on the y axis).

    Parameters
    ----------
    camera : Camera

    Returns
    -------
    (H, W, 3) uint8
        RGB, a new array (cached per camera, copied on return).

    Notes
    -----
    Rays are cast at a quarter of the resolution and the result resized: the backdrop only
    needs to be textured and static, not sharp.
    """
    if not isinstance(camera, Camera):
        raise InvalidInputError(f"camera must be an elastocap.Camera, got {type(camera).__name__}")
    return _background(camera).copy()


_BACKGROUND_SUBSAMPLING = 4
_WALL_RADIUS = 8.0


@lru_cache(maxsize=32)
def _background(camera: Camera) -> NDArray[np.uint8]:
    step = _BACKGROUND_SUBSAMPLING
    columns = -(-camera.width // step)
    rows = -(-camera.height // step)
    u, v = np.meshgrid(
        (np.arange(columns) + 0.5) * step - 0.5, (np.arange(rows) + 0.5) * step - 0.5
    )
    origins, directions = camera.rays(np.column_stack([u.ravel(), v.ravel()]))
    o, d = origins[0], directions
    # Wall: |o_xz + t d_xz| = R, the positive root.
    a = d[:, 0] ** 2 + d[:, 2] ** 2
    b = 2 * (o[0] * d[:, 0] + o[2] * d[:, 2])
    c = o[0] ** 2 + o[2] ** 2 - _WALL_RADIUS**2
    with np.errstate(invalid="ignore", divide="ignore"):
        t_wall = (-b + np.sqrt(np.maximum(b * b - 4 * a * c, 0.0))) / (2 * a)
        t_floor = np.where(d[:, 1] < 0, -o[1] / d[:, 1], np.inf)
    on_floor = t_floor < t_wall
    grey = np.full(len(d), 0.5)
    floor = o + t_floor[on_floor, None] * d[on_floor]
    tiles = (np.floor(floor[:, 0] / 0.5) + np.floor(floor[:, 2] / 0.5)) % 2
    grey[on_floor] = 0.44 + 0.1 * tiles
    wall = o + np.nan_to_num(t_wall[~on_floor, None]) * d[~on_floor]
    panel = np.floor(np.degrees(np.arctan2(wall[:, 2], wall[:, 0])) / 10) % 2
    band = (wall[:, 1] > 1.0) & (wall[:, 1] < 1.2)
    grey[~on_floor] = 0.5 + 0.06 * panel - 0.12 * band
    grey[~np.isfinite(d).all(axis=1)] = 0.5
    tint = np.array([1.0, 0.98, 0.95])
    small = np.clip(np.rint(255 * grey[:, None] * tint), 0, 255).astype(np.uint8).reshape(rows, columns, 3)
    image = cv2.resize(small, (camera.width, camera.height), interpolation=cv2.INTER_LINEAR)
    image.flags.writeable = False
    return image


# ------------------------------------------------------------------------------------------
# The capture folder
# ------------------------------------------------------------------------------------------

JPEG_QUALITY = 95


def write_synthetic_capture(
    out: str | Path,
    *,
    frames: int = 30,
    cameras: int = 8,
    seed: int = 0,
    spacing: float = 0.01,
    image_size: tuple[int, int] = (1024, 768),
    workers: int | None = None,
    progress: bool = True,
    figure: str = "capsules",
    motion: str = "walk",
) -> Path:
    """Write a synthetic capture folder with its ground truth.

    Parameters
    ----------
    out : str or Path
        The capture folder; created if missing. A folder written before by this function
        with the same settings is resumed: frames whose files all exist are skipped.
    frames : int, default 30, keyword-only
        Frames ``0 .. frames - 1``; at least 1. 30 frames are one walk cycle, with one clap.
    cameras : int, default 8, keyword-only
        At least 2; see :func:`ring_rig` for the layout.
    seed : int, default 0, keyword-only
        The figure (:class:`CapsuleFigure`) and the rig's small perturbations.
    spacing : float, default 0.01, keyword-only
        Voxel edge of the ground-truth surface's marching cubes, metres.
    image_size : (width, height), default (1024, 768), keyword-only
        Pixels.
    workers : int, optional, keyword-only
        Frames rendered at once, in threads (numpy and OpenCV release the GIL for most of
        the work); default: the number of CPUs, at most 4.
    progress : bool, default True, keyword-only
        Show a progress bar.
    figure : {"capsules", "body"}, default "capsules", keyword-only
        What walks in the scene: the capsule figure (:class:`CapsuleFigure`, ground truth in
        ``ground_truth/figure.json``), or the body model itself
        (:class:`elastocap.synth.body.BodyFigure`: the default human with a shape within
        4% of unit and a smooth motion drawn from ``seed``), ground truth in
        ``ground_truth/body.json`` (model description, shape, per-frame states in the
        body stage's z-up frame), so that ``elastocap body`` can be scored.
    motion : {"walk", "fast"}, default "walk", keyword-only
        The capsule figure's motion (:class:`CapsuleFigure`): walking with a clap, or a
        fast arm swing across the chest and a leg kick (hand and foot 10 to 35 cm per
        frame), the elastic fit's hard case. The body figure only walks.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    InvalidInputError
        Bad counts or sizes; ``out`` is a file; ``out`` holds a synthetic capture written
        with other settings (seed, cameras, spacing or image size).

    Notes
    -----
    Every file is written under a temporary name and renamed into place
    (``os.replace``), so an interrupted run leaves only whole files, and a rerun finishes
    the frames that lack some. Images are JPEG (quality 95), masks PNG with 0 / 255,
    ground-truth surfaces binary PLY with vertex colours.
    """
    frames = as_count("frames", frames, minimum=1)
    n_cameras = as_count("cameras", cameras, minimum=2)
    seed = as_count("seed", seed, minimum=0)
    spacing = as_positive("spacing", spacing)
    try:
        width, height = image_size
    except (TypeError, ValueError):
        raise InvalidInputError(f"image_size must be (width, height), got {image_size!r}") from None
    width, height = as_count("width", width), as_count("height", height)
    workers = min(os.cpu_count() or 1, 4) if workers is None else as_count("workers", workers)
    root = Path(out)
    if root.exists() and not root.is_dir():
        raise InvalidInputError(f"out must be a folder, got the existing file {root}")

    walker: Any
    kind: type[Any]
    if figure == "capsules":
        walker, kind, description = CapsuleFigure(seed, motion=motion), CapsuleFigure, root / "ground_truth" / "figure.json"
    elif figure == "body" and motion != "walk":
        raise InvalidInputError(f"motion={motion!r} is a motion of the capsule figure; the body figure only walks")
    elif figure == "body":
        from elastocap.synth.body import BodyFigure

        walker, kind, description = BodyFigure(seed), BodyFigure, root / "ground_truth" / "body.json"
    else:
        raise InvalidInputError(f"figure must be 'capsules' or 'body', got {figure!r}")
    rig = ring_rig(n_cameras, width=width, height=height, seed=seed)
    settings = {"spacing": spacing, "image_size": [width, height], "cameras": n_cameras}
    written_frames = _check_resumable(root, description, walker, rig, settings, kind)

    # The description first: a folder holding it is recognised as ours when resuming.
    description.parent.mkdir(parents=True, exist_ok=True)
    total = max(frames, written_frames)
    record = walker.to_dict(total) if figure == "body" else walker.to_dict()
    record.update(frames=total, settings=settings)
    text = (json.dumps(record, indent=2) + "\n").encode()
    if not description.exists() or description.read_bytes() != text:
        save_bytes(description, text)
    for folder in ("images", "masks"):
        for name in rig.names:
            (root / folder / name).mkdir(parents=True, exist_ok=True)
    (root / "background").mkdir(exist_ok=True)
    if not (root / "intri.yml").exists() or not (root / "extri.yml").exists():
        _save_rig(rig, root)
    for camera in rig.cameras:
        path = root / "background" / f"{camera.name}.png"
        if not path.exists():
            save_image(path, render_background(camera), jpeg_quality=JPEG_QUALITY)

    todo = [n for n in range(frames) if not _frame_complete(root, rig, n)]
    executor = ThreadPoolExecutor(max_workers=workers)
    try:
        with tqdm(total=frames, initial=frames - len(todo), desc="elastocap synth", unit="frame",
                  disable=not progress) as bar:
            pending = [executor.submit(_write_frame, root, walker, rig, n, spacing) for n in todo]
            for done in as_completed(pending):
                done.result()
                bar.update(1)
    finally:
        # On an error or an interrupt, drop the frames not started; finished ones stay.
        executor.shutdown(wait=True, cancel_futures=True)
    return root


def _check_resumable(
    root: Path, description: Path, figure: Any, rig: Rig, settings: dict[str, Any], kind: Any = CapsuleFigure
) -> int:
    """The frame count an earlier run recorded (0 for a new folder); an error when the
    folder holds another synthetic capture."""
    if not root.is_dir():
        return 0
    if not description.exists():
        if (root / "intri.yml").exists() or (root / "extri.yml").exists() or (root / "images").exists():
            raise InvalidInputError(f"{root} holds a capture that elastocap synth did not write: use another --out")
        return 0
    try:
        previous = json.loads(description.read_text())
        same = (
            kind.from_dict(previous) == figure
            and previous.get("settings") == settings
            and (not (root / "intri.yml").exists() or Rig.load(root) == rig)
        )
    except (ValueError, KeyError, TypeError) as error:
        raise InvalidInputError(f"{description}: unreadable ({error}); use another --out") from None
    if not same:
        raise InvalidInputError(
            f"{root} holds a synthetic capture written with other settings (seed, cameras, spacing or "
            "image size): use another --out or delete it"
        )
    return int(previous.get("frames", 0))


def _frame_files(root: Path, rig: Rig, frame: int) -> Iterable[Path]:
    stem = f"{frame:06d}"
    for name in rig.names:
        yield root / "masks" / name / f"{stem}.png"
        yield root / "images" / name / f"{stem}.jpg"
    yield root / "ground_truth" / f"{stem}.ply"


def _frame_complete(root: Path, rig: Rig, frame: int) -> bool:
    return all(path.exists() for path in _frame_files(root, rig, frame))


def _write_frame(root: Path, figure: Any, rig: Rig, frame: int, spacing: float) -> None:
    mesh = figure.mesh(frame, spacing)
    stem = f"{frame:06d}"
    for camera in rig.cameras:
        mask, image = render_mesh(mesh, camera, background=render_background(camera))
        save_image(root / "masks" / camera.name / f"{stem}.png", mask.astype(np.uint8) * 255)
        save_image(root / "images" / camera.name / f"{stem}.jpg", image)
    ply = mesh.export(file_type="ply")
    assert isinstance(ply, bytes)
    save_bytes(root / "ground_truth" / f"{stem}.ply", ply)


def _save_rig(rig: Rig, root: Path) -> None:
    """``rig.save`` into a scratch folder, then both files renamed into place."""
    scratch = root / ".rig.tmp"
    if scratch.exists():
        shutil.rmtree(scratch)
    rig.save(scratch)
    for name in ("intri.yml", "extri.yml"):
        os.replace(scratch / name, root / name)
    scratch.rmdir()
