"""The track stage of a capture (issue 15): surface points tracked through every frame,
``OUT/tracks/<frame:06d>.npz`` per frame (resumable), and two pictures: the trajectories
over a camera's image (``OUT/tracks.png``) and a strip over time of every track's state
(``OUT/tracks_strip.png``: one row per track, one column per frame, coloured by flag)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from elastocap._io import save_image
from elastocap.capture.folder import Capture
from elastocap.tracking import Tracks, track_points
from elastocap.tracking.flags import TrackFlag

__all__ = ["FIT_SPACING", "FIT_TRACK_OPTIONS", "run_track_stage", "trajectory_picture", "strip_picture"]

# The seeding density (pixels per seed) of the tracks the pipeline makes, which are the
# elastic fit's (``elastocap fit`` reads OUT/tracks). Textured fast capture, the fit with
# the spread, drift with / without tracks on seeds 1, 2, 3 (benches/README.md, trackfit4):
# 0.651 / 0.532 / 0.513 at 10 px (seed 3: 2 frames lose a limb), 0.622 / 0.472 / 0.467 at
# 5 px (none), for 2.0-2.3x the tracking CPU; held-out seeds 4 and 5: 0.632 / 0.705 (seed 5:
# one frame lost) at 10 px, 0.591 / 0.641 (none) at 5 px. ``track_points``' own default (10) stays the
# tracker's (its speed line at 1,000 points).
FIT_SPACING = 5

# The seeding of the fit's tracks (``track_points`` options; benches/README.md, trackfit6):
# seeds 3 px from the mask's edge (``track_points``' own margin, a whole patch, leaves the
# forearms, hands and feet without a seed: 0-10% of their seen points lie that far inside
# two cameras' masks), and between the full seedings every frame where the tracks left the
# mask bare within 2 cells (a fast limb loses its points within a frame or two). Seed 7
# (tuning): the share of the truth's seen points within 2% of the diagonal of a tracked
# position 0.49 -> 0.89 (right forearm 0.05 -> 0.93, hand 0.04 -> 0.97), the frame that
# lost the right hand with tracks (frame 32, 7.65%) held. Both stay off in ``track_points``
# (its tracking figures, its speed line).
FIT_TRACK_OPTIONS: dict[str, int] = {"seed_margin": 3, "reseed_bare": 2}

# Colours of the strip per flag (RGB): tracked green, not seeded dark, failures warm.
_FLAG_COLOURS = np.array([
    [40, 200, 60], [30, 30, 30], [120, 120, 120], [230, 160, 30], [220, 60, 200], [230, 40, 40],
    [40, 120, 230], [40, 200, 230], [160, 90, 230], [250, 240, 80], [170, 170, 170],
], np.uint8)


def trajectory_picture(capture: Capture, tracks: Tracks, *, camera: str | None = None, tail: int = 15) -> NDArray[np.uint8]:
    """(H, W, 3) RGB: the last frame's image of ``camera`` (default: the first) with the
    projected trajectories of its last ``tail`` frames, one colour per track."""
    name = camera if camera is not None else capture.cameras[0]
    cam = capture.rig[name]
    frame = int(tracks.frames[-1])
    image = np.ascontiguousarray(capture.image(name, frame))
    rng = np.random.default_rng(0)
    colours = rng.integers(60, 256, size=(len(tracks.ids), 3))
    window = tracks.positions[-tail:]
    f, n = window.shape[:2]
    uv = cam.project(np.nan_to_num(window.reshape(-1, 3)))[0].reshape(f, n, 2)
    uv[~np.isfinite(window).all(axis=2)] = np.nan
    for j in range(n):
        path = uv[:, j]
        ok = np.asarray(np.isfinite(path).all(axis=1))
        if ok.sum() >= 2:
            cv2.polylines(image, [np.round(path[ok]).astype(np.int32)], False, tuple(int(v) for v in colours[j]), 1, cv2.LINE_AA)
        if ok[-1]:
            cv2.circle(image, tuple(int(v) for v in np.round(path[-1])), 2, tuple(int(v) for v in colours[j]), -1)
    return image


def strip_picture(tracks: Tracks, *, height: int = 600) -> NDArray[np.uint8]:
    """(rows, F, 3) RGB: one row per track (in order of first appearance, resampled to at
    most ``height`` rows), one column per frame, coloured by :class:`TrackFlag`."""
    flags = tracks.flags.T
    tracked = flags == TrackFlag.TRACKED
    first = np.where(tracked.any(axis=1), np.argmax(tracked, axis=1), flags.shape[1])
    order = np.argsort(first, kind="stable")
    picture = _FLAG_COLOURS[np.minimum(flags[order], len(_FLAG_COLOURS) - 1)]
    if len(picture) > height:
        picture = picture[np.linspace(0, len(picture) - 1, height).astype(int)]
    scale = max(1, 600 // max(1, picture.shape[1]))
    return np.repeat(picture, scale, axis=1)


def run_track_stage(capture: Capture, out: str | Path, *, frames: list[int] | None = None, progress: bool = True,
                    spacing: int = FIT_SPACING, **options: object) -> Tracks:
    """Track the capture's surface points into ``OUT/tracks/`` (resuming), then draw the
    pictures. ``spacing`` is the seeding density for the elastic fit (:data:`FIT_SPACING`,
    not ``track_points``' own default); ``options`` go to :func:`elastocap.track_points`,
    over :data:`FIT_TRACK_OPTIONS` (the fit's seeding)."""
    chosen = list(capture.frames) if frames is None else frames
    bar = tqdm(total=len(chosen), desc="track", unit="frame", disable=not progress)
    done = {"n": 0}

    def tick(frame: int) -> None:
        done["n"] += 1
        bar.update(1)

    try:
        tracks = track_points(capture, frames=chosen, out=out, progress=tick, spacing=spacing,
                              **{**FIT_TRACK_OPTIONS, **options})  # type: ignore[arg-type]
    finally:
        bar.close()
    root = Path(out)
    save_image(root / "tracks.png", trajectory_picture(capture, tracks))
    save_image(root / "tracks_strip.png", strip_picture(tracks))
    return tracks
