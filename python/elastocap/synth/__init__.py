"""Synthetic captures with ground truth, for the demo, the tests and the benches: the
capsule figure and the body figure in motion, a ring of cameras with skew and distortion,
the capture writer, and the textured stereo capture with ground-truth depth and surface
points.

Only the demo, the command line and tests import this package (checked by the import
contracts in pyproject.toml)."""

from elastocap.synth.capsules import CapsuleFigure
from elastocap.synth.body import BodyFigure
from elastocap.synth.capture import render_background, ring_rig, write_synthetic_capture
from elastocap.synth.textured import load_textured_truth, stereo_rig, write_textured_capture

__all__ = [
    "BodyFigure",
    "CapsuleFigure",
    "load_textured_truth",
    "render_background",
    "ring_rig",
    "stereo_rig",
    "write_synthetic_capture",
    "write_textured_capture",
]
