"""Listing a capture folder's frames per camera: image folders or videos, frame offsets,
and which frames each camera lacks."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Union

from elastocap._core import InvalidInputError
from elastocap.cameras.formats.common import IMAGE_SUFFIXES, VIDEO_SUFFIXES
from elastocap.capture.media import Video

__all__ = ["FrameTable", "Where", "by_camera", "list_source", "listing", "settle_frames"]

# A frame's pixels: an image file, or (video file, 0-based frame index).
Where = Union[Path, tuple[Path, int]]
# Per camera: capture frame number -> where its pixels are.
FrameTable = dict[str, dict[int, Where]]

# A frame file's stem: the frame number, usually zero-padded to 6 digits.
_FRAME_STEM = re.compile(r"^\d+$")
# How many frames an error message lists before it says "and N more".
_LISTED = 10


def listing(numbers: list[int]) -> str:
    shown = ", ".join(str(n) for n in numbers[:_LISTED])
    return shown if len(numbers) <= _LISTED else f"{shown} and {len(numbers) - _LISTED} more"


def _video_of(folder: Path, name: str) -> Path | None:
    found = [folder / f"{name}{suffix}" for suffix in VIDEO_SUFFIXES if (folder / f"{name}{suffix}").is_file()]
    if len(found) > 1:
        raise InvalidInputError(f"camera {name!r} has several videos: {', '.join(map(str, found))}")
    return found[0] if found else None


def _frame_files(directory: Path, offset: int) -> dict[int, Where]:
    files: dict[int, Where] = {}
    for file in directory.iterdir():
        if file.suffix.lower() not in IMAGE_SUFFIXES or not _FRAME_STEM.match(file.stem):
            continue
        number = int(file.stem) + offset
        if number in files:
            raise InvalidInputError(f"two files for frame {int(file.stem)}: {files[number]} and {file}")
        files[number] = file
    return dict(sorted(files.items()))


def list_source(
    folders: list[Path], names: list[str], offsets: dict[str, int], what: str
) -> FrameTable:
    """Capture frame -> pixels, per camera, from ``<folder>/<camera>/<frame>.<image>`` or
    ``<folder>/<camera>.<video>`` in the first of ``folders`` that has the camera (video
    frame ``i`` is the camera's frame ``i``); a camera's frame ``n`` is capture frame ``n +
    offsets[camera]``."""
    table: FrameTable = {}
    for name in names:
        offset = offsets.get(name, 0)
        for folder in folders:
            if (folder / name).is_dir():
                table[name] = _frame_files(folder / name, offset)
                break
            video = _video_of(folder, name) if folder.is_dir() else None
            if video is not None:
                reader = Video(video)
                count = reader.count
                reader.close()
                table[name] = {index + offset: (video, index) for index in range(count)}
                break
        else:
            where = " or ".join(f"{folder / name}/ or {folder / name}.mp4|avi|mkv|mov" for folder in folders if folder.is_dir())
            raise FileNotFoundError(f"camera folder missing: {where} (the rig names camera {name!r}; {what})")
    return table


def lacking(table: FrameTable, names: list[str]) -> dict[str, list[int]]:
    """Per camera, the frames other cameras have in this source and it lacks."""
    union: set[int] = set().union(*(set(table[name]) for name in names))
    return {name: sorted(union - set(table[name])) for name in names if union - set(table[name])}


def by_camera(frames: dict[int, list[str]]) -> str:
    """``1, 4 (cam1); 7 (cam0, cam2)``: frames grouped by the cameras they lack."""
    groups: dict[tuple[str, ...], list[int]] = {}
    for frame, cameras in frames.items():
        groups.setdefault(tuple(cameras), []).append(frame)
    return "; ".join(f"{listing(numbers)} (lacking {', '.join(cameras)})" for cameras, numbers in groups.items())


def settle_frames(
    names: list[str], colour: FrameTable | None, masks: FrameTable | None, masks_dir: Path, policy: str
) -> tuple[dict[int, list[str]], dict[int, list[str]], dict[int, list[str]]]:
    """``(frames, skipped, trimmed)``: the capture's frames with the cameras that have each;
    the frames left out, with the cameras that lack them, under ``policy`` (see
    :mod:`elastocap.capture.config`; with "error", they are refused); and the frames
    outside the span every camera covers (recordings of different starts or lengths), cut
    whatever the policy."""
    sources = [(source, table) for source, table in (("images", colour), (masks_dir.name, masks)) if table]
    every: set[int] = set()
    for _, table in sources:
        for name in names:
            every |= set(table[name])
    if not every:
        return {}, {}, {}
    present = {f: [n for n in names if all(f in table[n] for _, table in sources)] for f in sorted(every)}
    covered = [[f for f, cameras in present.items() if name in cameras] for name in names]
    if not all(covered):
        empty = [name for name, frames in zip(names, covered) if not frames]
        raise InvalidInputError(f"camera(s) {empty} have no frame in every source ({', '.join(s for s, _ in sources)})")
    lo, hi = max(c[0] for c in covered), min(c[-1] for c in covered)
    if lo > hi:
        raise InvalidInputError(
            f"the cameras' recordings do not overlap (frames {lo} to {hi}): check the offsets in capture.toml"
        )
    trimmed = {f: [n for n in names if n not in cameras] for f, cameras in present.items()
               if not lo <= f <= hi and cameras}
    inside = {f: cameras for f, cameras in present.items() if lo <= f <= hi}
    if policy == "error":
        for source, table in sources:
            for name, gap in lacking(table, names).items():
                frames_lacked = [f for f in gap if lo <= f <= hi]
                if frames_lacked:
                    sample = next(iter(table[name].values()), None)
                    where = sample[0] if isinstance(sample, tuple) else masks_dir.parent / source / name
                    raise InvalidInputError(
                        f"{where} lacks frame(s) {listing(frames_lacked)} that other cameras have (set missing = "
                        f"\"skip\" or \"present\" in capture.toml, or pass missing=, to leave such frames out or "
                        "carve them with the cameras present)"
                    )
    needed = len(names) if policy != "present" else min(2, len(names))
    frames = {f: cameras for f, cameras in inside.items() if len(cameras) >= needed}
    # Frames no camera has in some source (masks made for part of a take) are left out
    # silently, as before; frames that only some cameras lack are reported.
    skipped = {f: [n for n in names if n not in cameras] for f, cameras in inside.items()
               if f not in frames and cameras}
    return frames, skipped, trimmed
