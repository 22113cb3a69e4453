"""Ceilings of issue 15's fit with tracks (``benches/eval_tracks_fit.py``), from the truth:
what the drift ratio would be if part of the tracks were perfect. Not a measure of the
library: each oracle replaces something with the ground truth, then runs the bench.

- ``anchors``: every track anchored after the rest frame (re-seeded by the tracker) is
  attached at the TRUE rest position of the surface point it was tracked on (the
  ground-truth point nearest its tracked position at the anchor, within 1% of the
  diagonal, as ``--diagnose``'s anchor table takes it), weighted over the rest frame's
  fitted nodes; the others as the fit attaches them. The ceiling of attaching re-seeded
  tracks through anything that has not drifted.
- ``positions``: ``anchors``, and every track's tracked positions replaced by the truth of
  the surface point it was first tracked on (tracks farther than 1% of the diagonal from
  any truth point dropped); same frames, same covariances: the tracker's coverage, perfect
  accuracy.
- ``perfect``: the tracks replaced by 1,000 of the truth's material points (chosen at
  random, seed 0), at their true positions wherever the truth says they are visible in
  two cameras or more and show their material, covariance (2 mm)^2 I. Coverage and
  accuracy perfect (the drift is measured on the truth's 2,000 points, these among them).

Run: ``python benches/eval_tracks_fit_oracle.py ORACLE SEED --root R [the bench's other
arguments]``.
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

import elastocap
from elastocap.elastic import tracks as attachments_module
from elastocap.synth.textured import load_textured_truth
from elastocap.tracking.tracks import Tracks

ORACLES = ("anchors", "positions", "perfect")


def true_anchors(truth, diagonal: float):
    """``TrackAttachments.attach`` with the re-seeded tracks tied at their true rest point."""
    original = attachments_module.TrackAttachments.attach
    state: dict = {}
    trees: dict = {}

    def attach(self, frame, positions):
        row = self._row(frame)
        if row is None:
            return 0
        if "rest" not in state:
            state["rest"] = (frame, positions.copy())
        if frame == state["rest"][0]:
            return original(self, frame, positions)
        which = np.flatnonzero(self.anchor == row)
        if not len(which):
            return 0
        tree = trees.setdefault(frame, cKDTree(truth.positions[frame]))
        gap, nearest = tree.query(self.tracks.positions[row, which])
        good = gap <= 0.01 * diagonal
        count = 0
        if (~good).any():
            # Far from every truth point: attached as the fit does.
            keep = self.anchor.copy()
            self.anchor[which[good]] = -2
            count += original(self, frame, positions)
            self.anchor = keep
        rest = truth.positions[state["rest"][0]][nearest[good]]
        neighbours, phi, placed = attachments_module.placeable_weights(rest, state["rest"][1], self.k)
        chosen = which[good]
        self.unplaced[chosen[~placed]] = True
        chosen = chosen[placed]
        self.neighbours[chosen], self.phi[chosen] = neighbours[placed], phi[placed]
        self.attached[chosen] = True
        return count + len(chosen)

    return attach


def true_positions(load, truth, diagonal: float):
    def loader(out):
        t = load(out)
        tracked = t.flags == 0
        first = np.where(tracked.any(axis=0), tracked.argmax(axis=0), -1)
        positions, flags, covariances = t.positions.copy(), t.flags.copy(), t.covariances.copy()
        for k in np.unique(first[first >= 0]):
            rows = np.flatnonzero(first == k)
            gap, nearest = cKDTree(truth.positions[int(t.frames[k])]).query(t.positions[k, rows])
            far = rows[gap > 0.01 * diagonal]
            positions[:, far], flags[:, far], covariances[:, far] = np.nan, 1, np.nan
            good, nearest = rows[gap <= 0.01 * diagonal], nearest[gap <= 0.01 * diagonal]
            for i, f in enumerate(t.frames):
                m = tracked[i, good]
                positions[i, good[m]] = truth.positions[int(f)][nearest[m]]
        return Tracks(t.frames, t.ids, positions, covariances, flags, t.views)

    return loader


def perfect_tracks(load, truth):
    def loader(out):
        t = load(out)
        pick = np.random.default_rng(0).choice(truth.positions.shape[1], 1000, replace=False)
        seen = (truth.visible[:, :, pick].sum(axis=1) >= 2) & np.asarray(truth.material)[:, pick]
        positions = np.where(seen[..., None], truth.positions[:, pick], np.nan)
        covariances = np.where(seen[..., None, None], 0.002**2 * np.eye(3), np.nan)
        flags = np.where(seen, 0, 1).astype(np.uint8)
        return Tracks(t.frames, np.arange(len(pick), dtype=np.int64), positions[t.frames], covariances[t.frames], flags[t.frames])

    return loader


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1] not in ORACLES or "--root" not in sys.argv:
        raise SystemExit(f"usage: eval_tracks_fit_oracle.py {{{','.join(ORACLES)}}} SEED --root R [bench arguments]")
    oracle = sys.argv[1]
    root = Path(sys.argv[sys.argv.index("--root") + 1])
    truth = load_textured_truth(root)
    diagonal = float(np.linalg.norm(np.ptp(truth.positions[0], axis=0)))
    if oracle in ("anchors", "positions"):
        attachments_module.TrackAttachments.attach = true_anchors(truth, diagonal)
    if oracle == "positions":
        elastocap.load_tracks = true_positions(elastocap.load_tracks, truth, diagonal)
    if oracle == "perfect":
        elastocap.load_tracks = perfect_tracks(elastocap.load_tracks, truth)
    sys.argv = ["eval_tracks_fit.py"] + sys.argv[2:]
    runpy.run_path(str(Path(__file__).with_name("eval_tracks_fit.py")), run_name="__main__")


if __name__ == "__main__":
    main()
