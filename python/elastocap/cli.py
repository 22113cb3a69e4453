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
    from elastocap.demo import run_demo

    metrics_path = run_demo(Path(args.out), n_points=args.points, progress=not args.quiet)
    print(f"wrote {metrics_path}")
    return 0


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="elastocap",
        description="Markerless capture of shape and motion from calibrated multi-view video.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    demo = commands.add_parser(
        "demo",
        help="run the demo on generated data and write what it measured",
        description="Exercise the kernels (spatial hashing, polar decomposition) on generated "
        "data, check them against scipy and numpy, and write OUT/metrics.json.",
    )
    demo.add_argument("--out", default="demo-out", help="output folder (default: demo-out)")
    demo.add_argument("--points", type=int, default=100_000, help="points per generated cloud (default: 100000)")
    demo.add_argument("--quiet", action="store_true", help="no progress bar")
    demo.set_defaults(run=_demo)
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
