"""The stages behind the command line (hull, fit, body), the demo, the report and its
pictures."""

from elastocap.pipeline.hull import load_hull, run_hull_stage
from elastocap.pipeline.fit import run_fit_stage
from elastocap.pipeline.body import run_body_stage

__all__ = ["load_hull", "run_body_stage", "run_fit_stage", "run_hull_stage"]
