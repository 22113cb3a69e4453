"""Issue 17: the elastic fit keeps every limb on fast motion.

The synthetic fast-motion capture (``CapsuleFigure(motion="fast")``: an arm swinging across
the chest and a leg kicking, hands and feet moving 10-35 cm per frame) is rendered into 8
cameras with skew and distortion and carved into visual hulls; the model is built from
frame 0's hull and fitted through the sequence. Judged against the figure's true surface
with the lost-limb measure (:mod:`elastocap.elastic.measures`).

The coverage weight (2.0) was tuned on capture seed 1 at 1,000 nodes and hulls of 64 voxels
(1.0 left one frame at 5.8%, 3.0 and 4.0 at 5.0% and 5.9% with the volume up to 1.105);
this test runs seed 2, held out, at the size ``elastocap fit`` uses (2,500 nodes, 128
voxels). At 1,000 nodes and 64 voxels seed 2 keeps its limbs less well (worst frame 6.9%
with the term, 18.6% without): a limb is then about one node spacing thick.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from elastocap import ElasticModel, fit_sequence
from elastocap.elastic.measures import LOST_LIMB_FRACTION, surface_error
from elastocap.pipeline.hull import load_hull, run_hull_stage
from elastocap.synth import CapsuleFigure
from elastocap.synth.capture import write_synthetic_capture

SEED = 2
FRAMES = 14
# Volume within 5% of rest on every frame (issue 17, item 4).
VOLUME_RTOL = 0.05


@pytest.fixture(scope="module")
def fast_capture(tmp_path_factory: pytest.TempPathFactory) -> tuple[list, list]:
    root = tmp_path_factory.mktemp("fast")
    write_synthetic_capture(root, frames=FRAMES, seed=SEED, motion="fast", image_size=(640, 480), progress=False)
    run_hull_stage(root, root / "out", resolution=128, progress=False)
    hulls = [load_hull(root / "out", f) for f in range(FRAMES)]
    figure = CapsuleFigure(SEED, motion="fast")
    truths = [figure.mesh(f, spacing=0.02) for f in range(FRAMES)]
    return hulls, truths


def _lost(fit, truths: list) -> np.ndarray:
    return np.array([surface_error(fit.surface(f), truths[f]).lost_limb_fraction for f in range(len(truths))])


@pytest.fixture(scope="module")
def fits(fast_capture: tuple[list, list]) -> tuple:
    hulls, _ = fast_capture
    model = ElasticModel.from_mesh(hulls[0].mesh(), n_nodes=2500)
    return fit_sequence(model, hulls), fit_sequence(model, hulls, coverage=0.0)


def test_the_coverage_term_keeps_the_fast_limbs_that_the_fit_without_it_loses(
    fast_capture: tuple[list, list], fits: tuple
) -> None:
    _, truths = fast_capture
    with_term, without = fits
    kept, lost = _lost(with_term, truths), _lost(without, truths)
    print("lost-limb measure, % of the diagonal, with / without coverage:")
    print(np.round(100 * kept, 1), np.round(100 * lost, 1))
    assert kept.max() < LOST_LIMB_FRACTION
    # The fit before the term loses a limb here. How many frames it loses is chaotic: a
    # rounding-level change moves it (measured with the core's sums before they were ordered,
    # rust/ordered.rs: 5 frames, worst 14.9%; after: 1 frame at 5.8%, another at 4.97%), so the
    # contrast asserted is the worst frame and at least one lost frame.
    assert lost.max() > LOST_LIMB_FRACTION
    assert (lost >= LOST_LIMB_FRACTION).sum() >= 1
    # The fit reports how much of each hull's surface it leaves unexplained: little, once
    # the limbs are kept.
    unexplained = np.array([with_term.fits[f].metrics["unexplained"] / with_term.fits[f].metrics["samples"]
                            for f in range(1, FRAMES)])
    assert unexplained.max() < 0.2, unexplained


def test_the_volume_stays_within_five_percent_of_rest(fits: tuple) -> None:
    with_term, _ = fits
    volumes = np.array([with_term.fits[f].metrics["volume_ratio"] for f in range(FRAMES)])
    assert np.all(np.abs(volumes - 1) < VOLUME_RTOL), volumes
