"""Synthetic captures with ground truth, for the demo, the tests and the benches: the
capsule figure and the body figure in motion, a ring of cameras with skew and distortion,
the capture writer.

Only the demo, the command line and tests import this package (checked by the import
contracts in pyproject.toml)."""

from elastocap.synth.capsules import CapsuleFigure
from elastocap.synth.body import BodyFigure
from elastocap.synth.capture import render_background, ring_rig, write_synthetic_capture

__all__ = ["BodyFigure", "CapsuleFigure", "render_background", "ring_rig", "write_synthetic_capture"]
