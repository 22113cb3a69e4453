"""elastocap's ``rig.json``: ``{"cameras": [{"name", "K", "dist", "R", "t", "width",
"height"}, ...]}``. Holds everything elastocap's camera holds, exactly (JSON floats in their
shortest exact form)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

from elastocap._core import InvalidInputError
from elastocap._io import save_text
from elastocap.cameras.formats.common import CameraRecord, settle_size, size_from_capture

if TYPE_CHECKING:
    from elastocap.cameras.camera import Camera

__all__ = ["read", "write"]

NAME = "json"


def read(file: Path, size: tuple[int, int] | None) -> list[CameraRecord]:
    """``{"cameras": [{"name", "K", "dist", "R", "t", "width", "height"}, ...]}``."""
    try:
        data = json.loads(file.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise InvalidInputError(f"{file}: not valid JSON ({error})") from None
    entries = data.get("cameras") if isinstance(data, dict) else None
    if not isinstance(entries, list) or not entries:
        raise InvalidInputError(f'{file}: expected {{"cameras": [...]}} with at least one camera')
    cameras: list[CameraRecord] = []
    for index, entry in enumerate(entries):
        where = f"{file}: cameras[{index}]"
        if not isinstance(entry, dict):
            raise InvalidInputError(f"{where} must be an object, got {type(entry).__name__}")
        missing = [key for key in ("name", "K", "R", "t") if key not in entry]
        if missing:
            raise InvalidInputError(f"{where} lacks {', '.join(missing)}")
        name = entry["name"]
        file_size = None
        if "width" in entry or "height" in entry:
            file_size = (entry.get("width"), entry.get("height"))
        image_size = size_from_capture(file.parent, str(name)) if file_size is None else None
        w, h = settle_size(str(name), file_size, image_size, size, file)
        cameras.append(
            CameraRecord(name, entry["K"], entry.get("dist"), entry["R"], entry["t"], w, h, where)
        )
    return cameras


def write(file: Path, cameras: Sequence[Camera]) -> None:
    """``{"cameras": [...]}`` with every field; Python prints floats in their shortest
    form that reads back exactly."""
    document = {"cameras": [_camera_json(camera) for camera in cameras]}
    save_text(file, json.dumps(document, indent=2) + "\n")


def _camera_json(camera: Camera) -> dict[str, Any]:
    return {
        "name": camera.name,
        "K": camera.K.tolist(),
        "dist": camera.dist.tolist(),
        "R": camera.R.tolist(),
        "t": camera.t.tolist(),
        "width": camera.width,
        "height": camera.height,
    }
