"""Time and space of the exported files: the frame rate, and the map from the capture's
world (its units, its up axis) to the metres and +Y up of glTF, which every export uses.

A capture run writes its options to ``OUT/capture.toml`` (``elastocap capture``); the
exports read ``fps``, ``units`` and ``up`` from there, unless given.
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = [
    "DEFAULT_FPS",
    "UNITS",
    "ExportSettings",
    "ExportSpace",
    "FrameRateWarning",
    "export_settings",
    "read_config",
]

#: Frames per second when neither the videos nor the configuration say (with a warning).
DEFAULT_FPS = 30.0
#: Metres per unit of the capture's world, by name.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
# World -> +Y up, per up axis of the capture: a z-up world turns by -90 degrees about x,
# (x, y, z) -> (x, z, -y), a proper rotation, so handedness and winding are kept.
_TO_Y_UP = {
    "y": np.eye(3),
    "z": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),
}


class FrameRateWarning(UserWarning):
    """The frame rate was not known and the default (30 frames per second) was used."""


@dataclass(frozen=True)
class ExportSpace:
    """The map from the capture's world to export space (metres, +Y up).

    Attributes
    ----------
    scale : float
        Metres per world unit.
    up : {"y", "z"}
        The capture world's up axis.
    """

    scale: float = 1.0
    up: str = "y"

    @property
    def rotation(self) -> NDArray[np.float64]:
        """``(3, 3)`` float64: world axes -> export axes (a proper rotation)."""
        return _TO_Y_UP[self.up].copy()

    def points(self, points: NDArray[np.floating[Any]]) -> NDArray[np.float64]:
        """``(N, 3)`` world positions -> export positions (metres, +Y up)."""
        return np.asarray(self.scale * (np.asarray(points, dtype=np.float64) @ _TO_Y_UP[self.up].T))

    def directions(self, vectors: NDArray[np.floating[Any]]) -> NDArray[np.float64]:
        """``(N, 3)`` world directions (normals) -> export axes, not scaled."""
        return np.asarray(np.asarray(vectors, dtype=np.float64) @ _TO_Y_UP[self.up].T)


@dataclass(frozen=True)
class ExportSettings:
    """What every export of one take needs besides the data.

    Attributes
    ----------
    take : str
        The take's name: the exported files are ``OUT/export/<take>.<ext>``.
    fps : float
        Frames per second of the capture.
    space : ExportSpace
    """

    take: str
    fps: float
    space: ExportSpace


def read_config(path: str | Path) -> dict[str, Any]:
    """The TOML file at ``path`` as a dictionary.

    Raises
    ------
    InvalidInputError
        The file is not valid TOML (the message names the file and the line).
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as error:
        raise InvalidInputError(f"{path}: not a valid TOML file: {error}") from None


def _units(value: Any) -> float:
    if isinstance(value, str) and value in UNITS:
        return UNITS[value]
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value) and value > 0:
        return float(value)
    raise InvalidInputError(f"units must be one of {', '.join(UNITS)} or metres per unit (> 0), got {value!r}")


def _fps(value: Any) -> float:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value) and value > 0:
        return float(value)
    raise InvalidInputError(f"fps must be a positive number of frames per second, got {value!r}")


def export_settings(
    out: str | Path,
    *,
    take: str | None = None,
    fps: float | None = None,
    units: str | float | None = None,
    up: str | None = None,
) -> ExportSettings:
    """The export settings of the output folder ``out``.

    Each of ``fps``, ``units`` and ``up``, when not given, comes from ``out/capture.toml``
    (written by ``elastocap capture``, which takes the frame rate from the videos), else
    from the defaults: 30 frames per second (with a :class:`FrameRateWarning`), metres,
    +Y up. ``take`` defaults to the name of the capture folder the configuration names,
    else to the name of ``out``.

    Raises
    ------
    InvalidInputError
        An unknown unit or up axis, a frame rate that is not positive, or a malformed
        ``capture.toml``.
    """
    out = Path(out)
    config_file = out / "capture.toml"
    config = read_config(config_file) if config_file.exists() else {}
    if take is None:
        take = Path(str(config["capture"])).name if "capture" in config else out.resolve().name
    if fps is None and "fps" in config:
        fps = config["fps"]
    if fps is None:
        warnings.warn(
            f"the frame rate of {out} is not known (no fps in {config_file} and no videos): "
            f"using {DEFAULT_FPS:g} frames per second",
            FrameRateWarning,
            stacklevel=2,
        )
        fps = DEFAULT_FPS
    up = config.get("up", "y") if up is None else up
    if up not in _TO_Y_UP:
        raise InvalidInputError(f"up must be 'y' or 'z', got {up!r}")
    scale = _units(config.get("units", "m") if units is None else units)
    if not take or "/" in take or take in (".", ".."):
        raise InvalidInputError(f"take must be a plain file name, got {take!r}")
    return ExportSettings(take=take, fps=_fps(fps), space=ExportSpace(scale=scale, up=up))
