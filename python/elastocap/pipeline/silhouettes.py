"""The model-based silhouette stage of a capture without masks or a background plate
(``elastocap silhouettes``): :class:`~elastocap.silhouettes.model_based.SilhouetteTracker`
run over the frames, its masks written as ``OUT/masks/<camera>/<frame:06d>.png``.

The sibling of :mod:`elastocap.pipeline.masks` (plates and dark backgrounds); its masks
feed ``elastocap hull``, ``fit`` and ``body`` the same way.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.capture.folder import Capture
from elastocap.silhouettes.model_based import SilhouetteTracker

__all__ = ["run_silhouettes_stage"]


def _read_mask(path: Path) -> NDArray[np.bool_] | None:
    import cv2

    if not path.exists():
        return None
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InvalidInputError(f"cannot read the mask {path}")
    return np.asarray(image != 0)


def run_silhouettes_stage(
    capture: Capture | str | Path,
    out: str | Path,
    *,
    frames: Iterable[int] | None = None,
    progress: bool = True,
    **options: Any,
) -> list[int]:
    """``elastocap silhouettes``: model-based silhouettes of every frame, written as
    ``out/masks/<camera>/<frame:06d>.png`` (0 / 255), the layout of a capture's ``masks/``,
    which ``elastocap hull``, ``fit`` and ``body`` then use.

    Inputs beside the images: the stereo stage's binarised disparity masks
    ``out/disparity/<camera>/<frame:06d>.png`` (non-zero: a disparity inside the
    reconstruction volume; needed for the first frame) and points
    ``out/points/<frame:06d>.npz`` (``points (N, 3)``, world) when present. Frames whose
    masks are all written are skipped; the loop resumes from the last of them.

    Returns
    -------
    list of int
        The frames written now.
    """
    from tqdm import tqdm

    from elastocap._io import load_npz, save_image

    cap = capture if isinstance(capture, Capture) else Capture.open(capture)
    out = Path(out)
    wanted = list(cap.frames if frames is None else frames)
    if not wanted:
        raise InvalidInputError(f"{cap} has no frames to extract silhouettes from (no images/ or videos/ frames)")
    names = cap.rig.names
    tracker = SilhouetteTracker(cap.rig, **options)

    def mask_path(name: str, frame: int) -> Path:
        return out / "masks" / name / f"{frame:06d}.png"

    written = []
    for frame in tqdm(wanted, desc="silhouettes", unit="frame", disable=not progress):
        if all(mask_path(n, frame).exists() for n in names):
            tracker.previous = {n: _read_mask(mask_path(n, frame)) for n in names}  # type: ignore[misc]
            continue
        disparity = {n: m for n in names if (m := _read_mask(out / "disparity" / n / f"{frame:06d}.png")) is not None}
        points_file = out / "points" / f"{frame:06d}.npz"
        points = None
        if points_file.exists():
            points = np.asarray(load_npz(points_file, required=("points",))["points"], dtype=np.float64)
        masks = tracker.step({n: cap.image(n, frame) for n in names}, disparity_masks=disparity, points=points)
        for n in names:
            save_image(mask_path(n, frame), masks[n].astype(np.uint8) * 255)
        written.append(frame)
    return written
