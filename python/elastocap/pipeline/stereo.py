"""The stereo stage of a capture (``elastocap stereo``): dense 3-D points with per-point
sigma and colour for every frame, from the camera pairs or triplets the capture names.

Writes, per frame::

    OUT/points/<frame:06d>.ply        binary PLY: x, y, z (float64, world units), red, green,
                                      blue (uint8), sigma (float64, world units: the standard
                                      deviation along the point's worst direction)
    OUT/points/<frame:06d>.npz        points (N, 3), sigma (N,), covariance (N, 3, 3),
                                      colours (N, 3) uint8, group (N,) int64 (the pair each
                                      point came from), pixels (N, 2) (in that pair's left
                                      camera), pairs (P,) str ("<left>-<right>")
    OUT/disparity/<pair>/<frame:06d>.png|.npz   the SGBM stage's files (the seeds)
    OUT/disparity/<camera>/<frame:06d>.png      the pair's disparity mask in its LEFT camera's
                                                pixels (0 / 255), what ``elastocap
                                                silhouettes`` reads; right cameras get none
    OUT/pictures/stereo/<frame:06d>.png         per pair: the disparity, and the points over
                                                the left image coloured by depth

Frames whose PLY and NPZ both exist are skipped (resume); every write is atomic.

The pairs: ``CAPTURE/stereo.json`` (``{"stereo_pairs": [["cam00", "cam01"], ...]}``, as
:func:`elastocap.synth.write_textured_capture` writes; a group of three gives the pairs of
its first camera with each other), else chosen by baseline (:func:`choose_pairs`).
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from elastocap._core import InvalidInputError
from elastocap._io import save_bytes, save_image, save_npz
from elastocap.cameras.rig import Rig
from elastocap.capture.folder import Capture
from elastocap.hull.grid import space_seen_by
from elastocap.stereo.disparity_stage import write_disparity
from elastocap.stereo.points import PairPoints, pair_points
from elastocap.stereo.rectify import RectifiedPair, rectify_pair

__all__ = ["choose_pairs", "pair_volume", "ply_bytes", "read_stereo_pairs", "run_stereo_stage"]

# A rig around a scene looks at its middle: of the space a pair sees, what lies further from
# the rig's vertical axis (through its middle, along the cameras' mean "up") than this share
# of the pair's distance to that axis is close to the cameras. "The space every camera sees"
# of a 4-camera ring reached to within 0.2 m of them (facing pairs see each other's near
# space) and SGBM's range was useless: 0 points. The region is a cylinder, not a ball: the
# rig's middle is at the cameras' mean height, not the scene's, and the box around a ball
# reached back towards the cameras at its corners. 0.4 of 3 m keeps the depths of a pair of
# the textured capture's rig between 1.3 and 4.7 m (tuned on seeds 0-1).
CENTRE_REGION = 0.4


def read_stereo_pairs(capture_root: str | Path, rig: Rig) -> list[list[str]] | None:
    """The camera groups of ``CAPTURE/stereo.json``, or None without the file.

    Raises
    ------
    InvalidInputError
        An unreadable file, a group of fewer than two cameras, or a name not in the rig.
    """
    path = Path(capture_root) / "stereo.json"
    if not path.is_file():
        return None
    try:
        groups = json.loads(path.read_text())["stereo_pairs"]
        groups = [[str(name) for name in group] for group in groups]
    except (ValueError, KeyError, TypeError) as error:
        raise InvalidInputError(f"{path}: expected {{\"stereo_pairs\": [[camera, camera], ...]}} ({error})") from None
    for group in groups:
        if len(group) < 2 or len(set(group)) != len(group):
            raise InvalidInputError(f"{path}: a group needs two or more different cameras, got {group}")
        unknown = [name for name in group if name not in rig.names]
        if unknown:
            raise InvalidInputError(f"{path}: cameras {unknown} are not in the rig ({rig.names})")
    return groups


def choose_pairs(rig: Rig, *, max_angle: float = 30.0) -> list[list[str]]:
    """Pairs by baseline when the capture names none: each camera with its nearest camera
    whose optical axis is within ``max_angle`` degrees of its own, shortest baselines
    first, each camera in at most one pair."""
    cameras = rig.cameras
    centres = np.array([c.center for c in cameras])
    axes = np.array([c.R[2] for c in cameras])
    distance = np.linalg.norm(centres[:, None] - centres[None], axis=2)
    parallel = axes @ axes.T >= np.cos(np.radians(max_angle))
    candidates = sorted(
        (distance[i, j], i, j) for i in range(len(cameras)) for j in range(i + 1, len(cameras)) if parallel[i, j]
    )
    used: set[int] = set()
    pairs = []
    for _, i, j in candidates:
        if i not in used and j not in used:
            used |= {i, j}
            pairs.append([cameras[i].name, cameras[j].name])
    return pairs


def ply_bytes(points: NDArray[np.float64], colours: NDArray[np.uint8], sigma: NDArray[np.float64]) -> bytes:
    """A binary little-endian PLY point cloud with ``sigma`` as a vertex property."""
    record = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("sigma", "<f8")])
    rows = np.empty(len(points), dtype=record)
    for k, name in enumerate("xyz"):
        rows[name] = points[:, k]
    for k, name in enumerate(("red", "green", "blue")):
        rows[name] = colours[:, k]
    rows["sigma"] = sigma
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment elastocap stereo: sigma = standard deviation along the worst direction\n"
        f"element vertex {len(points)}\nproperty double x\nproperty double y\nproperty double z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty double sigma\nend_header\n"
    )
    return header.encode() + rows.tobytes()


def _frame_files(out: Path, frame: int) -> tuple[Path, Path]:
    return out / "points" / f"{frame:06d}.ply", out / "points" / f"{frame:06d}.npz"


def run_stereo_stage(
    capture: Capture | str | Path,
    out: str | Path,
    *,
    frames: Iterable[int] | None = None,
    pairs: list[list[str]] | None = None,
    volume: Any = None,
    pictures: bool = True,
    progress: bool = True,
    **options: Any,
) -> list[int]:
    """Dense points of every frame from the capture's stereo pairs; returns the frames
    written now.

    Parameters
    ----------
    capture : Capture or path
    out : path
        Output folder (module docstring for what is written).
    frames : iterable of int, optional
        Frames to process (default all); frames already written are skipped.
    pairs : list of list of str, optional
        Camera groups; default ``CAPTURE/stereo.json`` or :func:`choose_pairs`.
    volume : (2, 3) array_like, optional
        Lower and upper corners of the capture volume (world units): SGBM's disparity
        range and the points kept. Default: per pair, the space both its cameras see within
        the rig's centre region (:func:`pair_volume`), which needs cameras around the scene.
    pictures : bool, default True
        Write ``OUT/pictures/stereo/<frame>.png``.
    progress : bool, default True
    **options
        Passed to :func:`~elastocap.stereo.points.pair_points` (e.g. ``step``, ``size``,
        ``min_correlation``, ``seed_spacing``).
    """
    cap = capture if isinstance(capture, Capture) else Capture.open(capture)
    if not cap.frames:
        raise InvalidInputError(f"{cap} has no frames (no images/ or videos/ frames)")
    wanted = list(cap.frames if frames is None else frames)
    unknown = sorted(set(wanted) - set(cap.frames))
    if unknown:
        raise InvalidInputError(f"frames {unknown[:5]} are not in the capture (it has {cap.frames[0]}..{cap.frames[-1]})")
    groups = pairs if pairs is not None else read_stereo_pairs(cap.root, cap.rig) or choose_pairs(cap.rig)
    if not groups:
        raise InvalidInputError(f"{cap}: no camera pair to match (no stereo.json, and no two cameras look the same way)")
    if volume is not None:
        volume = np.asarray(volume, dtype=np.float64)
        if volume.shape != (2, 3) or not np.isfinite(volume).all() or not (volume[1] > volume[0]).all():
            raise InvalidInputError(f"volume must be (2, 3) finite corners with lower < upper, got {volume.tolist()}")
    rectified: list[RectifiedPair] = []
    volumes: list[Any] = []
    for group in groups:
        for other in group[1:]:
            volumes.append(pair_volume(cap.rig, [group[0], other]) if volume is None else volume)
            # Centred on the images, not on the volume: the volume (all the space every camera
            # sees) projects lopsided from a raised pair, and centring on it cut the upper
            # body out of the rectified view of the textured capture's elevated pairs.
            rectified.append(rectify_pair(cap.rig[group[0]], cap.rig[other]))
    out = Path(out)
    todo = [f for f in wanted if not all(p.exists() for p in _frame_files(out, f))]
    for frame in tqdm(todo, desc="stereo", unit="frame", disable=not progress):
        results = []
        for pair, seen in zip(rectified, volumes):
            left, right = cap.image(pair.left.name, frame), cap.image(pair.right.name, frame)
            mask = cap.mask(pair.left.name, frame) if cap.has_masks else None
            if mask is not None:
                mask = cv2.dilate(mask.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
            result = pair_points(pair, left, right, seen, mask=mask, **options)
            write_disparity(out, result.disparity, frame)
            # The silhouette stage reads the disparity mask per camera, in its own pixels.
            save_image(out / "disparity" / pair.left.name / f"{frame:06d}.png", result.disparity.mask_original.astype(np.uint8) * 255)
            results.append(result)
        # The silhouette stage needs a disparity mask in every camera: a camera that is only
        # ever a pair's right one gets the left's masked points projected into it.
        lefts = {pair.left.name for pair in rectified}
        for pair, result in zip(rectified, results):
            if pair.right.name not in lefts:
                mask = projected_mask(pair.right, result.disparity.points)
                save_image(out / "disparity" / pair.right.name / f"{frame:06d}.png", mask.astype(np.uint8) * 255)
        _write_frame(out, frame, results)
        if pictures:
            save_image(out / "pictures" / "stereo" / f"{frame:06d}.png", stereo_picture(cap, frame, results))
    return todo


def pair_volume(rig: Rig, names: list[str], *, samples: int = 40) -> NDArray[np.float64]:
    """``(2, 3)`` lower and upper corners (world units) of the space both cameras ``names``
    of ``rig`` see within the rig's centre region: a grid over the box around the rig's
    cameras, kept where both cameras see it and no further from the rig's vertical axis
    (through the cameras' mean centre, along their mean image "up") than ``CENTRE_REGION``
    times the pair's distance to it. A rig that is one group of close cameras (no middle
    to look at) gets :func:`~elastocap.hull.grid.space_seen_by`.

    Raises
    ------
    InvalidInputError
        When no grid point qualifies (a pair that does not look at the rig's middle).
    """
    cameras = list(rig.cameras)
    centres = np.array([c.center for c in cameras])
    middle = centres.mean(axis=0)
    # Image rows point down: "up" is minus the second row of each rotation.
    up = -np.mean([np.asarray(c.R)[1] for c in cameras], axis=0)
    up /= max(float(np.linalg.norm(up)), 1e-12)

    def off_axis(x: NDArray[np.float64]) -> NDArray[np.float64]:
        d = x - middle
        return np.asarray(np.linalg.norm(d - np.outer(d @ up, up), axis=1))

    pair = [rig[name] for name in names]
    pair_distance = off_axis(np.array([c.center for c in pair]))
    baseline = np.linalg.norm(pair[0].center - pair[-1].center)
    if len(names) >= len(cameras) or pair_distance.min() <= baseline:
        return np.stack(space_seen_by(rig))
    reach = float(np.linalg.norm(centres - middle, axis=1).max())
    axis = np.linspace(-reach, reach, samples)
    points = middle + np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    keep = off_axis(points) <= CENTRE_REGION * float(pair_distance.mean())
    for camera in pair:
        keep &= camera.visible(points)
    if not keep.any():
        raise InvalidInputError(f"cameras {names} see nothing of the rig's centre region: pass volume=")
    step = 2 * reach / (samples - 1)
    return np.stack([points[keep].min(axis=0) - step, points[keep].max(axis=0) + step])


def projected_mask(camera: Any, points: NDArray[np.float64], *, closing: int = 3) -> NDArray[np.bool_]:
    """The pixels of ``camera`` that world ``points`` (N, 3) fall in, closed by an elliptic
    element of radius ``closing`` pixels: a mask from another view's dense points (its
    neighbour in a short-baseline pair sees nearly the same surface)."""
    mask = np.zeros((camera.height, camera.width), np.uint8)
    if len(points):
        uv, depth = camera.project(points)
        ij = np.rint(uv).astype(np.int64)
        keep = (depth > 0) & (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < camera.width) & (ij[:, 1] < camera.height)
        mask[ij[keep, 1], ij[keep, 0]] = 1
        element = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * closing + 1, 2 * closing + 1))
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, element)
    return mask > 0


def _write_frame(out: Path, frame: int, results: list[PairPoints]) -> None:
    points = np.concatenate([r.points for r in results]) if results else np.zeros((0, 3))
    sigma = np.concatenate([r.sigma for r in results]) if results else np.zeros(0)
    colours = np.concatenate([r.colours for r in results]) if results else np.zeros((0, 3), np.uint8)
    ply, npz = _frame_files(out, frame)
    save_npz(
        npz,
        points=points,
        sigma=sigma,
        covariance=np.concatenate([r.covariance for r in results]) if results else np.zeros((0, 3, 3)),
        colours=colours,
        group=np.concatenate([np.full(len(r.points), k, np.int64) for k, r in enumerate(results)]) if results else np.zeros(0, np.int64),
        pixels=np.concatenate([r.pixels for r in results]) if results else np.zeros((0, 2)),
        pairs=np.array([r.pair.name for r in results]),
    )
    save_bytes(ply, ply_bytes(points, colours, sigma))


def stereo_picture(cap: Capture, frame: int, results: list[PairPoints]) -> NDArray[np.uint8]:
    """Per pair, side by side: the rectified disparity (colour map, black where the check
    failed) and the left image with its points drawn coloured by depth."""
    from elastocap.pipeline.pictures import contact_sheet

    tiles: list[NDArray[np.uint8]] = []
    labels: list[str] = []
    for result in results:
        d = result.disparity.disparity.disparity
        valid = result.disparity.disparity.valid & np.isfinite(d)
        lo, hi = (np.percentile(d[valid], [2, 98]) if valid.any() else (0.0, 1.0))
        scaled = np.clip((np.nan_to_num(d) - lo) / max(hi - lo, 1e-9) * 255, 0, 255).astype(np.uint8)
        colour = np.ascontiguousarray(cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)[:, :, ::-1], dtype=np.uint8)
        colour[~valid] = 0
        tiles.append(colour)
        labels.append(f"{result.pair.name} disparity")
        image = cap.image(result.pair.left.name, frame).copy()
        if image.ndim == 2:
            image = np.repeat(image[:, :, None], 3, axis=2)
        if len(result.points):
            depth = result.pair.left.to_camera(result.points)[:, 2]
            lo, hi = np.percentile(depth, [2, 98])
            shade = np.clip((depth - lo) / max(hi - lo, 1e-9) * 255, 0, 255).astype(np.uint8)
            palette = cv2.applyColorMap(shade[:, None], cv2.COLORMAP_TURBO)[:, 0, ::-1]
            iu, iv = np.rint(result.pixels[:, 0]).astype(int), np.rint(result.pixels[:, 1]).astype(int)
            image[iv, iu] = palette
        tiles.append(image)
        labels.append(f"{result.pair.left.name}: {len(result.points)} points")
    return contact_sheet(tiles, labels, columns=2, width=480)
