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
        progress=not args.quiet,
    )
    print(f"wrote {len(written)} hull(s) into {Path(args.out) / 'hull'} ({len(capture.frames) - len(written)} already there or not asked for)")
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
        progress=not args.quiet,
    )
    print(f"fitted {len(result.fits)} frame(s) into {Path(args.out) / 'fit'}; figures in {Path(args.out) / 'metrics.json'}")
    return 0


def _body(args: argparse.Namespace) -> int:
    from elastocap.pipeline.body import run_body_stage
    from elastocap.capture.folder import Capture
    from elastocap.pipeline.hull import parse_frames

    capture = Capture.open(args.capture)
    written = run_body_stage(capture, Path(args.out), frames=parse_frames(args.frames, capture.frames), progress=not args.quiet)
    print(f"wrote {written}")
    return 0


def _silhouettes(args: argparse.Namespace) -> int:
    from elastocap.capture.folder import Capture
    from elastocap.pipeline.hull import parse_frames
    from elastocap.silhouettes.model_based import run_silhouettes_stage

    capture = Capture.open(args.capture)
    written = run_silhouettes_stage(capture, Path(args.out), frames=parse_frames(args.frames, capture.frames), progress=not args.quiet)
    print(f"wrote the masks of {len(written)} frame(s) into {Path(args.out) / 'masks'}")
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
        description="Write a synthetic capture, carve its visual hulls, fit an elastic model "
        "through all frames, measure it against the ground truth, draw the fits over the camera "
        "images (OUT/report.html with fit_views.png, fit_strip.png, fit_plots.png, "
        "hull_views.png), check the kernels against scipy and numpy, and write "
        "OUT/metrics.json. A second run resumes the first.",
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
    hull.add_argument("--quiet", action="store_true", help="no progress bar")
    hull.set_defaults(run=_hull)
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
    fit.add_argument("--rest-frame", type=int, default=None, help="frame the model is built from (default: first)")
    fit.add_argument("--nodes", type=int, default=2500, help="nodes of the elastic model (default: 2500)")
    fit.add_argument(
        "--rotation",
        choices=["rhs", "warped", "none"],
        default="warped",
        help="rotation compensation (default: warped, which tracks rotations without accumulating strain)",
    )
    fit.add_argument("--stiffness", type=float, default=1.0, help="elastic stiffness vs. surface pull (default: 1)")
    fit.add_argument("--resolution", type=int, default=128, help="hull voxels along the longest side (default: 128)")
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
    body.add_argument("--quiet", action="store_true", help="no progress bar")
    body.set_defaults(run=_body)
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
