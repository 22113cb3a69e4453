"""The options of ``elastocap capture`` (and of each take of ``elastocap batch``): one table,
read from TOML (``--config capture.toml``), every option also a flag, and written back as
the TOML of the run (``OUT/capture.toml``).

Precedence: the defaults, then the configuration file, then the flags given.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from elastocap._core import InvalidInputError
from elastocap.pipeline.export import FORMATS
from elastocap.pipeline.export.settings import UNITS as UNITS_NAMES
from elastocap.pipeline.export.settings import read_config
from elastocap.pipeline.masks import SILHOUETTE_METHODS
from elastocap.pipeline.track import FIT_SPACING

__all__ = ["CaptureOptions", "add_option_flags", "resolve_options"]


def _option(default: Any, kind: str, help: str, choices: tuple[str, ...] | None = None) -> Any:
    return field(default=default, metadata={"kind": kind, "help": help, "choices": choices})


@dataclass(frozen=True)
class CaptureOptions:
    """Every option of a capture run (TOML key = attribute; flag = ``--`` + the key with
    dashes). ``None`` means "not set": the stage decides (see each help)."""

    silhouettes: str = _option("auto", "str", "masks: the capture's own; background: against background/; dark: a dark "
                               "background; auto: the first the capture allows", SILHOUETTE_METHODS)
    dark_threshold: float = _option(30.0, "float", "grey level (0-255) above which a pixel may be the object (silhouettes = dark)")
    resolution: int = _option(128, "int", "hull voxels along the longest side")
    tolerance: int = _option(0, "int", "cameras that may disagree when carving")
    phantoms: str = _option("drop", "str", "drop: leave out the hull's components that explain no silhouette pixel of their "
                            "own (space few cameras see); keep: the carving as it is", ("drop", "keep"))
    nodes: int = _option(2500, "int", "nodes of the elastic model")
    rest_frame: int | None = _option(None, "int?", "frame the elastic model is built from (not set: the frame whose hull encloses the least volume)")
    rotation: str = _option("warped", "str", "rotation compensation of the elastic model", ("rhs", "warped", "none"))
    stiffness: float = _option(1.0, "float", "elastic stiffness against the surface pull")
    tracks: bool = _option(False, "bool", "track surface points before the fit and fit with them (textured "
                           "images; the tracks of elastocap track, which the fit reads from OUT/tracks when there)")
    track_spacing: int = _option(FIT_SPACING, "int", "pixels per seed of the tracks for the fit (one per spacing x spacing of mask; "
                                 "5: drift with / without tracks 0.59 / 0.64 against 0.63 / 0.71 at 10 on held-out seeds, for ~2x the tracking)")
    body: bool = _option(False, "bool", "fit the articulated human body model too (people only)")
    exports: tuple[str, ...] = _option(("glb", "pc2"), "list", "animation files to write into OUT/export "
                                       "(bvh, trc, c3d need body = true)", FORMATS)
    fps: float | None = _option(None, "float?", "frames per second (not set: from the videos, else 30 with a warning)")
    units: str = _option("m", "str", "the calibration's units: m, cm, mm, or metres per unit")
    up: str = _option("y", "str", "the capture world's up axis", ("y", "z"))
    threads: int | None = _option(None, "int?", "worker threads of the Rust core (not set: every core)")

    def __post_init__(self) -> None:
        for f in fields(self):
            _check(f.name, getattr(self, f.name), f.metadata, "option")
        if self.units not in UNITS_NAMES:
            try:
                ok = math.isfinite(float(self.units)) and float(self.units) > 0
            except ValueError:
                ok = False
            if not ok:
                raise InvalidInputError(f"option units must be one of {', '.join(UNITS_NAMES)} or metres per unit, got {self.units!r}")
        if self.track_spacing < 2:
            raise InvalidInputError(f"option track_spacing must be at least 2 pixels per seed, got {self.track_spacing}")
        body_formats = [f for f in self.exports if f in ("bvh", "trc", "c3d")]
        if body_formats and not self.body:
            raise InvalidInputError(f"exports {body_formats} need the body fit: set body = true (--body)")

    def to_toml(self, *, capture: str | Path | None = None, notes: dict[str, str] | None = None) -> str:
        """The options as TOML (with ``capture = PATH`` first when given); ``notes`` add a
        comment to a key's line (e.g. where a value came from)."""
        notes = notes or {}
        lines = ["# elastocap capture: the options of this run (each is also a flag: --key-with-dashes)"]
        if capture is not None:
            lines.append(f"capture = {json.dumps(str(capture))}")
        for f in fields(self):
            value = getattr(self, f.name)
            note = f"  # {notes[f.name]}" if f.name in notes else ""
            if value is None:
                lines.append(f"# {f.name} = (not set){note}")
            else:
                lines.append(f"{f.name} = {_toml_value(value)}{note}")
        return "\n".join(lines) + "\n"


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a TOML basic string
    return "[" + ", ".join(_toml_value(v) for v in value) + "]"


def _check(name: str, value: Any, meta: Any, where: str) -> None:
    kind, choices = meta["kind"], meta["choices"]
    if value is None and kind.endswith("?"):
        return
    base = kind.rstrip("?")
    ok = {
        "str": isinstance(value, str),
        "int": isinstance(value, int) and not isinstance(value, bool),
        "float": isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value),
        "bool": isinstance(value, bool),
        "list": isinstance(value, tuple) and all(isinstance(v, str) for v in value),
    }[base]
    if not ok:
        raise InvalidInputError(f"{where} {name} must be {'a list of strings' if base == 'list' else 'a ' + base}, got {value!r}")
    if base == "int" and name != "rest_frame" and value < (1 if name in ("resolution", "nodes", "threads") else 0):
        raise InvalidInputError(f"{where} {name} must be {'positive' if name != 'tolerance' else 'at least 0'}, got {value}")
    if base == "float" and value <= 0 and name != "dark_threshold":
        raise InvalidInputError(f"{where} {name} must be positive, got {value}")
    if choices is not None:
        bad = [v for v in (value if base == "list" else (value,)) if v not in choices]
        if bad:
            raise InvalidInputError(f"{where} {name}: {bad[0]!r} is not one of {', '.join(choices)}")


def add_option_flags(parser: argparse.ArgumentParser) -> None:
    """One flag per option (default: not given, so that the configuration file counts)."""
    for f in fields(CaptureOptions):
        flag = "--" + f.name.replace("_", "-")
        kind, help_text = f.metadata["kind"], f.metadata["help"]
        default = f" (default: {_toml_value(f.default)})" if f.default is not None else ""
        if kind == "bool":
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=None, help=help_text + default)
        elif kind == "list":
            parser.add_argument(flag, default=None, metavar="A,B", help=help_text + " (comma-separated; default: "
                                + ",".join(CaptureOptions().exports) + ")")
        else:
            convert = {"int": int, "float": float, "str": str}[kind.rstrip("?")]
            parser.add_argument(flag, type=convert, default=None, choices=f.metadata["choices"], help=help_text + default)


def resolve_options(config: str | Path | None, flags: argparse.Namespace | dict[str, Any] | None = None) -> tuple[CaptureOptions, dict[str, Any]]:
    """The options of a run: defaults, then ``config`` (a TOML file), then ``flags``.

    Returns the options and the configuration file's other keys (``capture``).

    Raises
    ------
    InvalidInputError
        An unknown key in the file, or a value of the wrong type or out of range (the
        message names the file and the key).
    """
    options = CaptureOptions()
    extra: dict[str, Any] = {}
    names = {f.name for f in fields(CaptureOptions)}
    if config is not None:
        table = read_config(config)
        unknown = sorted(set(table) - names - {"capture"})
        if unknown:
            raise InvalidInputError(f"{config}: unknown option(s) {unknown}; options are {', '.join(sorted(names))}")
        extra = {k: v for k, v in table.items() if k not in names}
        values: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in table.items() if k in names}
        try:
            options = replace(options, **values)
        except InvalidInputError as error:
            raise InvalidInputError(f"{config}: {error}") from None
    given = vars(flags) if isinstance(flags, argparse.Namespace) else dict(flags or {})
    flagged: dict[str, Any] = {k: given[k] for k in names if given.get(k) is not None}
    if isinstance(flagged.get("exports"), str):
        flagged["exports"] = tuple(v.strip() for v in flagged["exports"].split(",") if v.strip())
    return replace(options, **flagged), extra
