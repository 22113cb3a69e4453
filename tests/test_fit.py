"""Fitting the elastic model through a sequence (issue 5): accuracy against the hulls,
rigid tracking, self-intersection, resume, bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

import elastocap
from elastocap import ElasticModel, InvalidInputError, SelfIntersection, fit_sequence, run_fit_stage
from elastocap.pipeline.fit import load_model
from elastocap.pipeline.hull import load_hull
from elastocap.synth.capture import write_synthetic_capture
from data_paths import HORSE
from tolerances import (
    FIT_HULL_VOXELS,
    FIT_RESUME_RTOL,
    FIT_RIGID_ENERGY_RTOL,
    FIT_RIGID_FLOOR_RTOL,
    FIT_TIP_ON_LIMB_VOXELS,
    FIT_VOLUME_RTOL,
)


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fit") / "capture"
    return write_synthetic_capture(out, frames=4, cameras=8, spacing=0.02, image_size=(320, 240), progress=False)


@pytest.fixture(scope="module")
def fitted(capture: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fit") / "out"
    run_fit_stage(capture, out, n_nodes=900, resolution=96, progress=False)
    return out


def test_fitted_surfaces_hug_the_hulls_with_one_topology(fitted: Path) -> None:
    model, rest = load_model(fitted)
    assert rest == 0
    faces = None
    for frame in range(4):
        hull = load_hull(fitted, frame)
        mesh = trimesh.load(fitted / "fit" / f"{frame:06d}.ply", process=False)
        if faces is None:
            faces = mesh.faces
        np.testing.assert_array_equal(mesh.faces, faces)
        distance = np.abs(hull.sdf().sample(mesh.vertices))
        assert distance.mean() < FIT_HULL_VOXELS * hull.grid.spacing, (frame, distance.mean(), hull.grid.spacing)
        assert abs(mesh.volume / model.surface.volume - 1) < FIT_VOLUME_RTOL
    metrics = json.loads((fitted / "metrics.json").read_text())
    assert metrics["summary"]["frames"] == 4
    assert {f["frame"] for f in metrics["frames"]} == {0, 1, 2, 3}


def test_resume_refits_only_missing_frames_and_gives_the_same_result(capture: Path, fitted: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    shutil.copytree(fitted, out)
    for frame in (2, 3):
        (out / "fit" / f"{frame:06d}.ply").unlink()
        (out / "fit" / f"{frame:06d}.npz").unlink()
    kept = (out / "fit" / "000001.npz").stat().st_mtime_ns
    run_fit_stage(capture, out, progress=False)
    assert (out / "fit" / "000001.npz").stat().st_mtime_ns == kept
    for frame in (2, 3):
        with np.load(fitted / "fit" / f"{frame:06d}.npz") as a, np.load(out / "fit" / f"{frame:06d}.npz") as b:
            np.testing.assert_allclose(b["positions"], a["positions"], rtol=0, atol=FIT_RESUME_RTOL * 10)


CAPSULE = trimesh.creation.capsule(height=1.0, radius=0.25, count=[24, 24])


def _rigid_sequence(poisson: float = 0.3) -> tuple[ElasticModel, list[trimesh.Trimesh]]:
    model = ElasticModel.from_mesh(CAPSULE, n_nodes=700, rotation="warped", poisson=poisson)
    targets = []
    for step in range(4):
        moved = CAPSULE.copy()
        turn = Rotation.from_euler("xz", [12 * step, 8 * step], degrees=True).as_matrix()
        transform = np.eye(4)
        transform[:3, :3] = turn
        transform[:3, 3] = [0.05 * step, -0.03 * step, 0.02 * step]
        moved.apply_transform(transform)
        targets.append(moved)
    return model, targets


def test_rigid_motion_stays_unstrained_with_the_coverage_term() -> None:
    # The coverage term pulls a displaced start hard; its pulls vanish once the surface is in
    # place. A frame's iteration stops on the whole objective (elastic energy included), so
    # the strain the pulls left relaxes: measured 0.05% of a 5% stretch's energy on the first
    # rotated frame (11% when the iteration stopped on the data terms alone, after 2
    # iterations).
    model, targets = _rigid_sequence()
    fit = fit_sequence(model, targets)
    stretch = model.energy(model.nodes * 1.05)
    for frame in fit.frames:
        assert fit.fits[frame].metrics["elastic_energy"] < FIT_RIGID_ENERGY_RTOL * stretch, frame


def test_rigid_motion_is_tracked_without_elastic_energy() -> None:
    # The corotational mode: measured on this sequence, the paper's rhs mode accumulates
    # strain with each rotation step (1.3% -> 36% of a 5% stretch's energy over 5 steps)
    # while the warped mode stays at the rest frame's level (voxel rounding of the target).
    # At the Poisson ratio these figures were measured at (from_mesh's default is now 0.48,
    # where the warped mode ends at 2.1x the rest frame's energy: voxel rounding of the
    # target costs more in a nearly incompressible model).
    # The elastic model alone (no coverage term: see the test above).
    model, targets = _rigid_sequence()
    fit = fit_sequence(model, targets, coverage=0.0)
    stretch = model.energy(model.nodes * 1.05)
    rest = fit.fits[0].metrics["elastic_energy"]
    for frame in fit.frames:
        metrics = fit.fits[frame].metrics
        assert metrics["elastic_energy"] < FIT_RIGID_ENERGY_RTOL * stretch, (frame, metrics)
        assert metrics["elastic_energy"] < 2.0 * rest + FIT_RIGID_FLOOR_RTOL * stretch, (frame, metrics)
        assert abs(metrics["volume_ratio"] - 1) < FIT_VOLUME_RTOL
        assert metrics["mean_distance"] < 0.02  # the target grid is 1/100 of the capsule's length


def two_blocks(gap: float) -> trimesh.Trimesh:
    """Two 0.4 x 0.4 x 1 blocks side by side along x with `gap` between them; for a negative
    gap (overlapping blocks) their union, one block."""
    if gap <= 0:
        return trimesh.creation.box(extents=[0.8 + gap, 0.4, 1.0])
    left = trimesh.creation.box(extents=[0.4, 0.4, 1.0])
    left.apply_translation([-(0.2 + gap / 2), 0, 0])
    right = trimesh.creation.box(extents=[0.4, 0.4, 1.0])
    right.apply_translation([0.2 + gap / 2, 0, 0])
    return trimesh.util.concatenate([left, right])


def test_self_intersection_term_keeps_limbs_apart() -> None:
    # Two limbs at rest 0.3 apart, pushed together until the hull is one block 0.6 wide: the
    # limbs (0.8 together) must flatten against each other or pass through each other.
    # Without held contacts the term's contacts alternate between iterations, so the count
    # depends on the node layout: the median over four layouts (node seeds) is asserted.
    targets = [two_blocks(gap) for gap in (0.3, 0.1, -0.1, -0.2)]
    last = []
    for seed in range(4):
        model = ElasticModel.from_mesh(two_blocks(0.3), n_nodes=900, rotation="warped", seed=seed)
        held = fit_sequence(model, targets, self_intersection=SelfIntersection(hold=True))
        on = fit_sequence(model, targets, self_intersection=SelfIntersection())
        off = fit_sequence(model, targets, self_intersection=None)
        counts = [
            (off.fits[f].metrics["penetrating"], on.fits[f].metrics["penetrating"], held.fits[f].metrics["penetrating"])
            for f in on.frames
        ]
        print("penetrating surface nodes per frame (off, on, on + held contacts):", counts)
        assert counts[0] == (0, 0, 0)
        assert held.fits[3].metrics["volume_ratio"] > 1 - FIT_VOLUME_RTOL
        last.append(counts[-1])
    last_off, last_on, last_held = np.median(np.array(last, dtype=float), axis=0)
    # Measured (seeds 0-3; about 580 surface nodes): 151 / 166 / 152 / 141 without the term,
    # 107 / 100 / 40 / 29 with it, 3 / 4 / 4 / 2 when contacts are held for the frame (with
    # the voxelised node placement before: 157 / 139 / 107 / 150, 57 / 75 / 40 / 51, 20 / 5 /
    # 12 / 22).
    assert last_off >= 100
    assert last_on <= 0.65 * last_off
    assert last_held <= 0.2 * last_off


LEGS_GRID = elastocap.Grid([-0.5, -0.9, -0.8], 0.02, (51, 61, 81))
LEG_GAP, LEG_LENGTH, LEG_WIDTH = 0.4, 0.6, 0.1


def _leg_occupancy(side: int, swing: float) -> np.ndarray:
    """Voxels of one leg, 0.1 x 0.6 x 0.1, hanging from its hip at x = side * 0.25 and swung
    back by `swing` degrees about the x axis."""
    p = LEGS_GRID.centers() - [side * (LEG_GAP + LEG_WIDTH) / 2, 0.0, 0.0]
    c, s = np.cos(np.radians(swing)), np.sin(np.radians(swing))
    local = np.stack([p[..., 0], c * p[..., 1] + s * p[..., 2], c * p[..., 2] - s * p[..., 1]], axis=-1)
    half = LEG_WIDTH / 2
    return np.all((local >= [-half, -LEG_LENGTH, -half]) & (local <= [half, 0.05, half]), axis=-1)


def _two_legs(swing: float) -> elastocap.Hull:
    """A block (the hips) with two legs 0.4 apart; the left one swung by `swing` degrees."""
    p = LEGS_GRID.centers()
    reach = LEG_GAP / 2 + LEG_WIDTH + 0.05
    hips = np.all((p >= [-reach, 0.0, -0.1]) & (p <= [reach, 0.2, 0.1]), axis=-1)
    return elastocap.Hull(hips | _leg_occupancy(-1, swing) | _leg_occupancy(1, 0.0), LEGS_GRID)


@pytest.mark.xfail(
    reason="layout-sensitive: with the node layouts of seeds 0-3 the tip stays on its leg for "
    "one of four, before the exact node placement (seed 0; tip median 0.147 / 0.172 / 0.148 off "
    "its leg for seeds 1-3) and after it (seed 2; 0.20 / 0.21 / 0.19 for seeds 0, 1, 3); to be "
    "made robust in the fit's invalidation, not by choosing a seed. Since the core's sums are "
    "ordered (rust/ordered.rs) the fit is the same on any thread count, and with seed 0's layout "
    "it now passes on all (it passed or failed by thread count before): luck of rounding, not "
    "robustness, so the mark stays",
    strict=False,
)
def test_invalidation_keeps_a_fast_swung_limb_tip_on_its_own_limb() -> None:
    # The left leg swings back by 75 degrees between two frames. Where its tip was, the
    # nearest target surface is the other leg (0.35 away, the swung leg 0.53): without
    # invalidation the tip's nodes associate with the right leg and are dragged towards it;
    # with it, those associations collide with the right leg's own and are dropped, and the
    # tip follows its leg.
    swing = 75.0
    model = ElasticModel.from_mesh(_two_legs(0.0).mesh(), n_nodes=800, rotation="warped")
    targets = [_two_legs(0.0), _two_legs(swing)]
    rest = model.nodes
    tip = np.flatnonzero((rest[:, 0] < 0) & (rest[:, 1] < -LEG_LENGTH + 0.1))
    assert len(tip) >= 10
    own = elastocap.SDF.from_occupancy(_leg_occupancy(-1, swing), LEGS_GRID)
    other = elastocap.SDF.from_occupancy(_leg_occupancy(1, 0.0), LEGS_GRID)
    figures = {}
    # The coverage term (issue 17) pulls the tip back into its leg as well: without
    # invalidation it alone keeps the tip 0.07 off its leg, so it is off for the contrast.
    for invalidate in (True, False):
        x = fit_sequence(model, targets, invalidate=invalidate, coverage=2.0 if invalidate else 0.0).fits[1].positions[tip]
        figures[invalidate] = (float(np.median(own.sample(x))), float(np.median(other.sample(x))))
    print("tip median distance to (its leg, the other leg), invalidation and coverage on / off:", figures)
    h = LEGS_GRID.spacing
    on_own, on_other = figures[True]
    off_own, off_other = figures[False]
    assert abs(on_own) < FIT_TIP_ON_LIMB_VOXELS * h
    assert on_other > 0.3  # nowhere near the other leg (the swung tip is 0.57 from it)
    # Without invalidation and coverage the tip leaves its leg towards the other one
    # (measured 0.078 off its leg, 0.31 from the other; with both 0.036 and 0.36).
    assert off_own > 3 * h
    assert off_other < on_other - 0.04


def test_bad_input_is_a_clear_error(capture: Path, tmp_path: Path) -> None:
    model = ElasticModel.from_mesh(CAPSULE, n_nodes=300)
    with pytest.raises(InvalidInputError, match="rest_frame"):
        fit_sequence(model, [CAPSULE], rest_frame=3)
    with pytest.raises(InvalidInputError, match="empty"):
        fit_sequence(model, [])
    empty = elastocap.Hull(np.zeros((8, 8, 8), bool), elastocap.Grid([0, 0, 0], 0.1, (8, 8, 8)))
    with pytest.raises(InvalidInputError, match="empty"):
        fit_sequence(model, [CAPSULE, empty])
    planar = ElasticModel.from_mask(np.pad(np.ones((20, 20), bool), 5), n_nodes=100, k=8)
    with pytest.raises(InvalidInputError, match="2-D model fits to masks"):
        fit_sequence(planar, [CAPSULE])
    with pytest.raises(InvalidInputError, match="rest frame 99"):
        run_fit_stage(capture, tmp_path / "out", rest_frame=99, progress=False)
    with pytest.raises(InvalidInputError, match="stiffness"):
        fit_sequence(model, [CAPSULE], stiffness=-1.0)


def test_an_empty_hull_frame_stops_the_fit_after_handing_over_the_frames_before_it() -> None:
    # Bad input, "nothing lost": the frames fitted before the empty one reach the callback
    # (elastocap fit writes them there), then the error names the problem.
    model = ElasticModel.from_mesh(CAPSULE, n_nodes=300)
    empty = elastocap.Hull(np.zeros((8, 8, 8), bool), elastocap.Grid([0, 0, 0], 0.1, (8, 8, 8)))
    handed: list[int] = []
    with pytest.raises(InvalidInputError, match="hull is empty"):
        fit_sequence(model, [CAPSULE, CAPSULE, empty], callback=lambda fit: handed.append(fit.frame))
    assert handed == [0, 1]


@pytest.mark.skipif(not HORSE.exists(), reason="shared data not present")
def test_horse_gallop_first_frames_fit_as_closely_as_the_hulls(monkeypatch: pytest.MonkeyPatch) -> None:
    # The first frames of issue 5's evaluation (benches/eval_horse.py, which runs all 48 and
    # the peer): 8 virtual cameras, hulls, a model of frame 0's hull, fit, ground truth.
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "benches"))
    eval_horse = __import__("eval_horse")
    monkeypatch.setattr(eval_horse, "SAMPLES", 10_000)
    monkeypatch.setattr(eval_horse, "HORSE", HORSE)
    result = eval_horse.evaluate(4, 1500, stiffness=1.0, peer=False, log=lambda *_: None)
    summary = result["summary"]
    print({key: summary[key] for key in ("fit_over_hull", "fit_drift_pct", "volume_ratio_min", "volume_ratio_max")})
    assert summary["fit_over_hull"] <= 1.2
    assert summary["volume_ratio_min"] > 1 - FIT_VOLUME_RTOL and summary["volume_ratio_max"] < 1 + FIT_VOLUME_RTOL
    assert summary["fit_drift_pct"] <= 2.0


def test_targets_keyed_by_frame_numbers_give_results_keyed_by_them() -> None:
    # Capture frame numbers with gaps: the same fit as the sequence, under the frame
    # numbers (never a mix of numbers and list positions).
    model = ElasticModel.from_mesh(CAPSULE, n_nodes=300)
    moved = []
    for step in range(3):
        target = CAPSULE.copy()
        target.apply_translation([0.03 * step, 0.0, 0.0])
        moved.append(target)
    by_position = fit_sequence(model, moved, rest_frame=1)
    by_number = fit_sequence(model, {10: moved[0], 12: moved[1], 17: moved[2]}, rest_frame=12)
    assert by_number.frames == [10, 12, 17] and by_number.rest_frame == 12
    for position, number in zip((0, 1, 2), (10, 12, 17)):
        assert by_number.fits[number].frame == number
        np.testing.assert_array_equal(by_number.fits[number].positions, by_position.fits[position].positions)
    with pytest.raises(InvalidInputError, match="rest_frame = 11 is not a frame"):
        fit_sequence(model, {10: moved[0], 12: moved[1]}, rest_frame=11)
    with pytest.raises(InvalidInputError, match="keyed by int frame numbers"):
        fit_sequence(model, {"a": moved[0]}, rest_frame=0)


def test_the_volume_term_holds_the_volume_against_a_target_that_lost_it() -> None:
    # A carved hull gains and loses phantom volume as limbs meet and part; the body keeps
    # its own. A compressible capsule (Poisson 0.3) fitted to itself shrunk by 10% (volume
    # 0.73 of rest) follows the target without the term and keeps its volume with it.
    # Measured: 0.850 without, 0.896 at weight 1, 0.947 at 4 (the default); at Poisson 0.48
    # 0.936 / 0.947 / 0.966.
    model = ElasticModel.from_mesh(CAPSULE, n_nodes=700, rotation="warped", poisson=0.3)
    shrunk = CAPSULE.copy()
    shrunk.apply_scale(0.9)
    without = fit_sequence(model, [CAPSULE, shrunk], volume=0.0).fits[1].metrics
    held = fit_sequence(model, [CAPSULE, shrunk]).fits[1].metrics
    print("volume ratio without / with the term:", without["volume_ratio"], held["volume_ratio"])
    assert without["volume_ratio"] < 0.88
    assert held["volume_ratio"] > without["volume_ratio"] + 0.07
