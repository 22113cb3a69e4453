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
[--resolution 128] [--size 640 480] [--options '{"track_weight": 1.0}']
[--track-options '{"spacing": 7}' --tracks-out DIR] [--reuse-without]``. The capture,
hulls and tracks are kept in ``/tmp/elastocap_texfast_<seed>_<frames>_<width>`` and reused
(tracks of other ``track_points`` options go to their own ``--tracks-out``, else they would
be read back as the default's). ``--reuse-without`` keeps the fit without tracks in
``OUT/without_<nodes>.npz`` and reads it back on the next run (it does not depend on the
tracks or the fit's track options).
``--options`` are ``fit_sequence``'s keywords as JSON; its option objects may be given as
mappings of their fields (``"track_terms": {"ahead": 2}``, ``"stiff_stage": {"frames": "all"}``)
or, as in the commands of earlier sessions, flat (``"track_ahead": 2``,
``"stiff_stage_frames": "all"``): both become the objects (``grouped_keywords``).
Prints one JSON line per fit (``"tracks": false`` and ``true``) and their drift ratio.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from elastocap import ElasticModel, InvalidInputError, TrackTerms, fit_sequence, load_tracks, track_points
from elastocap.capture.folder import Capture
from elastocap.elastic.fit_options import grouped_keywords
from elastocap.elastic.measures import surface_error
from elastocap.pipeline.hull import load_hull, run_hull_stage
from elastocap.synth.textured import load_textured_truth, write_textured_capture
from elastocap.tracking.flags import TrackFlag


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("seed", type=int)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--nodes", type=int, default=2500)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--size", type=int, nargs=2, default=(640, 480))
    parser.add_argument("--options", type=json.loads, default={}, help="fit_sequence options of the fit with tracks")
    parser.add_argument("--with-only", action="store_true", help="only the fit with tracks (no ratio)")
    parser.add_argument("--without-only", action="store_true",
                        help="only the fit without tracks (with --reuse-without: computed ahead of the runs with tracks)")
    parser.add_argument("--root", type=Path, default=None,
                        help="capture folder (default /tmp/elastocap_texfast_<seed>_<frames>_<width>)")
    parser.add_argument("--prepare-only", action="store_true", help="write the capture, hulls and tracks, fit nothing")
    parser.add_argument("--track-options", type=json.loads, default={},
                        help="track_points options (e.g. the seeding density '{\"spacing\": 7}')")
    parser.add_argument("--tracks-out", type=Path, default=None,
                        help="where the tracks go (OUT/tracks; default ROOT/out)")
    parser.add_argument("--reuse-without", action="store_true",
                        help="read the fit without tracks back from OUT/without_<nodes>.npz when there, else write it")
    parser.add_argument("--diagnose", action="store_true",
                        help="per frame: drift without / with, tracks pulling, their mean age, drifted points near a track; "
                        "per frame at or near the lost-limb line: the body parts the worst distances are on")
    parser.add_argument("--save-with", type=Path, default=None,
                        help="write the fit with tracks' node positions (F, N, 3) to this .npz")
    parser.add_argument("--remeasure", action="store_true",
                        help="fit nothing: measure the fits of --reuse-without's cache and --save-with's file again")
    args = parser.parse_args()
    root = args.root or Path(f"/tmp/elastocap_texfast_{args.seed}_{args.frames}_{args.size[0]}")
    clock = time.perf_counter()
    stages = {}
    cpu = time.process_time()
    write_textured_capture(root, frames=args.frames, seed=args.seed, motion="fast", image_size=tuple(args.size),
                           supersample=2, progress=False)
    stages["capture"], cpu = time.process_time() - cpu, time.process_time()
    out = root / "out"
    run_hull_stage(root, out, resolution=args.resolution, progress=False)
    stages["hulls"], cpu = time.process_time() - cpu, time.process_time()
    capture = Capture.open(root)
    tracks_out = args.tracks_out or out
    if not (tracks_out / "tracks" / f"{args.frames - 1:06d}.npz").exists():
        track_points(capture, out=tracks_out, **args.track_options)
    stages["tracks"] = time.process_time() - cpu
    tracks = load_tracks(tracks_out)
    # fit_sequence refuses tracks with a covariance that is not positive definite (bad
    # input). The tracker wrote one on held-out seed 4 at 5 px (1 of 58,490 positions, an
    # eigenvalue of -2.8e-3 m^2: a tracker defect, reported, not the fit's); such positions
    # are marked UNCERTAIN here, and counted, so that the rest can be measured. Since branch
    # track17 the tracker's covariances are positive definite by construction (the
    # intersection's normal matrix inverted through its eigen decomposition, the fusion's
    # in the eigenbasis); the check stays as a guard and should count none.
    tracked = tracks.flags == TrackFlag.TRACKED
    covariances = tracks.covariances[tracked]
    indefinite = np.linalg.eigvalsh(0.5 * (covariances + covariances.transpose(0, 2, 1))).min(axis=1) <= 0
    if indefinite.any():
        where = np.argwhere(tracked)[indefinite]
        tracks.flags[where[:, 0], where[:, 1]] = TrackFlag.UNCERTAIN
        print(json.dumps({"seed": args.seed, "tracked_positions_with_indefinite_covariance_dropped": int(indefinite.sum()),
                          "at": [[int(tracks.frames[f]), int(tracks.ids[n])] for f, n in where[:5]]}))
    prepared = time.perf_counter() - clock
    # CPU seconds of this process only (a stage found done on disk costs ~0).
    print(json.dumps({"seed": args.seed, "prepare_cpu_seconds": {k: round(v, 1) for k, v in stages.items()},
                      "prepare_wall_seconds": round(prepared, 1)}))
    if args.prepare_only:
        return
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
    drifts: dict[bool, float] = {}
    curves: dict[bool, tuple] = {}
    for with_tracks in (True,) if args.with_only else (False,) if args.without_only else (False, True):
        clock, cpu = time.perf_counter(), time.process_time()
        options = dict(args.options) if with_tracks else {}
        cache = out / f"without_{args.nodes}.npz"
        fit = None
        if (not with_tracks and args.reuse_without and cache.exists()) or (with_tracks and args.remeasure):
            saved = np.load(cache if not with_tracks else args.save_with)
            positions, seconds, cpu = saved["positions"], float(saved["seconds"]), float(saved["cpu"])
        else:
            fit = fit_sequence(model, hulls, tracks=tracks if with_tracks else None, **fit_keywords(options))
            seconds, cpu = (time.perf_counter() - clock) / args.frames, (time.process_time() - cpu) / args.frames
            positions = np.stack([fit.fits[f].positions for f in frames])
            if not with_tracks and args.reuse_without:
                np.savez(cache, positions=positions, seconds=seconds, cpu=cpu)
            if with_tracks and args.save_with is not None:
                np.savez(args.save_with, positions=positions, seconds=seconds, cpu=cpu)
        vertices = [model.surface_at(positions[f]).vertices for f in frames]
        ties = cKDTree(vertices[0]).query(truth.positions[0])[1]
        drift = [100 * float(np.linalg.norm(vertices[f][ties] - truth.positions[f], axis=1).mean()) / diagonal for f in frames]
        lost = [100 * surface_error(model.surface_at(positions[f]), meshes[f]).lost_limb_fraction for f in frames]
        figure = figure_lost(model, positions, meshes, frames)
        drifts[with_tracks] = float(np.mean(drift))
        metrics = [fit.fits[f].metrics for f in frames] if fit is not None and with_tracks else [{} for f in frames]
        curves[with_tracks] = (drift, lost, [m.get("tracks", 0) for m in metrics],
                               [m.get("tracks_attached", 0) for m in metrics], vertices, ties, positions)
        print(json.dumps({
            "seed": args.seed, "tracks": with_tracks, "options": options,
            "drift_pct_mean": round(float(np.mean(drift)), 3), "drift_pct_max": round(max(drift), 3),
            "lost_pct_max": round(max(lost), 2), "frames_lost": sum(v >= 5.0 for v in lost),
            "figure_lost_pct_max": round(max(figure), 2), "figure_frames_lost": sum(v >= 5.0 for v in figure),
            "seconds_per_frame": round(seconds, 2), "cpu_seconds_per_frame": round(cpu, 2),
        }))
        print("  drift %", " ".join(f"{v:.1f}" for v in drift))
        print("  lost % ", " ".join(f"{v:.1f}" for v in lost))
        print("  figure lost %", " ".join(f"{v:.1f}" for v in figure))
    if not (args.with_only or args.without_only):
        print(json.dumps({"seed": args.seed, "drift_ratio_with_over_without": round(drifts[True] / drifts[False], 3)}))
    if args.diagnose and not (args.with_only or args.without_only):
        diagnose(truth, tracks, frames, diagonal, curves)
        lost_parts(model, truth, tracks, meshes, frames, diagonal, curves)
        anchor_errors(model, truth, tracks, frames, diagonal, curves[True][6], args.options)
        part_drift(truth, tracks, frames, diagonal, curves)


def fit_keywords(options: dict) -> dict:
    """``fit_sequence``'s keywords from ``--options``: its keywords and option objects as
    JSON (``"track_terms": {"ahead": 2}``, ``"stopping": {"max_iterations": 5}``) or, as in the
    commands of earlier sessions, its former flat keywords (``"track_ahead": 2``,
    ``"stiff_stage": 10.0``, ``"solver_tolerance": 1e-5``): ``grouped_keywords`` makes the
    objects (a field given both ways is refused)."""
    try:
        return grouped_keywords(options)
    except InvalidInputError as error:
        raise SystemExit(f"--options: {error}") from error


def figure_lost(model, positions, meshes, frames) -> list[float]:
    """The lost-limb measure (% of the diagonal) of the model's part that is the figure: the
    carved hull that the model is built from holds phantom components away from the figure,
    volume that no camera's mask carves away (seeds 1-5: 0.1-31% of the hull's vertices outside its
    largest component; on seed 4 some lie a metre from the figure, and every frame's measure
    is 50-70% with and without tracks). Fitted vertices farther than the lost-limb line from
    the true surface at frame 0 (the rest frame, fitted to its own hull) are not the figure
    and are left out of the fitted-to-true direction; the true-to-fitted direction is
    unchanged (a limb the fit lost still counts)."""
    from elastocap.elastic.measures import LOST_LIMB_FRACTION, LOST_LIMB_PERCENTILE
    from elastocap.geometry._distance import distance_to_mesh

    surface = model.surface_at(positions[frames[0]])
    used = np.unique(np.asarray(surface.faces).ravel())
    line = LOST_LIMB_FRACTION * float(np.linalg.norm(np.ptp(meshes[0].bounds, axis=0)))
    on = used[distance_to_mesh(np.asarray(surface.vertices)[used], meshes[0]) < line]
    lost = []
    for f in frames:
        surface = model.surface_at(positions[f])
        true = np.asarray(meshes[f].vertices)[np.unique(np.asarray(meshes[f].faces).ravel())]
        both = np.concatenate([distance_to_mesh(np.asarray(surface.vertices)[on], meshes[f]), distance_to_mesh(true, surface)])
        lost.append(100 * float(np.percentile(both, LOST_LIMB_PERCENTILE)) / float(np.linalg.norm(np.ptp(meshes[f].bounds, axis=0))))
    return lost


def diagnose(truth, tracks, frames, diagonal, curves) -> None:
    """Where the drift comes from, per frame: drift without / with tracks (% of the
    diagonal), tracks pulling the frame and attached at it, the tracked positions' count and
    mean age (frames since the track's first tracked frame), and the share of the truth's
    points drifted by more than 2% (without tracks) that have a tracked position within 2%
    of the diagonal of their true position in that frame."""
    tracked = tracks.flags == 0
    first = np.where(tracked.any(axis=0), tracked.argmax(axis=0), -1)
    print("frame drift_without drift_with pulling attached tracked mean_age drifted_pts with_track_near")
    for i, f in enumerate(frames):
        row = np.flatnonzero(tracks.frames == f)
        count, age, near, drifted = 0, 0.0, float("nan"), 0
        errors = np.linalg.norm(curves[False][4][f][curves[False][5]] - truth.positions[f], axis=1) / diagonal
        bad = errors > 0.02
        drifted = int(bad.sum())
        if len(row):
            live = np.flatnonzero(tracked[row[0]])
            count = len(live)
            age = float(np.mean(row[0] - first[live])) if count else 0.0
            if count and drifted:
                d = cKDTree(tracks.positions[row[0], live]).query(truth.positions[f][bad])[0] / diagonal
                near = float(np.mean(d < 0.02))
        print(f"{f:3d} {curves[False][0][i]:6.2f} {curves[True][0][i]:6.2f} {curves[True][2][i]:5d} {curves[True][3][i]:5d} "
              f"{count:5d} {age:5.1f} {drifted:6d} {near:5.2f}")


def part_drift(truth, tracks, frames, diagonal, curves) -> None:
    """Where the drift is, by body part (``synth.skeleton.PARTS``) of the truth's points:
    the part's share of the points, its mean drift over the frames without / with tracks,
    its share of the mean drift with tracks, and the share of its points with a tracked
    position within 2% of the diagonal in the frame (what the tracks cover); worst first."""
    from elastocap.synth.skeleton import PARTS

    error = {}
    for with_tracks in (False, True):
        vertices, ties = curves[with_tracks][4], curves[with_tracks][5]
        error[with_tracks] = np.stack([np.linalg.norm(vertices[f][ties] - truth.positions[f], axis=1) for f in frames]) * 100 / diagonal
    near = np.zeros(error[True].shape, bool)
    for i, f in enumerate(frames):
        row = np.flatnonzero(tracks.frames == f)
        live = tracks.positions[row[0]][tracks.flags[row[0]] == 0] if len(row) else np.zeros((0, 3))
        if len(live):
            near[i] = cKDTree(live).query(truth.positions[f])[0] <= 0.02 * diagonal
    print(f"drift by part (% of the diagonal): all points {error[True].mean():.2f}; near a track ({near.mean():.2f} of them) "
          f"{error[True][near].mean():.2f}, the others {error[True][~near].mean():.2f}")
    print("  part          points  without   with  contributes  near")
    rows = []
    for p in np.unique(truth.part):
        on = truth.part == p
        rows.append((error[True][:, on].sum() / error[True].size, PARTS[p], on.mean(), error[False][:, on].mean(),
                     error[True][:, on].mean(), near[:, on].mean()))
    for share, name, points, without, with_, covered in sorted(rows, reverse=True):
        print(f"  {name:12s} {100 * points:6.1f}% {without:8.2f} {with_:6.2f} {share:12.2f} {covered:5.2f}")


def anchor_errors(model, truth, tracks, frames, diagonal, positions, options: dict | None = None) -> None:
    """Where the tracks are attached, by anchor frame: the distance between a track's
    material point at rest (its MLS weights over the fit's frame-0 nodes) and the true rest
    position of the surface point it was tracked on (the ground-truth point nearest its
    tracked position at its anchor frame, within 1% of the diagonal), median % of the
    diagonal; attached as the fit does (the relay, the carry ahead and their options as the
    fit's ``TrackTerms`` from ``options`` set them, or its defaults; the frame's start for
    the carry's check is the fit's constant-velocity prediction, as the fit's) and without
    either (``relay``, ``ahead`` and ``relay_memory`` 0), on the same fit."""
    from elastocap.elastic.tracks import TrackAttachments

    spacing = float(np.mean(model.volumes) ** (1 / 3))
    terms = fit_keywords(options or {}).get("track_terms") or TrackTerms()
    bins = [(0, 1)] + [(lo, min(lo + 10, len(frames))) for lo in range(1, len(frames), 10)]
    rows = {}
    for relayed in (True, False):
        used = terms if relayed else replace(terms, relay=0, ahead=0, relay_memory=0)
        attachments = TrackAttachments.build(tracks, frames[0], model.neighbors.shape[1], used, spacing)
        for i, f in enumerate(frames):
            start = positions[frames[max(i - 1, 0)]] if i < 2 else 2 * positions[frames[i - 1]] - positions[frames[i - 2]]
            attachments.attach_ahead(f, start)
            attachments.attach(f, positions[f])
        n = np.flatnonzero(attachments.attached)
        anchor = attachments.anchor[n]
        error = np.full(len(n), np.nan)
        for row in np.unique(anchor):
            pick = anchor == row
            f = int(tracks.frames[row])
            gap, nearest = cKDTree(truth.positions[f]).query(tracks.positions[row, n[pick]])
            rest = np.einsum("tk,tkd->td", attachments.phi[n[pick]], positions[frames[0]][attachments.neighbours[n[pick]]])
            e = 100 * np.linalg.norm(rest - truth.positions[frames[0]][nearest], axis=1) / diagonal
            error[pick] = np.where(gap <= 0.01 * diagonal, e, np.nan)
        rows[relayed] = [(np.nanmedian(error[(anchor >= lo) & (anchor < hi)]) if ((anchor >= lo) & (anchor < hi)).any() else np.nan,
                        int(((anchor >= lo) & (anchor < hi) & np.isfinite(error)).sum())) for lo, hi in bins]
    print(f"anchor frames: median attachment error % of the diagonal (tracks), relay {terms.relay}"
          f"{f' and ahead {terms.ahead}' if terms.ahead else ''} / 0")
    for (lo, hi), a, b in zip(bins, rows[True], rows[False]):
        print(f"  {lo:3d}-{hi - 1:3d}: {a[0]:5.2f} / {b[0]:5.2f} ({a[1]})")


# Frames whose lost-limb measure reaches this (% of the diagonal) in either fit are broken
# down by body part: the line (5%) and frames just under it, which flip with small changes.
_NEAR_LOST = 4.8


def lost_parts(model, truth, tracks, meshes, frames, diagonal, curves) -> None:
    """Which limb a frame loses: for each frame at or near the lost-limb line in either fit,
    the body parts (``synth.skeleton.PARTS``) of the distances above the frame's 99th
    percentile in each fit (fitted vertex to the true surface, true vertex to the fitted
    one; a fitted vertex attributed to the part of the ground-truth point nearest it at
    frame 0, a true vertex to the part nearest it in the frame), and per part
    the tracks tracked in the frame that lie on it (tracked position within 2% of the
    diagonal of one of the part's true points)."""
    from elastocap.geometry._distance import distance_to_mesh
    from elastocap.synth.skeleton import PARTS

    tracked = tracks.flags == 0
    rest_parts = cKDTree(truth.positions[0])
    near = [i for i, f in enumerate(frames) if max(curves[False][1][i], curves[True][1][i]) >= _NEAR_LOST]
    for i in near:
        f = frames[i]
        parts_of = cKDTree(truth.positions[f])
        line = []
        for with_tracks in (False, True):
            surface = model.surface_at(curves[with_tracks][6][f])
            used = np.unique(np.asarray(surface.faces).ravel())
            fitted = np.asarray(surface.vertices)[used]
            true = np.asarray(meshes[f].vertices)[np.unique(np.asarray(meshes[f].faces).ravel())]
            both = np.concatenate([distance_to_mesh(fitted, meshes[f]), distance_to_mesh(true, surface)])
            # A fitted vertex belongs to the part its material sits on at frame 0 (where it
            # went astray says nothing); a true vertex to the part nearest it in the frame.
            part = np.concatenate([truth.part[rest_parts.query(curves[with_tracks][4][frames[0]][used])[1]],
                                   truth.part[parts_of.query(true)[1]]])
            worst = both >= np.percentile(both, 99.0)
            part = part[worst]
            counts = np.bincount(part, minlength=len(PARTS))
            top = np.argsort(-counts)[:3]
            line.append(("with" if with_tracks else "without") + f" {curves[with_tracks][1][i]:.2f}%: "
                        + ", ".join(f"{PARTS[p]} {counts[p] / worst.sum():.0%}" for p in top if counts[p]))
        row = np.flatnonzero(tracks.frames == f)
        on = ""
        if len(row):
            live = np.flatnonzero(tracked[row[0]])
            if len(live):
                gap, nearest = cKDTree(truth.positions[f]).query(tracks.positions[row[0], live])
                part = truth.part[nearest]
                counts = np.bincount(part[gap < 0.02 * diagonal], minlength=len(PARTS))
                on = "; tracks on " + ", ".join(f"{PARTS[p]} {counts[p]}" for p in np.flatnonzero(counts))
        print(f"frame {f}: " + " | ".join(line) + on)


if __name__ == "__main__":
    main()
