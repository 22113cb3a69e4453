"""The hull stage of a capture: a visual hull, its surface and signed distance per frame.

Writes ``OUT/hull/<frame:06d>.ply`` (the surface, world units) and
``OUT/hull/<frame:06d>.npz`` (``occupancy`` bit-packed with its ``shape``, ``origin``,
``spacing``, ``sdf`` as float32), skipping frames already written, so an interrupted run
resumes where it stopped. Writes are atomic.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from elastocap._core import InvalidInputError
from elastocap._io import load_npz, save_mesh, save_npz
from elastocap.cameras.rig import Rig
from elastocap.capture.folder import Capture
from elastocap.hull.grid import Grid, space_seen_by
from elastocap.hull.sdf import SDF
from elastocap.hull.carve import Hull, visual_hull
from elastocap.hull.phantoms import drop_phantoms

__all__ = ["coarse_visibility", "frame_grid", "load_hull", "parse_frames", "run_hull_stage", "with_masks"]


def with_masks(cap: Capture, out: str | Path) -> Capture:
    """``cap`` itself when it has ``masks/``, else the same capture with the masks that
    ``elastocap silhouettes`` wrote into ``out/masks`` (same layout), when every camera
    has some there."""
    folder = Path(out) / "masks"
    if cap.has_masks or not folder.is_dir() or not all((folder / name).is_dir() for name in cap.cameras):
        return cap
    return cap.with_masks(folder)


# Voxels along the longest side of the coarse carving that locates the object.
_COARSE = 48


def coarse_visibility(rig: Rig, seen: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Which voxels of :func:`frame_grid`'s coarse grid every camera sees, ``(nx, ny, nz)``
    bool: the same for every frame of a rig, so a stage computes it once."""
    grid = Grid.around(seen[0], seen[1], _COARSE)
    centres = grid.centers().reshape(-1, 3)
    return np.logical_and.reduce([camera.visible(centres) for camera in rig.cameras]).reshape(grid.shape)


def frame_grid(
    masks: dict[str, np.ndarray],
    rig: Rig,
    resolution: int,
    seen: tuple[np.ndarray, np.ndarray],
    visibility: np.ndarray | None = None,
) -> Grid:
    """The grid of one frame: a coarse conservative carving of the seen space locates the
    object, and the grid covers its box (plus two coarse voxels) with ``resolution`` voxels
    along the longest side.

    Only coarse voxels that every camera sees locate the object: one that some camera does
    not see is not carved by it, so the cone of a silhouette reaching out of the other
    cameras' views would stretch the box. ``visibility``: :func:`coarse_visibility` of the
    rig, when already computed.
    """
    coarse = visual_hull(masks, rig, Grid.around(seen[0], seen[1], _COARSE))
    if visibility is None:
        visibility = coarse_visibility(rig, seen)
    located = coarse.occupancy & visibility
    if not located.any():
        raise InvalidInputError("the silhouettes carve away everything: check masks and calibration")
    index = np.argwhere(located)
    h = coarse.grid.spacing
    lower = coarse.grid.origin + h * index.min(axis=0) - 2 * h
    upper = coarse.grid.origin + h * index.max(axis=0) + 2 * h
    return Grid.around(lower, upper, resolution)


def _frame_files(out: Path, frame: int) -> tuple[Path, Path]:
    return out / "hull" / f"{frame:06d}.ply", out / "hull" / f"{frame:06d}.npz"


def load_hull(out: Path, frame: int) -> Hull:
    """The hull of ``frame`` written by :func:`run_hull_stage` into ``out``, with the signed
    distance the stage saved (float32, so the fit samples what was written, not a field
    computed again)."""
    file = _frame_files(Path(out), frame)[1]
    data = load_npz(file, required=("origin", "spacing", "shape", "occupancy"))
    try:
        grid = Grid(data["origin"], float(data["spacing"]), tuple(int(n) for n in data["shape"]))
        count = int(np.prod(grid.shape))
        occupancy = np.unpackbits(data["occupancy"], count=count).astype(bool).reshape(grid.shape)
        sdf = SDF(data["sdf"], grid) if "sdf" in data else None
    except (ValueError, TypeError) as error:  # InvalidInputError is a ValueError too
        raise InvalidInputError(f"{file}: not a hull written by elastocap ({error})") from None
    return Hull(occupancy, grid, sdf=sdf)


def run_hull_stage(
    capture: Capture | str | Path,
    out: str | Path,
    *,
    resolution: int = 128,
    frames: Iterable[int] | None = None,
    tolerance: int = 0,
    footprint: str = "center",
    phantoms: str = "drop",
    progress: bool = True,
) -> list[int]:
    """Carve, mesh and write the hull of every frame; returns the frames written now.

    Parameters
    ----------
    capture : Capture or path
        The capture folder (with masks).
    out : path
        Output folder; ``out/hull/`` is created.
    resolution : int
        Voxels along the longest side of each frame's grid.
    frames : iterable of int, optional
        Frames to process (default: all); frames already written are skipped.
    tolerance, footprint
        As in :func:`~elastocap.hull.carve.visual_hull`.
    phantoms : {"drop", "keep"}
        ``"drop"``: leave out the hull's components that explain no silhouette pixel of
        their own (:func:`~elastocap.hull.phantoms.drop_phantoms`: blobs in space that few
        cameras see, which the elastic model would take for part of the subject).
    progress : bool
        Show a progress bar.
    """
    cap = with_masks(capture if isinstance(capture, Capture) else Capture.open(capture), out)
    if not cap.has_masks:
        raise InvalidInputError(f"{cap} has no masks/ folder (nor OUT/masks from `elastocap silhouettes`): the hull stage needs silhouettes")
    if not cap.frames:
        raise InvalidInputError(f"{cap} has no frames to carve (its masks/ folders hold no frame files)")
    wanted = list(cap.frames if frames is None else frames)
    if not wanted:
        raise InvalidInputError(f"frames: none asked for (the capture has frames {cap.frames[0]}..{cap.frames[-1]})")
    unknown = sorted(set(wanted) - set(cap.frames))
    if unknown:
        raise InvalidInputError(f"frames {unknown[:5]} are not in the capture (it has {cap.frames[0]}..{cap.frames[-1]})")
    if phantoms not in ("drop", "keep"):
        raise InvalidInputError(f"phantoms must be 'drop' or 'keep', got {phantoms!r}")
    out = Path(out)
    todo = [f for f in wanted if not all(p.exists() for p in _frame_files(out, f))]
    seen = space_seen_by(cap.rig)
    visibility = coarse_visibility(cap.rig, seen)
    for frame in tqdm(todo, desc="hull", unit="frame", disable=not progress):
        masks = cap.masks(frame)
        # missing = "present": a frame some cameras lack is carved with the others.
        rig = cap.rig_at(frame)
        blank = [name for name, mask in masks.items() if not mask.any()]
        if blank:
            raise InvalidInputError(
                f"frame {frame}: the mask of camera(s) {blank} is all background, which carves "
                f"the whole hull away; frames written so far are kept"
            )
        grid = frame_grid(masks, rig, resolution, seen, visibility if rig is cap.rig else None)
        hull = visual_hull(masks, rig, grid, tolerance=tolerance, footprint=footprint)
        if phantoms == "drop":
            hull = drop_phantoms(hull, masks, rig)
        ply, npz = _frame_files(out, frame)
        save_npz(
            npz,
            occupancy=np.packbits(hull.occupancy.reshape(-1)),
            shape=np.array(grid.shape),
            origin=grid.origin,
            spacing=np.float64(grid.spacing),
            sdf=hull.sdf().values.astype(np.float32),
        )
        save_mesh(ply, hull.mesh())
    return todo


def parse_frames(text: str | None, available: list[int]) -> list[int] | None:
    """``"a:b"`` (Python slice of frame numbers, end exclusive), ``"a"``, or None for all."""
    if text is None:
        return None
    try:
        if ":" in text:
            start, _, stop = text.partition(":")
            lo = int(start) if start else available[0] if available else 0
            hi = int(stop) if stop else available[-1] + 1 if available else 0
        else:
            return [int(text)]
    except ValueError:
        raise InvalidInputError(f"--frames must look like 'a:b' or 'a', got {text!r}") from None
    chosen = [f for f in available if lo <= f < hi]
    if not chosen:
        have = f"{available[0]}..{available[-1]}" if available else "none"
        raise InvalidInputError(f"--frames {text} selects no frame of the capture (it has frames {have})")
    return chosen


