"""What the tracks of a textured synthetic capture cover, per body part (issue 15; the fit
with tracks reaches only the surface that tracks lie on: benches/README.md, trackfit5's
``perfect`` oracle and its coverage table, first run as ``/tmp/trackfit5/cover.py``).

Per part of the truth's material points: the share that 2+ cameras see (showing their
material), and the share of those with a tracked position within 2% of the truth's
bounding-box diagonal at frame 0, at frame 0 and over every frame; and the same over all
parts.

Run: ``python benches/eval_tracks_fit_cover.py ROOT TRACKS_OUT`` (ROOT the capture of
``benches/eval_tracks_fit.py --root``, TRACKS_OUT its ``--tracks-out``).
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial import cKDTree

from elastocap import load_tracks
from elastocap.synth.skeleton import PARTS
from elastocap.synth.textured import load_textured_truth
from elastocap.tracking.flags import TrackFlag


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root")
    parser.add_argument("tracks")
    parser.add_argument("--near", type=float, default=0.02, help="share of the diagonal a tracked position counts within")
    args = parser.parse_args()
    truth = load_textured_truth(args.root)
    tracks = load_tracks(args.tracks)
    diagonal = float(np.linalg.norm(np.ptp(truth.positions[0], axis=0)))
    frames = truth.positions.shape[0]
    seen = (truth.visible.sum(axis=1) >= 2) & np.asarray(truth.material)
    near = np.zeros(seen.shape, bool)
    for f in range(frames):
        row = np.flatnonzero(tracks.frames == f)
        if len(row) == 0:
            continue
        live = tracks.positions[row[0]][tracks.flags[row[0]] == TrackFlag.TRACKED]
        if len(live):
            near[f] = cKDTree(live).query(truth.positions[f])[0] <= args.near * diagonal
    print(f"{len(tracks.ids)} tracks, {int((tracks.flags == TrackFlag.TRACKED).sum())} tracked positions")
    print("part          seen@0 covered@0  seen(all) covered(all)")

    def row(name: str, on: np.ndarray) -> None:
        s0, n0, sa, na = seen[0, on], near[0, on], seen[:, on], near[:, on]
        print(f"{name:12s} {s0.mean():6.2f} {n0[s0].mean() if s0.any() else float('nan'):9.2f} "
              f"{sa.mean():10.2f} {na[sa].mean() if sa.any() else float('nan'):12.2f}")

    for p in np.unique(truth.part):
        row(PARTS[p], truth.part == p)
    row("all", np.ones(len(truth.part), bool))


if __name__ == "__main__":
    main()
