"""``elastocap rig convert IN OUT`` and ``elastocap rig show RIG``: the command line of the
calibration formats (wired into :mod:`elastocap.pipeline.cli`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from elastocap.cameras.formats import FORMATS
from elastocap.cameras.formats.colmap import MODELS
from elastocap.cameras.rig import UNITS, Rig

__all__ = ["add_rig_parser", "convert_rig", "show_rig"]


def _load(args: argparse.Namespace, path: str) -> Rig:
    size = tuple(args.size) if args.size else None
    return Rig.load(path, size=size, format=args.input_format, units=args.units, up=args.up)


def convert_rig(args: argparse.Namespace) -> int:
    """Read ``args.input`` and write it to ``args.output``; prints what was written."""
    rig = _load(args, args.input)
    target = rig.save(args.output, format=args.format, model=args.colmap_model)
    print(f"wrote {len(rig)} cameras to {target}")
    return 0


def show_rig(args: argparse.Namespace) -> int:
    """Print the rig's cameras and sanity checks; draw it to ``args.out``."""
    from elastocap.cameras.show import check_rig, describe_rig, draw_rig

    rig = _load(args, args.rig)
    print(describe_rig(rig))
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        problems = check_rig(rig)
    for problem in problems:
        print(f"warning: {problem}")
    print(f"{len(problems)} warning(s); picture: {draw_rig(rig, args.out)}")
    return 0


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--from", dest="input_format", choices=list(FORMATS), default=None,
                        help="input format (default: told from the path)")
    parser.add_argument("--size", type=int, nargs=2, metavar=("W", "H"), default=None,
                        help="image size, for formats that do not store it")
    parser.add_argument("--units", choices=list(UNITS), default=None,
                        help="the input's world units: convert to metres")
    parser.add_argument("--up", choices=["x", "-x", "y", "-y", "z", "-z"], default=None,
                        help="the input's up axis: rotate it to +y")


def add_rig_parser(commands: Any) -> None:
    """Add ``rig convert`` and ``rig show`` to the command line's subparsers."""
    rig = commands.add_parser("rig", help="calibration formats: convert between them, show a rig",
                              description="Convert calibrations between formats, or print and draw a rig.")
    actions = rig.add_subparsers(dest="rig_command", required=True, metavar="ACTION")
    convert = actions.add_parser(
        "convert", help="convert a calibration to another format",
        description="Read a calibration in any format elastocap knows and write it in another, told by "
        "OUT's name (intri.yml or a folder: EasyMocap; rig.json; transforms.json: NeRF; *_par.txt: "
        "Middlebury; cameras.txt / cameras.bin: COLMAP; *.toml: Anipose; other *.yml: OpenCV stereo) "
        "or --format. What OUT's format cannot hold is refused with a message naming it.")
    convert.add_argument("input", metavar="IN", help="calibration file or folder")
    convert.add_argument("output", metavar="OUT", help="file or folder to write")
    convert.add_argument("--format", choices=list(FORMATS), default=None, help="output format")
    convert.add_argument("--colmap-model", choices=list(MODELS), default=None,
                         help="COLMAP camera model (default: the simplest that holds each camera)")
    _common(convert)
    convert.set_defaults(run=convert_rig)
    show = actions.add_parser(
        "show", help="print a rig's cameras, check them and draw them to a PNG",
        description="Print each camera (size, focal length and field of view, principal point, "
        "distortion, centre, viewing direction), warn about implausible focal lengths and cameras "
        "looking away from the volume the others see, and draw the camera frusta and that volume.")
    show.add_argument("rig", metavar="RIG", help="calibration file or folder")
    show.add_argument("--out", default="rig.png", help="picture to write (default: rig.png)")
    _common(show)
    show.set_defaults(run=show_rig)
