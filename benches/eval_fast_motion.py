"""Issue 17's fast-motion figures: the synthetic fast-motion capture (``CapsuleFigure(seed,
motion="fast")``, 8 cameras with skew and distortion) carved into hulls, the elastic model
built on one frame's hull and fitted through the sequence with each option set given, each
frame measured against the figure's true surface: the lost-limb measure (% of the
bounding-box diagonal; the hull's own beside it; the model built on the hull of least
volume unless ``--rest`` says otherwise), the fitted-to-hull ratio of the mean
pooled distance, the coverage term's unexplained samples (%) and the volume ratio.

Run: ``python benches/eval_fast_motion.py SEED FRAMES NODES RESOLUTION WIDTH HEIGHT
'[{"coverage": 0.0, "silhouette": 0.0}, {"silhouette": 0.0}, {}]' [--poisson P] [--rest volume|first|F]`` (fit_sequence
gets the capture's cameras and masks: its silhouette term is on unless the options turn it off); the capture and hulls are kept in
``/tmp/elastocap_fast_<seed>_<frames>_<width>`` and reused.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from elastocap import ElasticModel, fit_sequence
from elastocap.capture.folder import Capture
from elastocap.elastic.fit_options import grouped_keywords
from elastocap.elastic.measures import surface_error
from elastocap.elastic.rest import least_volume_frame
from elastocap.pipeline.hull import load_hull, run_hull_stage
from elastocap.synth import CapsuleFigure
from elastocap.synth.capture import write_synthetic_capture


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    for name in ("seed", "frames", "nodes", "resolution", "width", "height"):
        parser.add_argument(name, type=int)
    parser.add_argument("options", type=json.loads, help="JSON list of fit_sequence option sets")
    parser.add_argument("--poisson", type=float, default=None, help="the model's Poisson ratio (default from_mesh's)")
    parser.add_argument("--rest", default="volume",
                        help="the rest frame: 'volume' (the hull of least volume, the pipeline's default), "
                             "'first', or a frame number")
    args = parser.parse_args()
    root = Path(f"/tmp/elastocap_fast_{args.seed}_{args.frames}_{args.width}")
    write_synthetic_capture(root, frames=args.frames, seed=args.seed, motion="fast",
                            image_size=(args.width, args.height), progress=False)
    run_hull_stage(root, root / "out", resolution=args.resolution, progress=False)
    frames = range(args.frames)
    hulls = [load_hull(root / "out", f) for f in frames]
    figure = CapsuleFigure(args.seed, motion="fast")
    truths = [figure.mesh(f, spacing=0.02) for f in frames]
    hull_errors = [surface_error(hulls[f].mesh(), truths[f]) for f in frames]
    extra = {} if args.poisson is None else {"poisson": args.poisson}
    rest = {"volume": least_volume_frame(hulls), "first": 0}.get(args.rest)
    rest = int(args.rest) if rest is None else rest
    model = ElasticModel.from_mesh(hulls[rest].mesh(), n_nodes=args.nodes, **extra)
    print(f"seed {args.seed}, {args.frames} frames, rest frame {rest} ({args.rest}), {model.n_nodes} nodes, poisson {model.poisson}, "
          f"hulls of {args.resolution} voxels, images {args.width}x{args.height}")
    print("hull lost %", " ".join(f"{100 * e.lost_limb_fraction:.1f}" for e in hull_errors))
    capture = Capture.open(root)
    masks = [[capture.masks(f)[name] for name in capture.rig.names] for f in frames]
    for options in args.options:
        clock = time.perf_counter()
        # The cameras and masks, as the pipeline gives them ('{"silhouette": 0}' turns the
        # silhouette term off); the options as fit_sequence's keywords or its former flat
        # ones (grouped_keywords: '{"stiff_stage_frames": "all"}').
        views = {"cameras": capture.rig.cameras, "masks": masks}
        fit = fit_sequence(model, hulls, rest_frame=rest, **grouped_keywords(options), **views)
        seconds = (time.perf_counter() - clock) / args.frames
        errors = [surface_error(fit.surface(f), truths[f]) for f in frames]
        metrics = [fit.fits[f].metrics for f in frames]
        volumes = [m["volume_ratio"] for m in metrics]
        lost = [100 * e.lost_limb_fraction for e in errors]
        print(json.dumps(options), f"{seconds:.2f} s per frame")
        print("  lost %     ", " ".join(f"{v:.1f}" for v in lost))
        print("  fit / hull ", " ".join(f"{a.mean / b.mean:.2f}" for a, b in zip(errors, hull_errors)))
        print("  unexplained", " ".join(f"{100 * m['unexplained'] / max(1, m['samples']):.1f}" for m in metrics))
        print(f"  worst lost {max(lost):.2f}% (frame {int(np.argmax(lost))}), frames lost {sum(v >= 5.0 for v in lost)}, "
              f"volume {min(volumes):.3f}-{max(volumes):.3f}, "
              f"fit / hull mean {np.mean([e.mean for e in errors]) / np.mean([e.mean for e in hull_errors]):.2f}")


if __name__ == "__main__":
    main()
