"""A capture's configuration file, ``CAPTURE/capture.toml`` (optional)::

    units = "mm"          # the calibration's world units: converted to metres (Rig.load)
    up = "z"              # the calibration's up axis: rotated to +y (Rig.load)
    missing = "skip"      # frames some camera lacks: "error" (default), "skip", "present"

    [offsets]             # unsynchronised starts, in frames, per camera (default 0)
    cam01 = 3             # cam01 started 3 frames late: its frame n is capture frame n + 3
    cam02 = -2            # cam02 started 2 frames early: its frame 2 is capture frame 0

Recordings of different starts or lengths are cut to the span every camera covers (the
frames cut are in :attr:`Capture.trimmed`). Inside it, ``missing`` says what happens to a
frame that some camera lacks: "error" refuses the capture (naming the folder and frames);
"skip" leaves such frames out; "present" keeps them, each carved with the cameras that have
it (at least two). Both report their choice with a :class:`CaptureWarning` naming the
frames and cameras, and in :attr:`Capture.skipped` / :attr:`Capture.incomplete`.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from elastocap._core import InvalidInputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["MISSING_POLICIES", "CaptureConfig", "CaptureWarning", "missing_policy", "read_config"]

MISSING_POLICIES = ("error", "skip", "present")
CONFIG_NAME = "capture.toml"
_KEYS = {"units", "up", "scale", "missing", "offsets"}


class CaptureWarning(UserWarning):
    """A capture was opened with a choice the user should know about (frames skipped, or
    carved with fewer cameras, because some camera lacks them)."""


@dataclass(frozen=True)
class CaptureConfig:
    """What ``capture.toml`` says; defaults when there is none."""

    offsets: dict[str, int] = field(default_factory=dict)
    missing: str = "error"
    units: str | None = None
    up: str | None = None
    scale: float | None = None


def read_config(file: Path) -> CaptureConfig:
    """``file`` parsed and checked; the defaults when it does not exist."""
    if not file.exists():
        return CaptureConfig()
    try:
        data = tomllib.loads(file.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise InvalidInputError(f"{file}: not valid TOML ({error})") from None
    unknown = sorted(set(data) - _KEYS)
    if unknown:
        raise InvalidInputError(f"{file}: unknown key(s) {unknown} (known: {sorted(_KEYS)})")
    offsets = data.get("offsets", {})
    if not isinstance(offsets, dict):
        raise InvalidInputError(f"{file}: offsets must be a table of camera = frames")
    for name, value in offsets.items():
        if isinstance(value, bool) or not isinstance(value, int):
            raise InvalidInputError(f"{file}: offsets.{name} must be a whole number of frames, got {value!r}")
    missing = data.get("missing", "error")
    if missing not in MISSING_POLICIES:
        raise InvalidInputError(f"{file}: missing must be one of {', '.join(MISSING_POLICIES)}, got {missing!r}")
    strings: dict[str, Any] = {}
    for key in ("units", "up"):
        if key in data and not isinstance(data[key], str):
            raise InvalidInputError(f"{file}: {key} must be a string, got {data[key]!r}")
        strings[key] = data.get(key)
    scale = data.get("scale")
    if scale is not None and (isinstance(scale, bool) or not isinstance(scale, (int, float))):
        raise InvalidInputError(f"{file}: scale must be a number, got {scale!r}")
    return CaptureConfig(dict(offsets), missing, strings["units"], strings["up"], None if scale is None else float(scale))


def missing_policy(strict: bool | None, missing: str | None, settings: CaptureConfig) -> str:
    """The policy for frames some camera lacks: ``strict`` (legacy), else ``missing``, else
    the configuration's."""
    if strict is not None and missing is not None:
        raise InvalidInputError("give strict or missing, not both")
    if strict is not None:
        return "error" if strict else "skip"
    if missing is None:
        return settings.missing
    if missing not in MISSING_POLICIES:
        raise InvalidInputError(f"missing must be one of {', '.join(MISSING_POLICIES)}, got {missing!r}")
    return missing
