"""The body fit as a tracker (issue 16): joint angles recovered from stereo points and
silhouettes over consecutive frames; a frame far from its predecessor found again by the
global search; a subject the model cannot explain refused; frames with missing input;
BVH written and read back with bvhio."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from body_scenes import z_up_cameras
from elastocap import InvalidInputError
from elastocap.body import BodyModel, BodyObservations, BodyState
from elastocap.body.bvh import write_bvh
from elastocap.body.lost import LOST_DROP, LOST_PRIOR_SPREAD
from elastocap.body.track import BodyTracker, FrameQuality, limb_length_groups, lost_threshold, narrow_shape_family, track_body
from elastocap.render import render_silhouette
from elastocap.synth.body import BodyFigure

MODEL = BodyModel.default_human()
CAMERAS = z_up_cameras(6, width=320, height=240)


def observe(state: BodyState, *, points: int = 1500, seed: int = 0, cameras=CAMERAS) -> BodyObservations:
    mesh = MODEL.skin_mesh(state, spacing=0.01)
    rng = np.random.default_rng(seed)
    skin = MODEL.skin_points(state, points, seed=seed, spacing=0.015) + rng.normal(0, 0.002, (points, 3))
    return BodyObservations(points=skin, masks=[render_silhouette(mesh, c) for c in cameras])


def angles_rms(fit: BodyState, truth: BodyState) -> float:
    return float(np.degrees(np.sqrt(np.mean((fit.motion[6:] - truth.motion[6:]) ** 2))))


LIMB_JOINTS = [MODEL.part_names.index(f"{s}_{p}") for s in "lr" for p in ("forearm", "hand", "shin", "foot")]


def joint_errors(fit: BodyState, truth: BodyState) -> np.ndarray:
    """Errors of the elbows, wrists, knees and ankles, metres."""
    return np.linalg.norm(MODEL.pose(fit)[1][LIMB_JOINTS] - MODEL.pose(truth)[1][LIMB_JOINTS], axis=1)


def joint_error(fit: BodyState, truth: BodyState) -> float:
    return float(joint_errors(fit, truth).max())


def test_tracker_recovers_joint_angles_from_stereo_and_silhouettes() -> None:
    figure = BodyFigure(5)
    truths = [figure.state(f) for f in range(4)]
    track = track_body(MODEL, [observe(s, seed=f) for f, s in enumerate(truths)], cameras=CAMERAS, window=3)
    assert track.searched[0] and not any(track.searched[1:])
    for fit, truth in zip(track.states, truths):
        # (angles about a straight limb's own axis are barely observable: positions are)
        errors = joint_errors(fit, truth)
        assert np.sqrt(np.mean(errors**2)) < 0.02 and errors.max() < 0.04
        assert angles_rms(fit, truth) < 12.0
    assert np.abs(track.shape / figure.shape - 1).max() < 0.05
    assert all(np.array_equal(s.shape, track.shape) for s in track.states)
    # with points the full family: tapers and depths fitted, not held or tied
    per_part = track.shape.reshape(-1, 4)
    assert (per_part[:, 3] != 1.0).any() and (per_part[:, 2] != per_part[:, 1]).any()
    # ... and each limb's segments share one length (the foot its own)
    names = MODEL.part_names
    for side in "lr":
        arm = {per_part[names.index(f"{side}_{p}"), 0] for p in ("upperarm", "forearm", "hand")}
        leg = {per_part[names.index(f"{side}_{p}"), 0] for p in ("thigh", "shin")}
        assert len(arm) == 1 and len(leg) == 1
        assert per_part[names.index(f"{side}_foot"), 0] != per_part[names.index(f"{side}_shin"), 0]


@pytest.mark.parametrize("symmetric", [False, True])
def test_the_narrow_family_ties_depth_to_width_and_holds_the_taper(symmetric: bool) -> None:
    base = MODEL.mirrored_shape_groups() if symmetric else np.arange(MODEL.n_shape)
    groups, (lower, upper) = narrow_shape_family(MODEL, base)
    per_part, base_part = groups.reshape(-1, 4), base.reshape(-1, 4)
    assert np.array_equal(np.unique(groups), np.arange(groups.max() + 1))  # numbered 0..G-1
    assert np.array_equal(per_part[:, 2], per_part[:, 1])
    # nothing else merged: lengths, widths and tapers keep the base's partition
    for k in (0, 1, 3):
        same = base_part[:, k][:, None] == base_part[:, k][None, :]
        assert np.array_equal(per_part[:, k][:, None] == per_part[:, k][None, :], same)
    assert len(set(per_part[:, 0]) & set(per_part[:, 1])) == 0 and len(set(per_part[:, 1]) & set(per_part[:, 3])) == 0
    assert np.array_equal(lower.reshape(-1, 4)[:, 3], np.ones(len(per_part))) and np.array_equal(upper.reshape(-1, 4)[:, 3], np.ones(len(per_part)))
    assert (lower.reshape(-1, 4)[:, :3] == 0.5).all() and (upper.reshape(-1, 4)[:, :3] == 2.0).all()


@pytest.mark.parametrize("symmetric", [False, True])
def test_limb_length_groups_tie_each_limbs_segments_and_nothing_else(symmetric: bool) -> None:
    base = MODEL.mirrored_shape_groups() if symmetric else np.arange(MODEL.n_shape)
    groups = limb_length_groups(MODEL, base)
    assert np.array_equal(np.unique(groups), np.arange(groups.max() + 1))
    per_part, base_part = groups.reshape(-1, 4), base.reshape(-1, 4)
    names = MODEL.part_names
    chains = [[f"{s}_{p}" for p in chain] for s in "lr" for chain in (("upperarm", "forearm", "hand"), ("thigh", "shin"))]
    expected = base_part[:, 0].copy()
    for chain in chains:
        ids = [names.index(n) for n in chain]
        assert len(set(per_part[ids, 0])) == 1
        for i in ids[1:]:
            expected[expected == expected[i]] = expected[ids[0]]
    # lengths merge only along the chains (the mirror's ties kept), the rest as the base
    assert np.array_equal(per_part[:, 0][:, None] == per_part[:, 0][None, :], expected[:, None] == expected[None, :])
    for k in (1, 2, 3):
        same = base_part[:, k][:, None] == base_part[:, k][None, :]
        assert np.array_equal(per_part[:, k][:, None] == per_part[:, k][None, :], same)
    assert groups.max() + 1 == base.max() + 1 - (3 if symmetric else 6)


def test_with_masks_alone_the_shape_fit_keeps_the_knees_and_elbows_where_the_outline_puts_them() -> None:
    """Masks alone, the shape fit ties each limb's segment lengths and holds the shape
    near 1: a start whose knees and elbows sat 7-13 cm along straight limbs (thighs and
    upper arms long, shins and forearms short, the outline nearly the same) comes back to
    the true joints. With each segment's length free the outline does not say where one
    segment ends and the next begins, and they stay ~3 cm off (the capsule figure's
    frame-0 shape fit slid its knees 13-21 cm so, ``benches/README.md``, branch body11)."""
    truth = MODEL.rest_state()
    masks = [render_silhouette(MODEL.skin_mesh(truth, spacing=0.01), c) for c in CAMERAS]
    names = MODEL.part_names
    slid = truth.shape.copy().reshape(-1, 4)
    for side in "lr":
        for part, length in (("thigh", 1.3), ("shin", 0.75), ("upperarm", 1.25), ("forearm", 0.8)):
            slid[names.index(f"{side}_{part}"), 0] = length
    start = BodyState(slid.reshape(-1), truth.motion)
    joints = [names.index(f"{side}_{part}") for side in "lr" for part in ("shin", "forearm")]

    def shape_fit(**options: object) -> np.ndarray:
        tracker = BodyTracker(MODEL, cameras=CAMERAS, window=1, **options)  # type: ignore[arg-type]
        tracker.resume(BodyObservations(masks=masks), start)  # the window's shape fit on this frame
        return np.linalg.norm(MODEL.pose(tracker.result().states[0])[1][joints] - MODEL.pose(truth)[1][joints], axis=1)

    assert np.linalg.norm(MODEL.pose(start)[1][joints] - MODEL.pose(truth)[1][joints], axis=1).min() > 0.07
    assert shape_fit().max() < 0.01
    assert shape_fit(tie_limb_lengths=False, sigma_shape_masks=None).min() > 0.02


@pytest.mark.parametrize("seed", [6, 8])
def test_the_first_frame_search_puts_each_leg_on_its_own_data(seed: int) -> None:
    """Figures whose legs the search once swapped (a leg settled on the other leg's data,
    knees 17-24 cm and ankles 37-42 cm off, ~92% of the observations explained)."""
    truth = BodyFigure(seed).state(0)
    track = track_body(MODEL, [observe(truth)], cameras=CAMERAS)
    errors = joint_errors(track.states[0], truth)
    assert errors.max() < 0.02, errors
    assert track.quality[0].explained > 0.98


def test_a_frame_far_from_its_predecessor_is_found_by_the_global_search() -> None:
    figure = BodyFigure(5)
    truths = [figure.state(f) for f in range(3)]
    jumped = truths[-1].motion.copy()
    jumped[:2] += (0.25, -0.2)
    jumped[3] += np.radians(150)
    truths.append(BodyState(figure.shape, jumped))
    tracker = BodyTracker(MODEL, cameras=CAMERAS, window=2)
    for f, truth in enumerate(truths):
        tracker.update(observe(truth, seed=f))
    track = tracker.result()
    assert track.searched[-1]
    assert joint_error(track.states[-1], truths[-1]) < 0.04


#: Explained shares of the capsule figure's masks-only track, tuning seed 2, frames 0-9
#: (all tracked well, skin 16-20 mm), and of frame 10, where the left arm had drifted
#: (skin 23 mm, joints 93 mm RMS) with the median ray distance still 3 mm.
SEED2_SHARES = [0.843, 0.831, 0.859, 0.853, 0.838, 0.845, 0.849, 0.844, 0.854, 0.875]
SEED2_DRIFTED = 0.809


def test_the_lost_test_measures_a_drop_against_the_recent_frames_spread() -> None:
    """The fixed drop of 0.1 let seed 2's frame 10 pass (and the track fall to 36 mm skin
    in frame 11 before a search); the drop measured against the recent spread catches it
    and passes every frame of the well-tracked run."""
    below = lost_threshold(SEED2_SHARES)
    assert SEED2_DRIFTED < below
    assert all(share >= below for share in SEED2_SHARES)
    # a track whose share wanders as much is not lost for that drop
    noisy = [0.80, 0.90, 0.82, 0.88, 0.78, 0.92, 0.84, 0.86, 0.81, 0.89]
    assert SEED2_DRIFTED >= lost_threshold(noisy)
    # never less than LOST_DROP below the recent frames' upper quartile, however steady
    assert lost_threshold([0.9] * 10) == pytest.approx(0.9 - LOST_DROP)
    assert lost_threshold([0.9] * 5 + [0.91] * 5) == pytest.approx(0.91 - LOST_DROP)
    # few frames: their upper quartile less three prior spreads; none: 0.9
    assert lost_threshold([0.85, 0.86]) == pytest.approx(0.8575 - 3 * LOST_PRIOR_SPREAD)
    assert lost_threshold([]) == 0.9
    # the tracker reads it from its observed frames only
    tracker = BodyTracker(MODEL, cameras=CAMERAS)
    for share in SEED2_SHARES:
        tracker._append(None, None, FrameQuality(0.003, share, 4000), searched=False, observed=True)  # type: ignore[arg-type]
    tracker._append(None, None, FrameQuality(0.0, 0.2, 0), searched=False, observed=False)  # type: ignore[arg-type]
    assert tracker._lost(FrameQuality(0.003, SEED2_DRIFTED, 4000))
    assert not tracker._lost(FrameQuality(0.003, 0.835, 4000))
    assert tracker._lost(FrameQuality(0.02, 0.9, 4000))  # farther than lost_distance


def test_the_first_tracked_frames_are_lost_for_a_drop_a_held_track_does_not_make() -> None:
    """Frames 1-3 have too few predecessors to measure a spread; a prior spread stands in
    for it. Seed 2's frames 1-3, each against the frames before it, are not lost; seed 2's
    drifted share (0.809, a 0.03-0.05 drop) right after frame 0 or 1 is. Before, those
    frames were lost only 0.1 below their predecessors' median (0.74-0.75 here), so a drift
    that costs a few percent of the rays went on for up to three frames (the capsule
    figure's seed 11: frames 1-2 at 19 and 24 mm skin before frame 3's search)."""
    for f in range(1, 4):
        assert SEED2_SHARES[f] >= lost_threshold(SEED2_SHARES[:f])
    for f in range(1, 4):
        assert SEED2_DRIFTED < lost_threshold(SEED2_SHARES[:f])
    tracker = BodyTracker(MODEL, cameras=CAMERAS)
    tracker._append(None, None, FrameQuality(0.003, SEED2_SHARES[0], 4000), searched=True, observed=True)  # type: ignore[arg-type]
    assert tracker._lost(FrameQuality(0.003, SEED2_DRIFTED, 4000))
    assert not tracker._lost(FrameQuality(0.003, SEED2_SHARES[1], 4000))


def test_a_lost_frame_is_searched_from_the_last_held_frame_too() -> None:
    """The search of a lost frame starts also from the last frame the track held (not a
    lost one whose search found nothing better), its root moved with the data's centre."""
    tracker = BodyTracker(MODEL, cameras=CAMERAS)
    rng = np.random.default_rng(0)
    states = []
    for f, held in enumerate((True, True, False)):
        motion = MODEL.rest_state().motion.copy()
        motion[MODEL.motion_names.index("l_upperarm.1")] = 0.2 * f
        states.append(BodyState(np.ones(MODEL.n_shape), motion))
        points = rng.normal(0, 0.1, (50, 3)) + [0.1 * f, 0, 1]
        frame = tracker._prepare(BodyObservations(points=points), f)
        tracker._append(frame, states[-1], FrameQuality(0.003, 0.9, 50), searched=False, observed=True, held=held)
    now = tracker._prepare(BodyObservations(points=rng.normal(0, 0.1, (50, 3)) + [0.5, 0, 1]), 3)
    (start,) = tracker._held_start(now)
    # frame 1's pose (frame 2 was lost), moved by the centres' difference
    assert np.allclose(start.motion[3:], states[1].motion[3:])
    shift = now.centre() - tracker._frames[1].centre()
    assert np.allclose(start.motion[:3], states[1].motion[:3] + shift)
    assert 0.35 < shift[0] < 0.45


def test_a_subject_the_model_cannot_explain_is_refused() -> None:
    """A four-legged animal (a horizontal barrel on legs, a neck and a head)."""
    parts = [trimesh.creation.capsule(0.9, 0.22).apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))]
    for x in (-0.4, 0.4):
        for y in (-0.15, 0.15):
            parts.append(trimesh.creation.capsule(0.6, 0.06).apply_translation([x, y, -0.3]))
    parts.append(trimesh.creation.capsule(0.4, 0.08).apply_translation([0.75, 0, 0.35]))
    animal = trimesh.util.concatenate(parts).apply_translation([0.0, 0.0, 0.8])
    masks = [render_silhouette(animal, c) for c in CAMERAS]
    points = animal.sample(1500, seed=1)
    with pytest.raises(InvalidInputError, match="cannot explain"):
        track_body(MODEL, [BodyObservations(points=points, masks=masks)], cameras=CAMERAS)


def test_missing_input_frames_and_cameras() -> None:
    figure = BodyFigure(7)
    truths = [figure.state(f) for f in range(3)]
    first = observe(truths[0])
    # no stereo points, and one camera without a mask
    masks_only = observe(truths[1])
    masks_only = BodyObservations(masks=[None] + list(masks_only.masks[1:]))
    tracker = BodyTracker(MODEL, cameras=CAMERAS, window=3)
    tracker.update(first)
    tracker.update(masks_only)
    # nothing at all: the prediction is kept and the frame marked unobserved
    tracker.update(BodyObservations(masks=[None] * len(CAMERAS)))
    track = tracker.result()
    assert track.observed == [True, True, False]
    assert joint_error(track.states[1], truths[1]) < 0.04
    with pytest.raises(InvalidInputError, match="first frame has no observations"):
        BodyTracker(MODEL, cameras=CAMERAS).update(BodyObservations())
    with pytest.raises(InvalidInputError, match="one camera per mask"):
        BodyTracker(MODEL, cameras=CAMERAS).update(BodyObservations(masks=first.masks[:2]))


def test_bvh_reads_back_with_bvhio(tmp_path) -> None:
    bvhio = pytest.importorskip("bvhio")
    from elastocap.body.model import Z_UP_TO_WORLD

    figure = BodyFigure(3)
    states = [figure.state(f) for f in range(4)]
    path = write_bvh(tmp_path / "take.bvh", MODEL, figure.shape, states, 30.0)
    root = bvhio.readAsHierarchy(str(path))
    joints = [item[0] for item in root.layout() if item[0].Name in MODEL.part_names]
    assert sorted(j.Name for j in joints) == sorted(MODEL.part_names)
    for f, state in enumerate(states):
        root.loadPose(f)
        _, origins = MODEL.pose(state)
        world = origins @ Z_UP_TO_WORLD.T
        for joint in joints:
            assert np.allclose(np.array(joint.PositionWorld), world[MODEL.part_names.index(joint.Name)], atol=1e-5)
    with pytest.raises(InvalidInputError, match="fps"):
        write_bvh(tmp_path / "bad.bvh", MODEL, figure.shape, states, 0.0)


def test_the_first_frame_search_finds_the_capsule_figure() -> None:
    """The capsule figure (not the body model) of the clutter scene, seed 1 (a tuning seed),
    frame 0, from its 8 true silhouettes: with the shape free during the pose search, the
    search settled with the left forearm halved and its hand doubled (wrist 19 cm off,
    elbows, wrists, knees, ankles 78 mm RMS); holding the shape while the pose is searched
    and tying left to right: 23 mm RMS, every joint within 4 cm."""
    from elastocap.body.model import Z_UP_TO_WORLD
    from elastocap.synth.clutter import ClutterScene

    scene = ClutterScene(1, cameras=8, size=(480, 360))
    surface = scene.figure.mesh(0, 0.01)
    cameras = [c.replace(R=c.R @ Z_UP_TO_WORLD) for c in scene.rig.cameras]
    tracker = BodyTracker(MODEL, cameras=cameras, symmetric=True)
    state = tracker.update(BodyObservations(masks=[render_silhouette(surface, c) for c in scene.rig.cameras]))
    origins = MODEL.pose(state)[1] @ Z_UP_TO_WORLD.T
    truth = scene.joints(0)
    parts = {"elbow": "forearm", "wrist": "hand", "knee": "shin", "ankle": "foot"}
    errors = np.array([np.linalg.norm(origins[MODEL.part_names.index(f"{s}_{p}")] - truth[f"{s}_{j}"]) for j, p in parts.items() for s in "lr"])
    assert np.sqrt(np.mean(errors**2)) < 0.035 and errors.max() < 0.06, errors
    names = MODEL.part_names
    for part in ("forearm", "hand", "shin", "foot"):
        i, j = names.index(f"l_{part}"), names.index(f"r_{part}")
        assert np.array_equal(state.shape[4 * i : 4 * i + 4], state.shape[4 * j : 4 * j + 4])


def test_a_lost_frame_keeps_its_tracked_fit_unless_the_search_scores_clearly_better(monkeypatch) -> None:
    """The search of a lost frame starts from the tracked fit too, and its result replaces
    the tracked fit only when the search's own score (not another measure) is lower by
    REPLACE_MARGIN. Before, a result that explained a larger share replaced it whatever
    its score (the capsule figure's seed 16, frame 18: the result kept was 33 mm from the
    true skin)."""
    from elastocap.body import track as track_module

    rng = np.random.default_rng(1)
    tracked = MODEL.rest_state(position=(0.0, 0.0, 1.0))
    other = tracked.replace(motion=tracked.motion + 0.1)
    for found_score, replaced in ((0.0100 * (1 - track_module.REPLACE_MARGIN) * 1.01, False), (0.0100 * (1 - track_module.REPLACE_MARGIN) * 0.99, True)):
        tracker = BodyTracker(MODEL, cameras=CAMERAS)
        frame = tracker._prepare(BodyObservations(points=rng.normal(0, 0.1, (50, 3)) + [0, 0, 1]), 0)
        tracker._append(frame, tracked, FrameQuality(0.003, 0.9, 50), searched=True, observed=True)
        seen: dict[str, object] = {}

        def search(frame, shape, *, fit_shape, starts=()):
            seen["starts"] = list(starts)
            # the search's result explains MORE than the tracked fit in every case
            return other, FrameQuality(0.003, 0.99, 50)

        class Fit:
            states = [tracked]

        monkeypatch.setattr(tracker, "_fit", lambda *a, **k: Fit())
        monkeypatch.setattr(tracker, "_lost", lambda quality: True)
        monkeypatch.setattr(tracker, "search", search)
        monkeypatch.setattr(tracker, "score", lambda state, frame: (found_score if state is other else 0.0100, 0.9))
        state = tracker.update(BodyObservations(points=rng.normal(0, 0.1, (50, 3)) + [0, 0, 1]))
        assert (state is other) == replaced
        assert tracker._searched[-1] == replaced
        # the tracked fit was among the search's starts
        assert any(s is tracked for s in seen["starts"])  # type: ignore[attr-defined]
