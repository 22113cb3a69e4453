"""Atomic file writes: a killed run leaves either the old file or the new one, never half."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import trimesh
from numpy.typing import NDArray

__all__ = ["atomic_write", "save_bytes", "save_image", "save_mesh", "save_npz"]


def atomic_write(path: Path, write: Callable[[Path], Any]) -> None:
    """Call ``write(temporary_path)`` then rename the result onto ``path``.

    The temporary file sits beside ``path`` as ``.<name>.<random>.tmp``, which listings by
    suffix (frames, masks, images) do not pick up.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def save_npz(path: Path, **arrays: Any) -> None:
    """``numpy.savez_compressed`` to ``path``, atomically."""

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)

    atomic_write(path, write)


def save_mesh(path: Path, mesh: trimesh.Trimesh) -> None:
    """A mesh in the format of ``path``'s suffix (PLY, OBJ, GLB...), atomically."""
    atomic_write(path, lambda tmp: mesh.export(tmp, file_type=path.suffix.lstrip(".")))


def save_bytes(path: Path, data: bytes) -> None:
    """``data`` to ``path``, atomically."""
    atomic_write(path, lambda tmp: tmp.write_bytes(data))


def save_image(path: Path, image: NDArray[np.uint8], *, jpeg_quality: int = 95) -> None:
    """An RGB (or grey) image, atomically; the format follows the suffix (.png, .jpg)."""
    pixels = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if path.suffix.lower() in (".jpg", ".jpeg") else []
    ok, encoded = cv2.imencode(path.suffix, np.ascontiguousarray(pixels), params)
    if not ok:
        raise OSError(f"could not encode {path}")
    save_bytes(path, encoded.tobytes())
