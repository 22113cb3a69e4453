"""Issue 15, session 22 (branch trackfit10): the stiff first stage of a frame
(``fit_sequence(stiff_stage=StiffStage(stiffness=, frames=))``).

A limb's first step from the rest frame has no motion to predict it from: the frame starts
at the rest pose. When the limb moved by much of its own width, the surface term meets it
locally (each surface node pulled to its nearest target surface) and the soft elastic model
lets the limb's material slide along the limb instead of turning it: the surface ends on
the target, the material points do not (benches/README.md, trackfit10: seed 25's frame 1,
the left shin's and foot's material 8.5 / 10.6% of the diagonal off). A first stage at a
much higher stiffness turns the limb as a whole; the frame's own fit then places the
surface from there."""

from __future__ import annotations

import numpy as np
import pytest
from test_fit import LEG_GAP, LEG_WIDTH, LEGS_GRID, _leg_occupancy, _two_legs

import elastocap
from elastocap import ElasticModel, InvalidInputError, StiffStage, fit_sequence

SWING = 60.0


def _swung_leg(seed: int) -> tuple[ElasticModel, np.ndarray, np.ndarray]:
    """The two-legged block (tests/test_fit.py) at rest, its model, the left leg's nodes
    below the hips and their true positions after the leg swung back by ``SWING`` degrees
    about its hip."""
    model = ElasticModel.from_mesh(_two_legs(0.0).mesh(), n_nodes=800, rotation="warped", seed=seed)
    rest = model.nodes
    leg = np.flatnonzero((rest[:, 0] < 0) & (rest[:, 1] < -0.1))
    hip = np.array([-(LEG_GAP + LEG_WIDTH) / 2, 0.0, 0.0])
    c, s = np.cos(np.radians(SWING)), np.sin(np.radians(SWING))
    p = rest[leg] - hip
    # The inverse of _leg_occupancy's map from world to the swung leg's frame.
    true = hip + np.stack([p[:, 0], c * p[:, 1] - s * p[:, 2], s * p[:, 1] + c * p[:, 2]], axis=1)
    return model, leg, true


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_leg_swung_60_degrees_from_rest_keeps_its_material_with_the_stiff_stage(seed: int) -> None:
    """The left leg (0.6 long, 0.1 wide) swings back 60 degrees in the first frame after
    rest (the stage is on by default there). Without the stiff stage its nodes end
    0.11-0.12 (median) from where their material went, the surface on the leg's target; with
    a first stage at stiffness 10 they end 0.014-0.041 off (measured over the node layouts of
    seeds 0-3), the surface as close to the leg's target."""
    model, leg, true = _swung_leg(seed)
    targets = [_two_legs(0.0), _two_legs(SWING)]
    own = elastocap.SDF.from_occupancy(_leg_occupancy(-1, SWING), LEGS_GRID)
    figures = {}
    for stage in (None, 10.0):
        fit = fit_sequence(model, targets, stiff_stage=None if stage is None else StiffStage(stiffness=stage))
        x = fit.fits[1].positions
        figures[stage] = (float(np.median(np.linalg.norm(x[leg] - true, axis=1))),
                          float(np.median(np.abs(own.sample(x[leg])))))
        assert ("stiff_stage_iterations" in fit.fits[1].metrics) == (stage is not None)
        assert "stiff_stage_iterations" not in fit.fits[0].metrics
    print("leg nodes: median material error, median |distance| to the leg's target (default, stiff 10):", figures)
    assert figures[None][0] > 0.08  # the failure the stage is for
    assert figures[10.0][0] < 0.5 * figures[None][0]
    assert figures[10.0][1] <= figures[None][1] + LEGS_GRID.spacing


def test_the_stiff_stage_runs_on_the_first_frames_from_rest_or_on_all() -> None:
    """Rest frame 2 of five: with "first" (the default) only frames 1 and 3 (no motion
    prediction) get the stage, and the rest frame is the unstaged fit's to the bit;
    with "all" every frame but the rest frame does. Bad values are refused."""
    model = ElasticModel.from_mesh(_two_legs(0.0).mesh(), n_nodes=300, rotation="warped", seed=0)
    targets = [_two_legs(a) for a in (-10.0, -5.0, 0.0, 5.0, 10.0)]
    plain = fit_sequence(model, targets, rest_frame=2, stiff_stage=None)
    first = fit_sequence(model, targets, rest_frame=2)
    every = fit_sequence(model, targets, rest_frame=2, stiff_stage=StiffStage(stiffness=10.0, frames="all"))
    staged = {f for f in first.frames if "stiff_stage_iterations" in first.fits[f].metrics}
    assert staged == {1, 3}
    assert {f for f in every.frames if "stiff_stage_iterations" in every.fits[f].metrics} == {0, 1, 3, 4}
    np.testing.assert_array_equal(first.fits[2].positions, plain.fits[2].positions)
    for frame in (1, 3):
        assert np.abs(first.fits[frame].positions - plain.fits[frame].positions).max() > 0
    for bad in (dict(stiffness=0.0), dict(stiffness=float("nan")), dict(stiffness=-1.0), dict(frames="some")):
        with pytest.raises(InvalidInputError, match=f"StiffStage.{next(iter(bad))}"):
            StiffStage(**bad)  # type: ignore[arg-type]
    # The former keyword's value (a stiffness) is refused by type, naming the object.
    with pytest.raises(InvalidInputError, match="stiff_stage must be an elastocap.StiffStage or None"):
        fit_sequence(model, targets, stiff_stage=10.0)  # type: ignore[arg-type]
