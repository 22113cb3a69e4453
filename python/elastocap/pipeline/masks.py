"""The silhouette stage of a capture without masks: a mask per camera and frame from the
colour frames, against the capture's background plate or its dark background.

Writes ``OUT/masks/<camera>/<frame:06d>.png`` (0 / 255, the layout of a capture's
``masks/``), each frame's masks atomically and skipped when all are there, so an
interrupted run resumes; :func:`masked_capture` gives the capture with these masks for the
stages after it.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from elastocap._core import InvalidInputError
from elastocap._io import save_image
from elastocap.capture.folder import Capture
from elastocap.silhouettes.background import segment_dark_background, subtract_background

__all__ = ["SILHOUETTE_METHODS", "choose_silhouettes", "masked_capture", "run_masks_stage"]

#: ``masks``: the capture's own; ``background``: difference to ``background/<camera>``;
#: ``dark``: a threshold on a dark background refined by GrabCut; ``auto``: the first of
#: these the capture allows.
SILHOUETTE_METHODS = ("auto", "masks", "background", "dark")


def choose_silhouettes(capture: Capture, method: str = "auto") -> str:
    """The silhouette method for ``capture``: ``method`` checked against what it holds, or
    for ``"auto"`` its masks, else its background plates, else a dark background.

    Raises
    ------
    InvalidInputError
        An unknown method, or one the capture lacks the files for.
    """
    if method not in SILHOUETTE_METHODS:
        raise InvalidInputError(f"silhouettes must be one of {', '.join(SILHOUETTE_METHODS)}, got {method!r}")
    if method == "auto":
        method = "masks" if capture.has_masks else "background" if capture.has_background else "dark"
    if method == "masks" and not capture.has_masks:
        raise InvalidInputError(f"{capture.root} has no masks/ folder: choose silhouettes = background or dark")
    if method in ("background", "dark") and not capture.has_images:
        raise InvalidInputError(f"{capture.root} has neither images/ nor videos/ to extract silhouettes from")
    if method == "background" and not capture.has_background:
        raise InvalidInputError(f"{capture.root} has no background/ folder for background subtraction")
    return method


def _mask_file(out: Path, camera: str, frame: int) -> Path:
    return out / "masks" / camera / f"{frame:06d}.png"


def run_masks_stage(
    capture: Capture | str | Path,
    out: str | Path,
    *,
    method: str = "auto",
    frames: Iterable[int] | None = None,
    dark_threshold: float = 30.0,
    progress: bool = True,
) -> list[int]:
    """Extract and write the silhouettes of every frame; returns the frames written now
    (none when the capture's own masks are used).

    Parameters
    ----------
    capture : Capture or path
    out : path
        Output folder; ``out/masks/`` is created.
    method : {"auto", "masks", "background", "dark"}
        See :data:`SILHOUETTE_METHODS`.
    frames : iterable of int, optional
        Default: all frames of the capture.
    dark_threshold : float
        Grey level (0 to 255) above which a pixel may be the object, for ``"dark"``.
    progress : bool
        Show a progress bar.
    """
    cap = capture if isinstance(capture, Capture) else Capture.open(capture)
    method = choose_silhouettes(cap, method)
    if method == "masks":
        return []
    out = Path(out)
    backgrounds = {name: cap.background(name) for name in cap.cameras} if method == "background" else {}
    wanted = list(cap.frames if frames is None else frames)
    todo = [f for f in wanted if not all(_mask_file(out, name, f).exists() for name in cap.cameras)]
    for frame in tqdm(todo, desc=f"silhouettes ({method})", unit="frame", disable=not progress):
        for name in cap.cameras:
            image = cap.image(name, frame)
            if method == "background":
                mask = subtract_background(image, backgrounds[name])
            else:
                mask = segment_dark_background(image, dark_threshold)
            save_image(_mask_file(out, name, frame), np.where(mask, 255, 0).astype(np.uint8))
    return todo


def masked_capture(capture: Capture, out: str | Path, *, method: str = "auto") -> Capture:
    """``capture`` with the silhouettes the stages after this one use: its own masks, or
    those :func:`run_masks_stage` wrote into ``out/masks``."""
    if choose_silhouettes(capture, method) == "masks":
        return capture
    return capture.with_masks(Path(out) / "masks")
