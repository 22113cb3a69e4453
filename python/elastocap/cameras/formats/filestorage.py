"""OpenCV FileStorage (YAML / XML) reading shared by the EasyMocap and OpenCV-stereo
formats: opening with a one-line error, matrices, scalars, name lists, Rodrigues vectors."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError

__all__ = ["open_storage", "read_matrix", "read_names", "read_scalar", "rodrigues"]


def open_storage(file: Path) -> cv2.FileStorage:
    try:
        storage = cv2.FileStorage(str(file), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as error:
        # A parse error surfaces as cv2.error, or as a SystemError wrapping it.
        cause = error.__cause__ or error.__context__ or error
        text = str(cause).strip()
        found = re.search(r"\((\d+)\): ([^']+)'?\s*$", text)
        message = f"line {found[1]}: {found[2].strip()}" if found else (text.splitlines() or ["parse error"])[-1]
        raise InvalidInputError(f"{file}: not a readable OpenCV YAML file ({message})") from None
    if not storage.isOpened():
        raise InvalidInputError(f"{file}: not a readable OpenCV YAML file")
    return storage


def read_names(storage: cv2.FileStorage, file: Path, *, required: bool = True) -> list[str] | None:
    node = storage.getNode("names")
    if node.empty() or node.isNone():
        if required:
            raise InvalidInputError(f"{file}: no 'names' list of cameras")
        return None
    if not node.isSeq():
        raise InvalidInputError(f"{file}: 'names' must be a sequence of camera names")
    names = []
    for index in range(node.size()):
        item = node.at(index)
        if item.isString():
            names.append(item.string())
        elif item.isInt():
            names.append(str(int(item.real())))
        else:
            raise InvalidInputError(f"{file}: names[{index}] is not a camera name")
    if not names:
        raise InvalidInputError(f"{file}: 'names' is empty")
    return names


def read_matrix(
    storage: cv2.FileStorage, key: str, file: Path, *, required: bool
) -> NDArray[np.float64] | None:
    node = storage.getNode(key)
    if node.empty() or node.isNone():
        if required:
            raise InvalidInputError(f"{file}: {key} is missing")
        return None
    if node.isMap():
        try:
            matrix = node.mat()
        except cv2.error:
            matrix = None
        if matrix is None:
            raise InvalidInputError(f"{file}: {key} is not a readable matrix (malformed numbers?)")
        return np.asarray(matrix, dtype=np.float64)
    if node.isSeq():
        values = [node.at(i) for i in range(node.size())]
        if all(v.isReal() or v.isInt() for v in values):
            return np.array([v.real() for v in values], dtype=np.float64)
    raise InvalidInputError(f"{file}: {key} is not a matrix (expected !!opencv-matrix)")


def read_scalar(storage: cv2.FileStorage, key: str, file: Path) -> int | None:
    node = storage.getNode(key)
    if node.empty() or node.isNone():
        return None
    if node.isInt() or node.isReal():
        value = node.real()
    else:
        matrix = read_matrix(storage, key, file, required=True)
        assert matrix is not None
        if matrix.size != 1:
            raise InvalidInputError(f"{file}: {key} must be a single number, got shape {matrix.shape}")
        value = float(matrix.ravel()[0])
    if not (np.isfinite(value) and value > 0 and float(value).is_integer()):
        raise InvalidInputError(f"{file}: {key} must be a positive integer, got {value}")
    return int(value)


def rodrigues(rvec: Any, key: str, file: Path) -> NDArray[np.float64]:
    vector = np.asarray(rvec, dtype=np.float64)
    if vector.size != 3:
        raise InvalidInputError(f"{file}: {key} must be a 3x1 Rodrigues vector, got shape {vector.shape}")
    if not np.isfinite(vector).all():
        raise InvalidInputError(f"{file}: {key} must be finite, got {vector.ravel().tolist()}")
    matrix, _ = cv2.Rodrigues(vector.reshape(3, 1))
    return np.asarray(matrix, dtype=np.float64)
