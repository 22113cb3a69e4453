"""Oracle track sets for issue 15's fit with tracks (``benches/eval_tracks_fit.py``): the
tracker's tracks with part of them made exact from the truth, written as a track folder
that the bench reads with ``--tracks-out DST`` (the fit then reuses them: nothing is
tracked). Not a measure of the library: the ceilings of its levers (benches/README.md,
trackfit11).

Each track's surface point is the one it sat on at its first tracked frame: that position
put on the figure's surface (``material_points``' Newton steps along the field's
gradient), its body part the nearest capsule, its coordinates in that part's frame; its
true position in any frame is that point moved with its part as the truth's material
points are (``synth.textured_render.material_points``). Same ids and covariances; modes:

- ``pos``: every tracked position replaced by its surface point's true position (same
  frames): exact tracks, the tracker's coverage and anchors.
- ``rest``: ``pos``, and a position at frame 0 (the rest frame) for every track: each is
  then anchored at rest, on the rest fit (the fit's attachment made exact but for the
  rest fit's own error).
- ``full``: ``rest``, and every frame (each track's surface point tracked throughout).
- ``tailfix:X`` / ``taildrop:X``: only the positions farther than X% of the diagonal from
  their surface point's truth replaced / withheld (flag UNCERTAIN).

Run: ``python benches/write_oracle_tracks.py ROOT SRC DST MODE`` (ROOT the capture with
its ground truth, SRC the tracks' output folder holding ``tracks/``, DST a new folder).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from elastocap import load_tracks
from elastocap.synth.textured import load_textured_truth
from elastocap.synth.textured_render import material_points
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.tracks import write_frame


def main() -> None:
    if len(sys.argv) != 5:
        sys.exit(f"usage: python benches/write_oracle_tracks.py ROOT SRC DST MODE\n{__doc__}")
    root, src, dst, mode = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3]), sys.argv[4]
    truth = load_textured_truth(root)
    tracks = load_tracks(src)
    figure = truth.figure
    tracked = tracks.flags == TrackFlag.TRACKED
    first = tracked.argmax(axis=0)
    has = tracked.any(axis=0)
    part = np.zeros(len(tracks.ids), np.int64)
    local = np.zeros((len(tracks.ids), 3))
    for row in np.unique(first[has]):
        pick = np.flatnonzero(has & (first == row))
        frame = int(tracks.frames[row])
        x = tracks.positions[row, pick]
        p = np.argmin(figure.part_distances(x, frame), axis=1)
        c = figure.capsules(frame)
        on = material_points(figure, frame, p, np.einsum("nji,nj->ni", c.frames[p], x - c.starts[p]))
        part[pick] = p
        local[pick] = np.einsum("nji,nj->ni", c.frames[p], on - c.starts[p])
    want = tracked.copy()
    if mode in ("rest", "full"):
        want[0] |= has
    if mode == "full":
        want[:] = has[None, :]
    first_cov = tracks.covariances[first, np.arange(len(tracks.ids))]
    positions, covariances, flags = tracks.positions.copy(), tracks.covariances.copy(), tracks.flags.copy()
    for row in range(len(tracks.frames)):
        n = np.flatnonzero(want[row])
        positions[row, n] = material_points(figure, int(tracks.frames[row]), part[n], local[n])
        new = n[~tracked[row, n]]
        covariances[row, new] = first_cov[new]
        flags[row, new] = TrackFlag.TRACKED
    if mode.startswith("tail"):
        diagonal = float(np.linalg.norm(np.ptp(truth.positions[0], axis=0)))
        error = np.linalg.norm(positions - tracks.positions, axis=2) * 100 / diagonal
        bad = tracked & (error > float(mode.split(":")[1]))
        keep = tracked & ~bad
        positions[keep] = tracks.positions[keep]
        if mode.startswith("taildrop"):
            positions[bad] = np.nan
            covariances[bad] = np.nan
            flags[bad] = TrackFlag.UNCERTAIN
        print(f"positions beyond {mode.split(':')[1]}% of the diagonal: {int(bad.sum())} of {int(tracked.sum())}")
    elif mode not in ("pos", "rest", "full"):
        raise SystemExit(f"unknown mode {mode!r}")
    for row in range(len(tracks.frames)):
        write_frame(dst, int(tracks.frames[row]), {"ids": tracks.ids, "positions": positions[row],
                                                   "covariances": covariances[row], "flags": flags[row]})
    print(f"{mode}: tracked positions {int(tracked.sum())} -> {int((flags == TrackFlag.TRACKED).sum())}")


if __name__ == "__main__":
    main()
