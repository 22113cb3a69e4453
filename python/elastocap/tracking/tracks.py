"""Tracks: 3-D trajectories of surface points, their covariances and flags, and their files
``OUT/tracks/<frame:06d>.npz`` (one per frame, so runs resume and memory stays flat)."""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap._io import load_npz
from elastocap.tracking.flags import TrackFlag

__all__ = ["Tracks", "load_tracks", "frame_file", "write_frame", "read_frame"]


@dataclass(frozen=True)
class Tracks:
    """Tracked surface points over a sequence.

    Attributes
    ----------
    frames : (F,) int64
        Capture frame numbers.
    ids : (N,) int64
        Track identifiers (stable across frames and runs).
    positions : (F, N, 3) float64
        World positions (world units); NaN where the point is not tracked. The forward
        intersection of the views, fused with the rigid motion of the neighbouring points
        since the point was seeded (:mod:`elastocap.tracking.rigidity`).
    covariances : (F, N, 3, 3) float64
        Covariance of ``positions`` (world units squared): the forward intersection's,
        with the drift of the views' anchors (:mod:`elastocap.tracking.drift`), after the
        fusion; NaN where not tracked.

        What it is calibrated for: a track's motion from its own first position. Measured
        against the true surface point each track was seeded on (textured fast capture,
        tuning seeds 10 and 42, main's tracks; benches/README.md, "Session 26, lead", item
        5), the displacement from the first position has a median squared Mahalanobis
        distance d^2 of 2.6-2.8 where a calibrated 3-D Gaussian has 2.37, but a heavy tail
        (mean d^2 14-15 against 3; the displacement error's p90 14-18 mm against a sigma of
        5-8 mm). The elastic fit uses exactly that motion and meets the tail with a floor
        on the sigma and a Cauchy loss (:class:`elastocap.TrackTerms` ``sigma`` and
        ``scale``).

        What it omits: the seed's own offset from the surface (its first triangulation).
        Read as the error of the absolute position it is optimistic: median d^2 5.1-6.2,
        mean 300-460; the error's p50 is 10-13 mm at the seeding frame of late seeds
        (22-29% beyond 22 mm) and 6-7 mm five or more frames on, while the covariance's
        sqrt(trace) is ~3 mm at seeding and ~7.5-7.8 mm twenty frames on. Its largest axis
        (the views' depth) is too small (median e^2 / variance 1.6-2.9) and the two across
        it too large (0.35-0.43).
    flags : (F, N) uint8
        :class:`TrackFlag` codes: 0 where tracked, else why not.
    views : (F, N, C, 2) float64, optional
        The 2-D positions ``(u, v)`` in each of the capture's C cameras (pixels; NaN where
        the camera does not hold the point); None when not recorded.
    """

    frames: NDArray[np.int64]
    ids: NDArray[np.int64]
    positions: NDArray[np.float64]
    covariances: NDArray[np.float64]
    flags: NDArray[np.uint8]
    views: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        f, n = len(self.frames), len(self.ids)
        for name, shape in [("positions", (f, n, 3)), ("covariances", (f, n, 3, 3)), ("flags", (f, n))]:
            got = getattr(self, name).shape
            if got != shape:
                raise InvalidInputError(f"Tracks.{name} must have shape {shape}, got {got}")
        if self.views is not None and (self.views.ndim != 4 or self.views.shape[:2] != (f, n) or self.views.shape[3] != 2):
            raise InvalidInputError(f"Tracks.views must have shape ({f}, {n}, C, 2), got {self.views.shape}")
        finite = np.isfinite(self.positions).all(axis=2)
        if (finite != (self.flags == TrackFlag.TRACKED)).any():
            raise InvalidInputError("Tracks.positions must be finite exactly where flags is TRACKED (0)")

    def velocities(self) -> NDArray[np.float64]:
        """(F, N, 3) float64: central differences of ``positions`` per frame step (world units
        per frame; one-sided at the ends, NaN next to an untracked frame)."""
        return np.gradient(self.positions, axis=0) if len(self.frames) > 1 else np.full_like(self.positions, np.nan)

    def accelerations(self) -> NDArray[np.float64]:
        """(F, N, 3) float64: second differences of ``positions`` (world units per frame^2)."""
        a = np.full_like(self.positions, np.nan)
        a[1:-1] = self.positions[2:] - 2 * self.positions[1:-1] + self.positions[:-2]
        return a


def frame_file(out: str | Path, frame: int) -> Path:
    """``OUT/tracks/<frame:06d>.npz``."""
    return Path(out) / "tracks" / f"{int(frame):06d}.npz"


def write_frame(out: str | Path, frame: int, arrays: dict[str, NDArray[np.generic]]) -> Path:
    """Write one frame's arrays atomically (a scratch file renamed into place)."""
    path = frame_file(out, frame)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, scratch = tempfile.mkstemp(dir=path.parent, prefix=".", suffix=".npz")
    try:
        with os.fdopen(handle, "wb") as file:
            # numpy's stub types the keywords against savez's own allow_pickle flag.
            np.savez(file, **arrays)  # type: ignore[arg-type]
        os.replace(scratch, path)
    except BaseException:
        Path(scratch).unlink(missing_ok=True)
        raise
    return path


def read_frame(path: Path) -> dict[str, NDArray[np.generic]]:
    """The arrays of one frame file, read as untrusted input (no pickles, sizes checked)."""
    return load_npz(path, required=["ids", "positions", "covariances", "flags"])


def load_tracks(out: str | Path) -> Tracks:
    """Read the tracks that ``elastocap.track_points(..., out=OUT)`` or ``elastocap track``
    wrote into ``OUT/tracks/``.

    Parameters
    ----------
    out : str or Path
        The output folder (holding ``tracks/``).

    Returns
    -------
    Tracks
        Every frame file, in frame order; the union of their ids (points not yet seeded in
        a frame are NaN there, flagged ``NOT_SEEDED``).

    Raises
    ------
    FileNotFoundError
        No ``tracks/*.npz`` in ``out``.
    InvalidInputError
        A frame file without the expected arrays or with inconsistent shapes.
    """
    files = sorted((Path(out) / "tracks").glob("[0-9]*.npz"))
    if not files:
        raise FileNotFoundError(f"no tracks/<frame>.npz in {out}")
    frames = [read_frame(p) for p in files]
    for p, data in zip(files, frames):
        missing = {"ids", "positions", "covariances", "flags"} - data.keys()
        if missing:
            raise InvalidInputError(f"{p} lacks {sorted(missing)}")
        n = len(data["ids"])
        if data["positions"].shape != (n, 3) or data["covariances"].shape != (n, 3, 3) or data["flags"].shape != (n,):
            raise InvalidInputError(f"{p}: arrays of inconsistent shapes")
    ids = np.unique(np.concatenate([d["ids"] for d in frames])).astype(np.int64)
    f, n = len(frames), len(ids)
    positions = np.full((f, n, 3), np.nan)
    covariances = np.full((f, n, 3, 3), np.nan)
    flags = np.full((f, n), TrackFlag.NOT_SEEDED, np.uint8)
    with_views = all("uv" in d for d in frames)
    c = frames[0]["uv"].shape[1] if with_views else 0
    views = np.full((f, n, c, 2), np.nan) if with_views else None
    for i, data in enumerate(frames):
        cols = np.searchsorted(ids, data["ids"])
        if views is not None:
            views[i, cols] = data["uv"]
        positions[i, cols] = data["positions"]
        covariances[i, cols] = data["covariances"]
        flags[i, cols] = data["flags"]
    numbers = np.array([int(p.stem) for p in files], np.int64)
    return Tracks(frames=numbers, ids=ids, positions=positions, covariances=covariances, flags=flags, views=views)
