"""BodyModel: the default human, the JSON description (round trip, malformed files),
forward kinematics, the skin mesh and the silhouette."""

from __future__ import annotations

import json

import numpy as np
import pytest

from body_scenes import random_state, z_up_cameras
from elastocap import InvalidInputError
from elastocap.body import SKIN_LEVEL, BodyModel, BodyState

MODEL = BodyModel.default_human()


def test_default_human_has_the_issues_size_and_proportions() -> None:
    description = MODEL.to_dict()
    balls = sum(len(p["balls"]) for p in description["parts"])
    assert 14 <= len(MODEL.part_names) <= 18
    assert 30 <= balls <= 60
    assert (MODEL.lower < MODEL.upper).all()
    state = MODEL.rest_state(position=(0, 0, 0.95))
    lower, upper = MODEL.skin_mesh(state, spacing=0.015).bounds
    assert 1.6 < upper[2] - lower[2] < 1.95  # standing height, metres
    assert -0.05 < lower[2] < 0.08  # feet on the floor


def test_pose_frames_are_rotations_and_the_root_sits_at_its_translation() -> None:
    rng = np.random.default_rng(0)
    state = random_state(MODEL, rng)
    rotations, origins = MODEL.pose(state)
    np.testing.assert_allclose(rotations @ np.swapaxes(rotations, 1, 2), np.broadcast_to(np.eye(3), rotations.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rotations), 1.0, atol=1e-12)
    np.testing.assert_allclose(origins[0], state.motion[:3], atol=1e-15)


def test_length_coefficient_scales_the_bone() -> None:
    state = MODEL.rest_state()
    thigh = MODEL.part_names.index("l_thigh")
    shin = MODEL.part_names.index("l_shin")
    shape = state.shape.copy()
    shape[4 * thigh] = 1.2
    _, before = MODEL.pose(state)
    _, after = MODEL.pose(state.replace(shape=shape))
    bone = np.linalg.norm(before[shin] - before[thigh])
    np.testing.assert_allclose(np.linalg.norm(after[shin] - after[thigh]), 1.2 * bone, rtol=1e-12)


def test_save_and_load_round_trip(tmp_path) -> None:
    path = tmp_path / "human.json"
    MODEL.save(path)
    loaded = BodyModel.load(path)
    assert loaded.to_dict() == MODEL.to_dict()
    rng = np.random.default_rng(1)
    state = random_state(MODEL, rng)
    points = rng.normal([0, 0, 1], 0.3, (100, 3))
    np.testing.assert_array_equal(loaded.field(points, state)[0], MODEL.field(points, state)[0])


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda d: d.pop("parts"), "parts"),
        (lambda d: d["parts"][1].update(parent="l_hand"), "parent"),
        (lambda d: d["parts"][1]["joints"][0].update(axis=[0, 0, 0]), "axis"),
        (lambda d: d["parts"][0]["balls"][0].update(radii=[0.1, -0.1, 0.1]), "radii"),
        (lambda d: d["parts"][0].update(rest=[[1, 0, 0], [0, 1, 0], [0, 0, 2]]), "rest"),
        (lambda d: d["parts"][2].update(name="pelvis"), "unique"),
        (lambda d: d["parts"][0]["balls"][0].update(center=[0, "a", 0]), "center"),
        (lambda d: d["parts"][1]["joints"][0].update(limits=[10, -10]), "limits"),
    ],
)
def test_malformed_descriptions_raise_naming_the_fault(tmp_path, edit, match: str) -> None:
    description = MODEL.to_dict()
    edit(description)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(description))
    with pytest.raises(InvalidInputError, match=match):
        BodyModel.load(path)


def test_unreadable_file_raises(tmp_path) -> None:
    path = tmp_path / "bad.json"
    path.write_text("{ not json")
    with pytest.raises(InvalidInputError, match="cannot read"):
        BodyModel.load(path)
    with pytest.raises(InvalidInputError, match="cannot read"):
        BodyModel.load(tmp_path / "missing.json")


def test_state_of_the_wrong_length_raises() -> None:
    with pytest.raises(InvalidInputError, match="state.motion"):
        MODEL.field(np.zeros((1, 3)), BodyState(np.ones(MODEL.n_shape), np.zeros(3)))
    with pytest.raises(InvalidInputError, match="shape coefficients"):
        MODEL.field(np.zeros((1, 3)), BodyState(np.zeros(MODEL.n_shape), np.zeros(MODEL.n_motion)))


def test_skin_mesh_is_closed_outward_and_on_the_level_set() -> None:
    state = random_state(MODEL, np.random.default_rng(2))
    mesh = MODEL.skin_mesh(state, spacing=0.015)
    assert mesh.is_watertight and mesh.volume > 0
    values = MODEL.field(mesh.vertices, state)[0]
    # marching cubes interpolates linearly along cell edges: a few percent of T
    assert np.abs(values - SKIN_LEVEL).max() < 0.1
    points = MODEL.skin_points(state, 200, seed=2, spacing=0.015)
    np.testing.assert_allclose(MODEL.field(points, state)[0], SKIN_LEVEL, atol=1e-12)


def test_silhouette_contains_the_projected_skin_and_no_more() -> None:
    state = random_state(MODEL, np.random.default_rng(3))
    camera = z_up_cameras(2)[0]
    mask = MODEL.silhouette(state, camera)
    points = MODEL.skin_points(state, 3000, seed=3, spacing=0.015)
    uv, depth = camera.project(points)
    assert (depth > 0).all()
    pixels = np.round(uv).astype(int)
    # every skin point projects into the mask or onto its one-pixel border
    from scipy.ndimage import binary_dilation

    assert binary_dilation(mask)[pixels[:, 1], pixels[:, 0]].all()
    # and the mask is not larger than the projected skin (one-pixel border aside)
    hull = np.zeros_like(mask)
    hull[pixels[:, 1], pixels[:, 0]] = True
    covered = binary_dilation(hull, iterations=3)
    assert (mask & ~covered).sum() <= 0.01 * mask.sum()


def _joint_moves(state, joint: str, angle: float, part: str, base: str) -> np.ndarray:
    motion = state.motion.copy()
    motion[MODEL.motion_names.index(joint)] = angle
    _, origins = MODEL.pose(state.replace(motion=motion))
    _, rest = MODEL.pose(state)
    i, j = MODEL.part_names.index(part), MODEL.part_names.index(base)
    return (origins[i] - origins[j]) - (rest[i] - rest[j])


def test_limbs_bend_the_way_a_persons_do_on_both_sides() -> None:
    """Inside the joint limits, elbows and hips swing the limb forward (the way the toes and
    the face point), knees bend back; both sides alike (the right elbow and the knees were
    mirrored once, so the model could not fit a walking figure)."""
    state = MODEL.rest_state()
    centres, _ = MODEL.ball_centers(state)
    toes = centres[MODEL.ball_part == MODEL.part_names.index("l_foot")].mean(axis=0)
    forward = np.sign(toes[1] - MODEL.pose(state)[1][MODEL.part_names.index("l_foot")][1])
    head = centres[MODEL.ball_part == MODEL.part_names.index("head")]
    assert np.sign(head[-1, 1] - head[0, 1]) == forward
    for side in "lr":
        names = MODEL.motion_names

        def inside(joint: str) -> tuple[float, float]:
            k = names.index(joint)
            return float(MODEL.lower[k]), float(MODEL.upper[k])

        lo, hi = inside(f"{side}_forearm.0")
        bend = hi if abs(hi) > abs(lo) else lo
        assert _joint_moves(state, f"{side}_forearm.0", 0.8 * bend, f"{side}_hand", f"{side}_forearm")[1] * forward > 0.1
        lo, hi = inside(f"{side}_shin.0")
        bend = hi if abs(hi) > abs(lo) else lo
        assert _joint_moves(state, f"{side}_shin.0", 0.5 * bend, f"{side}_foot", f"{side}_shin")[1] * forward < -0.1
        lo, hi = inside(f"{side}_thigh.0")
        flex = hi if abs(hi) > abs(lo) else lo
        assert _joint_moves(state, f"{side}_thigh.0", 0.5 * flex, f"{side}_shin", f"{side}_thigh")[1] * forward > 0.1
