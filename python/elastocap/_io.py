"""Atomic file writes: a killed run leaves either the old file or the new one, never half."""

from __future__ import annotations

import glob
import os
import signal
import tempfile
import zipfile
import zlib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import trimesh
from numpy.typing import NDArray

from elastocap._core import InvalidInputError

__all__ = ["MAX_ARRAY_BYTES", "atomic_write", "load_npz", "save_bytes", "save_image", "save_mesh", "save_npz", "save_text"]

# Largest array an .npz file may declare (its header is checked before anything is
# allocated): a file from elsewhere cannot make elastocap allocate more than this.
MAX_ARRAY_BYTES = 4 << 30

# Test hook of the kill-and-resume tests (tests/test_resume*.py): with
# ELASTOCAP_KILL_AT_WRITE=n the process kills itself (SIGKILL) at its n-th atomic write,
# when the temporary file is half written and not yet renamed: the worst moment to die.
_KILL_AT_WRITE = int(os.environ.get("ELASTOCAP_KILL_AT_WRITE", "0") or 0)
_writes = 0


def _killed_here(tmp: Path) -> None:
    global _writes
    _writes += 1
    if _writes == _KILL_AT_WRITE:
        size = tmp.stat().st_size
        with open(tmp, "r+b") as f:
            f.truncate(size // 2)
        os.kill(os.getpid(), signal.SIGKILL)


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
        if _KILL_AT_WRITE:
            _killed_here(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    # Temporary files of this path left by a killed run: the file is now whole.
    for stale in path.parent.glob(f".{glob.escape(path.name)}.*.tmp"):
        stale.unlink(missing_ok=True)


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


def save_text(path: Path, text: str) -> None:
    """``text`` to ``path`` as UTF-8, atomically."""
    save_bytes(path, text.encode("utf-8"))


def opencv_storage_text(path: Path, write: Callable[[Any], None]) -> str:
    """What ``cv2.FileStorage`` would write to ``path`` (YAML or XML by its suffix), built in
    memory so the caller can write it atomically: ``write(storage)`` fills the storage."""
    storage = cv2.FileStorage(path.suffix or ".yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    try:
        write(storage)
    except BaseException:
        storage.release()
        raise
    return str(storage.releaseAndGetString())


def save_image(path: Path, image: NDArray[np.uint8], *, jpeg_quality: int = 95) -> None:
    """An RGB (or grey) image, atomically; the format follows the suffix (.png, .jpg)."""
    pixels = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if path.suffix.lower() in (".jpg", ".jpeg") else []
    ok, encoded = cv2.imencode(path.suffix, np.ascontiguousarray(pixels), params)
    if not ok:
        raise OSError(f"could not encode {path}")
    save_bytes(path, encoded.tobytes())


def load_npz(path: Path, *, required: Iterable[str] = ()) -> dict[str, NDArray[Any]]:
    """Every array of the ``.npz`` file ``path``, read as untrusted input.

    Object arrays (pickles) are refused (``allow_pickle=False``), each array's declared size
    is checked against :data:`MAX_ARRAY_BYTES` and against its compressed member's stated
    size before it is allocated, and the arrays named in ``required`` must be present.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    InvalidInputError
        Anything else wrong with the file (not a zip, truncated, a pickle, too large, an
        array missing); the message names the file.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist")
    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                _check_member(archive, info)
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: np.asarray(data[name]) for name in data.files}
    except InvalidInputError as error:
        raise InvalidInputError(f"{path}: {error}") from None
    except (zipfile.BadZipFile, zlib.error, EOFError, ValueError, OSError, KeyError) as error:
        raise InvalidInputError(f"{path}: not a readable .npz file ({type(error).__name__}: {error})") from None
    missing = [name for name in required if name not in arrays]
    if missing:
        raise InvalidInputError(f"{path}: lacks the array(s) {missing} (it has {sorted(arrays)})")
    return arrays


def _check_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> None:
    """Refuse an array member whose header declares a pickle or more bytes than allowed."""
    if not info.filename.endswith(".npy"):
        return
    with archive.open(info) as member:
        version = np.lib.format.read_magic(member)
        header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, _, dtype = header(member)
    if dtype.hasobject:
        raise InvalidInputError(f"array {info.filename[:-4]!r} holds Python objects (a pickle), which elastocap does not load")
    size = int(np.prod(shape, dtype=object)) * dtype.itemsize
    if size > MAX_ARRAY_BYTES or size > info.file_size:
        raise InvalidInputError(
            f"array {info.filename[:-4]!r} declares {shape} {dtype} ({size} bytes), more than "
            f"{'its stored data' if size <= MAX_ARRAY_BYTES else f'the {MAX_ARRAY_BYTES} bytes allowed'}"
        )
