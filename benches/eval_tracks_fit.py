"""Issue 15's Done-when figure for tracks in the fit: on the textured synthetic capture
(``write_textured_capture``, fast motion, 8 cameras with skew and distortion) the elastic
fit's drift with the tracks of ``elastocap.track_points`` (the real tracker, not the
truth) against the same fit without tracks, and the lost-limb measure of every frame.

- **Drift** (as ``benches/eval_horse.py``): each ground-truth material surface point
  (``load_textured_truth``, seeded on frame 0 and moved with its body part) is tied at the
  rest frame 0 to its nearest fitted surface vertex; drift is the distance between that
  vertex and the point's true position, mean over points, % of the truth's bounding-box
  diagonal at frame 0.
- **Lost-limb measure** (``elastic.measures``): 99th percentile of the pooled fitted/true
  surface distances, % of the diagonal; a limb is lost at 5%.

Run: ``python benches/eval_tracks_fit.py SEED [--frames 60] [--nodes 2500]
[--resolution 128] [--size 640 480] [--options '{"track_weight": 1.0}']``. The capture,
hulls and tracks are kept in ``/tmp/elastocap_texfast_<seed>_<frames>_<width>`` and reused.
Prints one JSON line per fit (``"tracks": false`` and ``true``) and their drift ratio.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from elastocap import ElasticModel, fit_sequence, load_tracks, track_points
from elastocap.capture.folder import Capture
from elastocap.elastic.measures import surface_error
from elastocap.pipeline.hull import load_hull, run_hull_stage
from elastocap.synth.textured import load_textured_truth, write_textured_capture


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("seed", type=int)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--nodes", type=int, default=2500)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--size", type=int, nargs=2, default=(640, 480))
    parser.add_argument("--options", type=json.loads, default={}, help="fit_sequence options of the fit with tracks")
    parser.add_argument("--with-only", action="store_true", help="only the fit with tracks (no ratio)")
    args = parser.parse_args()
    root = Path(f"/tmp/elastocap_texfast_{args.seed}_{args.frames}_{args.size[0]}")
    clock = time.perf_counter()
    write_textured_capture(root, frames=args.frames, seed=args.seed, motion="fast", image_size=tuple(args.size),
                           supersample=2, progress=False)
    out = root / "out"
    run_hull_stage(root, out, resolution=args.resolution, progress=False)
    capture = Capture.open(root)
    if not (out / "tracks" / f"{args.frames - 1:06d}.npz").exists():
        track_points(capture, out=out)
    tracks = load_tracks(out)
    prepared = time.perf_counter() - clock
    truth = load_textured_truth(root)
    frames = list(range(args.frames))
    hulls = [load_hull(out, f) for f in frames]
    meshes = [trimesh.load(truth.mesh_path(f), process=False) for f in frames]
    diagonal = float(np.linalg.norm(np.ptp(truth.positions[0], axis=0)))
    model = ElasticModel.from_mesh(hulls[0].mesh(), n_nodes=args.nodes)
    kept = int((tracks.flags == 0).sum())
    print(f"seed {args.seed}, {args.frames} frames, {model.n_nodes} nodes, hulls of {args.resolution} voxels, "
          f"images {args.size[0]}x{args.size[1]}; {len(tracks.ids)} tracks, {kept} tracked positions; "
          f"capture + hulls + tracks {prepared:.0f} s")
    drifts = {}
    for with_tracks in (True,) if args.with_only else (False, True):
        clock, cpu = time.perf_counter(), time.process_time()
        options = dict(args.options) if with_tracks else {}
        fit = fit_sequence(model, hulls, tracks=tracks if with_tracks else None, **options)
        seconds, cpu = (time.perf_counter() - clock) / args.frames, (time.process_time() - cpu) / args.frames
        vertices = [fit.surface(f).vertices for f in frames]
        ties = cKDTree(vertices[0]).query(truth.positions[0])[1]
        drift = [100 * float(np.linalg.norm(vertices[f][ties] - truth.positions[f], axis=1).mean()) / diagonal for f in frames]
        lost = [100 * surface_error(fit.surface(f), meshes[f]).lost_limb_fraction for f in frames]
        drifts[with_tracks] = float(np.mean(drift))
        print(json.dumps({
            "seed": args.seed, "tracks": with_tracks, "options": options,
            "drift_pct_mean": round(float(np.mean(drift)), 3), "drift_pct_max": round(max(drift), 3),
            "lost_pct_max": round(max(lost), 2), "frames_lost": sum(v >= 5.0 for v in lost),
            "seconds_per_frame": round(seconds, 2), "cpu_seconds_per_frame": round(cpu, 2),
        }))
        print("  drift %", " ".join(f"{v:.1f}" for v in drift))
        print("  lost % ", " ".join(f"{v:.1f}" for v in lost))
    if not args.with_only:
        print(json.dumps({"seed": args.seed, "drift_ratio_with_over_without": round(drifts[True] / drifts[False], 3)}))


if __name__ == "__main__":
    main()
