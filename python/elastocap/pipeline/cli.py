"""The ``elastocap`` command line.

Every command exits non-zero with a one-line reason on bad input (an
:class:`~elastocap.ElastocapError` or an unreadable path); a bug still shows its traceback.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from elastocap._core import ElastocapError

__all__ = ["main"]


def _demo(args: argparse.Namespace) -> int:
    from elastocap.pipeline.demo import run_demo

    metrics_path = run_demo(
        Path(args.out), n_points=args.points, frames=args.frames, cameras=args.cameras, progress=not args.quiet
    )
    print(f"wrote {metrics_path}")
    return 0


def _synth(args: argparse.Namespace) -> int:
    from elastocap.synth.capture import write_synthetic_capture

    out = write_synthetic_capture(
        Path(args.out), frames=args.frames, cameras=args.cameras, seed=args.seed, progress=not args.quiet,
        figure=args.figure,
    )
    print(f"wrote {out} ({args.frames} frames, {args.cameras} cameras)")
    return 0


def _hull(args: argparse.Namespace) -> int:
    from elastocap.capture.folder import Capture
    from elastocap.pipeline.hull import parse_frames, run_hull_stage

    capture = Capture.open(args.capture)
    written = run_hull_stage(
        capture,
        Path(args.out),
        resolution=args.resolution,
        frames=parse_frames(args.frames, capture.frames),
        tolerance=args.tolerance,
        footprint=args.footprint,
        phantoms="keep" if args.keep_phantoms else "drop",
        progress=not args.quiet,
    )
    print(f"wrote {len(written)} hull(s) into {Path(args.out) / 'hull'} ({len(capture.frames) - len(written)} already there or not asked for)")
    return 0


def _track(args: argparse.Namespace) -> int:
    from elastocap.capture.folder import Capture
    from elastocap.pipeline.hull import parse_frames
    from elastocap.pipeline.track import FIT_SPACING, run_track_stage

    capture = Capture.open(args.capture)
    spacing = FIT_SPACING if args.spacing is None else args.spacing
    tracks = run_track_stage(capture, Path(args.out), frames=parse_frames(args.frames, capture.frames),
                             progress=not args.quiet, spacing=spacing)
    tracked = int((tracks.flags == 0).any(axis=0).sum())
    print(f"tracked {tracked} of {len(tracks.ids)} points through {len(tracks.frames)} frames into {Path(args.out) / 'tracks'}")
    return 0


def _fit(args: argparse.Namespace) -> int:
    from elastocap.pipeline.fit import run_fit_stage

    result = run_fit_stage(
        args.capture,
        Path(args.out),
        rest_frame=args.rest_frame,
        n_nodes=args.nodes,
        rotation=args.rotation,
        stiffness=args.stiffness,
        resolution=args.resolution,
        tracks=not args.no_tracks,
        progress=not args.quiet,
    )
    print(f"fitted {len(result.fits)} frame(s) into {Path(args.out) / 'fit'}; figures in {Path(args.out) / 'metrics.json'}")
    return 0


def _body(args: argparse.Namespace) -> int:
    from elastocap.pipeline.body import run_body_stage
    from elastocap.capture.folder import Capture
    from elastocap.pipeline.hull import parse_frames

    capture = Capture.open(args.capture)
    written = run_body_stage(capture, Path(args.out), frames=parse_frames(args.frames, capture.frames),
                             tracks=not args.no_tracks, progress=not args.quiet)
    print(f"wrote {written}")
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    from elastocap.stereo.calibration_cli import run_calibrate

    run_calibrate(args.images, args.board, args.square_size, args.out, world=args.world, focal_length=args.focal_length)
    return 0


def _export(args: argparse.Namespace) -> int:
    from elastocap.pipeline.export import export_settings, export_take

    settings = export_settings(args.out, take=args.take, fps=args.fps, units=args.units, up=args.up)
    for path in export_take(args.out, args.format, settings):
        print(f"wrote {path}")
    return 0


def _capture(args: argparse.Namespace) -> int:
    from elastocap.pipeline.capture import run_capture
    from elastocap.pipeline.options import resolve_options

    options, extra = resolve_options(args.config, args)
    capture = args.capture if args.capture is not None else extra.get("capture")
    if capture is None:
        raise ElastocapError("name the capture folder (CAPTURE, or capture = \"...\" in the --config file)")
    run = run_capture(capture, Path(args.out), options, progress=not args.quiet)
    print(f"wrote {run.out / 'report.html'}, {run.out / 'metrics.json'} and {len(run.exports)} export(s) in {run.out / 'export'}")
    return 0


def _batch(args: argparse.Namespace) -> int:
    from elastocap.pipeline.batch import run_batch
    from elastocap.pipeline.options import resolve_options

    options, _ = resolve_options(args.config, args)
    result = run_batch(
        args.takes, Path(args.out), options, scheduler=args.scheduler, workers=args.workers, threads=options.threads,
        serial=args.serial, progress=not args.quiet,
    )
    summary = result.summary
    print(f"{summary['done']} of {summary['takes']} take(s) done, {len(summary['failed'])} failed; see {Path(args.out) / 'batch.json'}")
    for take in summary["failed"]:
        print(f"  {take}: {result.takes[take]['reason']}", file=sys.stderr)
    return 0 if not summary["failed"] else 1


def _silhouettes(args: argparse.Namespace) -> int:
    from elastocap.capture.folder import Capture
    from elastocap.pipeline.hull import parse_frames
    from elastocap.pipeline.silhouettes import run_silhouettes_stage

    capture = Capture.open(args.capture)
    written = run_silhouettes_stage(capture, Path(args.out), frames=parse_frames(args.frames, capture.frames), progress=not args.quiet)
    print(f"wrote the masks of {len(written)} frame(s) into {Path(args.out) / 'masks'}")
    return 0


def _stereo(args: argparse.Namespace) -> int:
    from elastocap.capture.folder import Capture
    from elastocap.pipeline.hull import parse_frames
    from elastocap.pipeline.stereo import run_stereo_stage

    from elastocap._core import InvalidInputError

    capture = Capture.open(args.capture)
    volume = None
    if args.volume is not None:
        try:
            corners = [float(x) for x in args.volume.split(",")]
        except ValueError:
            raise InvalidInputError(f"--volume must be six numbers x0,y0,z0,x1,y1,z1, got {args.volume!r}") from None
        if len(corners) != 6:
            raise InvalidInputError(f"--volume must be six numbers x0,y0,z0,x1,y1,z1, got {args.volume!r}")
        volume = [corners[:3], corners[3:]]
    written = run_stereo_stage(
        capture, Path(args.out), frames=parse_frames(args.frames, capture.frames), volume=volume, step=args.step,
        pictures=not args.no_pictures, progress=not args.quiet,
    )
    print(f"wrote the points of {len(written)} frame(s) into {Path(args.out) / 'points'}")
    return 0


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="elastocap",
        description="Markerless capture of shape and motion from calibrated multi-view video.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    demo = commands.add_parser(
        "demo",
        help="synthetic capture -> visual hulls -> elastic fit, plus kernel checks; writes a report",
        description="Write a synthetic capture and run elastocap capture on it (visual hulls, an "
        "elastic model fitted through all frames, OUT/report.html with fit_views.png, fit_strip.png, "
        "fit_plots.png, hull_views.png, and OUT/export/capture.glb, .pc2, .obj), measure it against "
        "the ground truth, check the kernels against scipy and numpy, and write OUT/metrics.json. "
        "A second run resumes the first.",
    )
    demo.add_argument("--out", default="demo-out", help="output folder (default: demo-out)")
    demo.add_argument("--points", type=int, default=100_000, help="points per generated cloud (default: 100000)")
    demo.add_argument("--frames", type=int, default=30, help="frames of the synthetic capture (default: 30)")
    demo.add_argument("--cameras", type=int, default=8, help="cameras of the synthetic capture (default: 8)")
    demo.add_argument("--quiet", action="store_true", help="no progress bar")
    demo.set_defaults(run=_demo)
    synth = commands.add_parser(
        "synth",
        help="write a synthetic capture folder (figure in motion, camera ring, ground truth)",
        description="Render a walking, turning, clapping figure from a ring of calibrated cameras "
        "and write the capture folder (intri.yml, extri.yml, images/, masks/, background/) with "
        "the ground-truth surfaces in ground_truth/. Rerunning finishes an interrupted capture.",
    )
    synth.add_argument("--out", required=True, metavar="CAPTURE", help="capture folder to write")
    synth.add_argument("--frames", type=int, default=30, help="number of frames (default: 30, one walk cycle)")
    synth.add_argument("--cameras", type=int, default=8, help="number of cameras, at least 2 (default: 8)")
    synth.add_argument("--seed", type=int, default=0, help="figure and rig variation (default: 0)")
    synth.add_argument("--quiet", action="store_true", help="no progress bar")
    synth.add_argument(
        "--figure", choices=("capsules", "body"), default="capsules",
        help="capsules: the capsule figure (default); body: the body model itself, with its "
        "shape and states in ground_truth/body.json",
    )
    synth.set_defaults(run=_synth)
    hull = commands.add_parser(
        "hull",
        help="carve the visual hull of every frame of a capture",
        description="Carve each frame's visual hull from the capture's masks and write "
        "OUT/hull/<frame>.ply (surface) and .npz (occupancy, grid, signed distance). Frames "
        "already written are skipped, so an interrupted run resumes.",
    )
    hull.add_argument("capture", metavar="CAPTURE", help="capture folder (intri/extri or rig.json, masks/)")
    hull.add_argument("--out", required=True, help="output folder")
    hull.add_argument("--resolution", type=int, default=128, help="voxels along the longest side (default: 128)")
    hull.add_argument("--frames", default=None, help="frames a:b (end exclusive) or a single frame (default: all)")
    hull.add_argument("--tolerance", type=int, default=0, help="cameras that may disagree (default: 0)")
    hull.add_argument("--footprint", choices=["center", "conservative"], default="center", help="finest-level test")
    hull.add_argument("--keep-phantoms", action="store_true",
                      help="keep the hull's components that explain no silhouette pixel of their own (default: left out)")
    hull.add_argument("--quiet", action="store_true", help="no progress bar")
    hull.set_defaults(run=_hull)
    track = commands.add_parser(
        "track",
        help="track surface points through every frame and across cameras",
        description="Seed points on the textured masks, track them in every camera (NCC box search, "
        "least-squares matching, forward-backward check) and in 3-D (forward intersection, trajectory "
        "filters), and write OUT/tracks/<frame>.npz (ids, positions, covariances, flags), "
        "OUT/tracks.png and OUT/tracks_strip.png. Frames already written are skipped.",
    )
    track.add_argument("capture", metavar="CAPTURE", help="capture folder (calibration, images/, masks/)")
    track.add_argument("--out", required=True, help="output folder")
    track.add_argument("--frames", default=None, help="frames a:b (end exclusive) or a single frame (default: all)")
    track.add_argument("--spacing", type=int, default=None, help="one seed per spacing x spacing pixels of mask (default: 5, the "
                       "elastic fit's: ~4x the tracks of 10 px for ~2.3x the tracking time; drift with / without tracks on the "
                       "textured fast capture 0.59 / 0.64 against 0.63 / 0.71 at 10 px, held-out seeds, benches/README.md, trackfit4)")
    track.add_argument("--quiet", action="store_true", help="no progress bar")
    track.set_defaults(run=_track)
    fit = commands.add_parser(
        "fit",
        help="fit an elastic model through all frames of a capture (hulls first if missing)",
        description="Carve the hulls that are missing, build an element-free elastic model of the "
        "rest frame's hull (OUT/model/rest.npz), fit it forward and backward through every frame "
        "and write OUT/fit/<frame>.ply (same vertices and faces every frame) and .npz (node "
        "positions, metrics), and OUT/metrics.json. Frames already fitted are not refitted.",
    )
    fit.add_argument("capture", metavar="CAPTURE", help="capture folder (intri/extri or rig.json, masks/)")
    fit.add_argument("--out", required=True, help="output folder")
    fit.add_argument("--rest-frame", type=int, default=None, help="frame the model is built from (default: the frame whose hull encloses the least volume)")
    fit.add_argument("--nodes", type=int, default=2500, help="nodes of the elastic model (default: 2500)")
    fit.add_argument(
        "--rotation",
        choices=["rhs", "warped", "none"],
        default="warped",
        help="rotation compensation (default: warped, which tracks rotations without accumulating strain)",
    )
    fit.add_argument("--stiffness", type=float, default=1.0, help="elastic stiffness vs. surface pull (default: 1)")
    fit.add_argument("--resolution", type=int, default=128, help="hull voxels along the longest side (default: 128)")
    fit.add_argument("--no-tracks", action="store_true",
                     help="ignore OUT/tracks/ (by default its tracks, from elastocap track, pin the fit)")
    fit.add_argument("--quiet", action="store_true", help="no progress bar")
    fit.set_defaults(run=_fit)
    body = commands.add_parser(
        "body",
        help="fit the articulated body model to every frame's silhouettes",
        description="Fit the default human body model (SPEC 6) to the capture's masks: "
        "OUT/body/fit.json (shape, joint angles per frame), OUT/body/<frame>.ply (skin meshes) "
        "and OUT/body_views.png. A finished run is not redone.",
    )
    body.add_argument("capture", metavar="CAPTURE", help="capture folder (intri/extri or rig.json, masks/)")
    body.add_argument("--out", required=True, help="output folder")
    body.add_argument("--frames", default=None, help="frames a:b (end exclusive) or a single frame (default: all)")
    body.add_argument("--no-tracks", action="store_true",
                      help="do not attach OUT/tracks/ points to body parts (by default they pin the parts they lie on)")
    body.add_argument("--quiet", action="store_true", help="no progress bar")
    body.set_defaults(run=_body)
    from elastocap.cameras.commands import add_rig_parser

    add_rig_parser(commands)
    calibrate = commands.add_parser(
        "calibrate",
        help="calibrate a rig from chessboard images (per-camera RMS; warns on what the views cannot determine)",
        description="Find the chessboard in IMAGES/<camera>/<view>.png|jpg (or a flat folder of "
        "<camera><view>.png|jpg, e.g. left01.jpg right01.jpg), calibrate every camera and their "
        "relative poses, and write the rig (a folder: intri.yml + extri.yml; or a .json file).",
    )
    calibrate.add_argument("images", metavar="IMAGES", help="folder of board images")
    calibrate.add_argument("--board", required=True, help="inner corners COLUMNSxROWS, e.g. 7x5")
    calibrate.add_argument("--square-size", type=float, default=1.0, help="square edge in the rig's unit (default: 1)")
    calibrate.add_argument("--out", required=True, metavar="RIG", help="output folder (intri/extri.yml) or .json")
    calibrate.add_argument("--world", default=None, help="camera whose frame is the world (default: first board pose)")
    calibrate.add_argument("--focal-length", type=float, default=None, help="focal length (px) to hold if undetermined")
    calibrate.set_defaults(run=_calibrate)
    from elastocap.pipeline.options import add_option_flags

    capture = commands.add_parser(
        "capture",
        help="every stage the capture allows, the report and the animation files, in one command",
        description="Silhouettes (the capture's masks, its background/ plates or a dark background), "
        "visual hulls, the elastic fit through every frame (and the body model with --body), then "
        "OUT/metrics.json, OUT/report.html and OUT/export/<take>.glb, .pc2 (+ .obj). Options come from "
        "--config (TOML; keys as below with underscores), overridden by the flags given; the options "
        "used are written to OUT/capture.toml. Interrupted runs resume where they stopped.",
    )
    capture.add_argument("capture", metavar="CAPTURE", nargs="?", default=None, help="capture folder (default: capture = in --config)")
    capture.add_argument("--out", required=True, help="output folder")
    capture.add_argument("--config", default=None, metavar="capture.toml", help="options file (TOML)")
    add_option_flags(capture)
    capture.add_argument("--quiet", action="store_true", help="no progress bars")
    capture.set_defaults(run=_capture)
    batch = commands.add_parser(
        "batch",
        help="many takes through elastocap capture on a Dask cluster (a take per task)",
        description="Run elastocap capture on every take under TAKES_DIR (a folder holding a "
        "calibration, at any depth) into OUT/<take>/, on a local cluster of worker processes or "
        "on a running Dask scheduler (--scheduler; e.g. dask-jobqueue on SLURM). A failing take is "
        "recorded with its reason in OUT/batch.json and the others go on; a rerun skips the takes "
        "already done. Exits 1 when a take failed.",
    )
    batch.add_argument("takes", metavar="TAKES_DIR", help="folder of takes (capture folders)")
    batch.add_argument("--out", required=True, help="output folder")
    batch.add_argument("--scheduler", default=None, metavar="ADDRESS", help="Dask scheduler address (default: a local cluster)")
    batch.add_argument("--workers", type=int, default=None, help="worker processes of the local cluster (default: cores / 2)")
    batch.add_argument("--serial", action="store_true", help="no cluster: one take after the other in this process")
    batch.add_argument("--config", default=None, metavar="capture.toml", help="options of every take (TOML)")
    add_option_flags(batch)  # --threads: each take's threads (default: cores / workers)
    batch.add_argument("--quiet", action="store_true", help="no progress bar")
    batch.set_defaults(run=_batch)
    export = commands.add_parser(
        "export",
        help="animation files of an output folder: glb, pc2 (+ obj), usd; bvh, trc, c3d",
        description="Write OUT/export/<take>.<format> in metres with +Y up: glb (rest mesh with a "
        "morph target per frame and the weights animated at the frame rate), pc2 (Blender Mesh "
        "Cache point cache, with <take>.obj, the rest mesh) and usd (time-sampled points, needs "
        "usd-core) from the elastic fit; bvh (skeleton), trc and c3d (joint trajectories) from the "
        "body fit. Frame rate, units and up axis come from OUT/capture.toml unless given.",
    )
    export.add_argument("out", metavar="OUT", help="output folder of the capture stages")
    export.add_argument(
        "--format", nargs="+", required=True, choices=["glb", "pc2", "usd", "bvh", "trc", "c3d"], help="one or more formats"
    )
    export.add_argument("--fps", type=float, default=None, help="frames per second (default: OUT/capture.toml, else 30)")
    export.add_argument("--units", default=None, help="the capture's units: m, cm, mm or metres per unit (default: m)")
    export.add_argument("--up", choices=["y", "z"], default=None, help="the capture's up axis (default: y)")
    export.add_argument("--take", default=None, help="file name of the exports (default: the capture folder's name)")
    export.set_defaults(run=_export)
    silhouettes = commands.add_parser(
        "silhouettes",
        help="model-based silhouettes without a background plate (snakes + body model)",
        description="Extract every frame's silhouettes in clutter (SPEC 8): active contours on "
        "the disparity-filtered gradient, corrected by the body model fitted to them. Reads "
        "OUT/disparity/<cam>/<frame>.png and OUT/points/<frame>.npz from the stereo stage; "
        "writes OUT/masks/<cam>/<frame>.png, which hull, fit and body then use.",
    )
    silhouettes.add_argument("capture", metavar="CAPTURE", help="capture folder (calibration, images/ or videos/)")
    silhouettes.add_argument("--out", required=True, help="output folder")
    silhouettes.add_argument("--frames", default=None, help="frames a:b (end exclusive) or a single frame (default: all)")
    silhouettes.add_argument("--quiet", action="store_true", help="no progress bar")
    silhouettes.set_defaults(run=_silhouettes)
    stereo = commands.add_parser(
        "stereo",
        help="dense 3-D points per frame from the capture's stereo pairs",
        description="For every frame and every camera pair or triplet named in CAPTURE/stereo.json "
        "(else pairs chosen by baseline): SGBM seeds, least-squares matches grown over the left "
        "image, forward intersection with each match's covariance. Writes OUT/points/<frame>.ply "
        "(x, y, z, colour, sigma) and .npz, OUT/disparity/<pair>/<frame>.png|.npz and "
        "OUT/pictures/stereo/<frame>.png. Frames already written are skipped.",
    )
    stereo.add_argument("capture", metavar="CAPTURE", help="capture folder (calibration, images/; masks/ optional)")
    stereo.add_argument("--out", required=True, help="output folder")
    stereo.add_argument("--frames", default=None, help="frames a:b (end exclusive) or a single frame (default: all)")
    stereo.add_argument(
        "--volume", default=None,
        help="capture volume --volume=x0,y0,z0,x1,y1,z1 in world units (default: the box every camera sees)",
    )
    stereo.add_argument("--step", type=int, default=2, help="spacing of the matched points in the left image, pixels (default: 2)")
    stereo.add_argument("--no-pictures", action="store_true", help="do not write OUT/pictures/stereo")
    stereo.add_argument("--quiet", action="store_true", help="no progress bar")
    stereo.set_defaults(run=_stereo)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``elastocap`` console script; returns the exit status."""
    args = _parser().parse_args(argv)
    try:
        return int(args.run(args))
    except (ElastocapError, OSError) as error:
        print(f"elastocap {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
