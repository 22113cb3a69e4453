"""The global pose search of the body tracker (issue 16): :func:`search_pose`.

Silhouettes and points do not say which data belong to which limb, so a local fit started
upright at the wrong heading, or with the legs together while the subject strides, settles
in a wrong valley: a leg on the other leg's data, the heading a quarter turn off. The search
fits many starts briefly and keeps refining the ones that explain the observations best.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap.body.model import SHAPE_NAMES, BodyModel, BodyState
from elastocap.body.starts import BodyVolume, data_starts

__all__ = ["ARM_STARTS", "LEG_STARTS", "search_pose"]

#: Shoulder starts of the global search (left, right first shoulder angle, radians): both
#: hanging, both reaching forward, one forward and one back (a walk's swing).
ARM_STARTS = ((0.0, 0.0), (-1.0, -1.0), (-0.8, 0.8), (0.8, -0.8))
#: Hip starts (left, right first hip angle, radians): together, and a stride either way.
#: Started together, a leg of a striding subject often settles on the other leg's data.
LEG_STARTS = ((0.0, 0.0), (0.35, -0.35), (-0.35, 0.35))
#: The starts at each heading: each arm start with the legs together, each stride with the
#: arms hanging.
COARSE_STARTS = tuple((arms, LEG_STARTS[0]) for arms in ARM_STARTS) + tuple((ARM_STARTS[0], legs) for legs in LEG_STARTS[1:])
#: Coarse results carried on to the middle stage (each also turned by half a turn).
CARRIED = 4
#: Coarse results whose headings differ by less than this (radians) are one valley.
DISTINCT_HEADING = np.radians(30)

#: A middle-stage result whose heading differs from the best one's by more than this
#: (radians) faces the other way: it is refined beside the best (front and back).
OPPOSITE_HEADING = np.pi / 2

#: Limb restarts (first joint angle of the upper arm / thigh, radians).
ARM_SWINGS = (-1.0, -0.4, 0.4, 1.0)
LEG_SWINGS = (-0.3, 0.3, 0.9)
#: A result explaining this share of the observations is not restarted further, and the
#: other facing is not refined beside it.
WELL_EXPLAINED = 0.98
#: Passes of the limb restarts over the best facing (the first pass over each facing), and
#: the relative gain in score a pass must make for another to follow. On the capsule
#: figure's frame 0, masks alone (tuning seeds 2 and 13), the first pass improved the
#: score up to its last restart, and two more passes took the joints from 92 / 99 mm RMS
#: to 72 / 77 mm, for 41-45 CPU s instead of 25-28 (branch body9). On the held-out seeds
#: the passes did not carry over (frame 0, masks alone: seed 17 55.7 -> 53.6 mm, seed 18
#: unchanged, seed 16 107 -> 134 mm: a lower score, a worse pose), so one pass is the
#: default; set 3 to search further.
RESTART_PASSES = 1
PASS_GAIN = 0.02
#: With ``fit_shape``, this many of the search's best distinct candidates (by the score at
#: the held shape) are each fitted with the shape free, and the best-scored after that is
#: returned. The held shape (the model's own, on a first frame) is not the subject's, and
#: the ranking at it can be wrong where the ranking at the subject's shape is right: the
#: capsule figure's seed 17 with points, the true pose's valley scored 14.6 mm at the unit
#: shape against the winner's 13.0, and 6.6 against 8.5 once each had its shape fitted;
#: with 4 candidates 5 cm apart its frame 0 came out at 8.9 mm joints RMS (main: 63 mm;
#: 10 cm apart: 54 mm), and seed 8's at 18.7 mm (main: 182 mm), for 4 shape fits (+13-19%
#: CPU of the search; ``benches/README.md``, branch body12).
SHAPED_CANDIDATES = 4
#: Two candidates are distinct when some part's origin (a joint) lies farther than this
#: (metres) from where the other puts it: a limb on another valley, not the same pose
#: refined a little differently.
DISTINCT_POSE = 0.05
#: With ``fit_shape``: fit the shape to the middle stage's best, keep the trunk's
#: coefficients of it (the limbs' held) and run stages 1 and 2 again at that shape. At the
#: subject's shape the search finds the true pose where at the model's own it walks into
#: wrong valleys (the capsule figure, searched at the true valley's fitted shape: seed 16
#: masks alone 109 -> 20 mm joints RMS, seed 5 89 -> 19 mm, seed 8 with points 193 -> 15
#: mm); a wrong pose's fitted shape is wrong in the limbs that absorb its error (searched
#: at it, seed 16: 126 mm) and right in the trunk, which the heading and the root place
#: (at its trunk alone: 21 mm). Frame 0 with it, after the ranking at the fitted shape:
#: masks alone seed 16 94 -> 41 mm, 13 45 -> 19 mm, 5 82 -> 19 mm; with points seed 8
#: 18.7 -> 14.4 mm; +25-35% CPU (``benches/README.md``, branch body12).
TRUNK_SHAPE_FIRST = True
#: ... when some trunk coefficient moved by more than this: else the second pass would
#: search at nearly the same shape (the demo's body figure, the model itself: 0.98-1.02,
#: 11 more CPU s; the capsule figure's trunk: 0.56-0.89 at the true pose).
TRUNK_SHAPE_CHANGE = 0.1
#: With ``fit_shape`` and :data:`TRUNK_SHAPE_FIRST`: the overall sizes (every part's
#: length, width and depth times one number) at which the middle stage's best is refitted
#: (:data:`SCALE_ITERATIONS`, the shape held) and scored before the trunk's shape is
#: fitted; the best-scored size is the limbs' in the second pass. Empty: the limbs at 1.
#: Why: the capsule figure's frame 0 still started wrong after body12 on exactly the short
#: figures (1.63-1.67 m against the model's 1.75 m); searched at the true height's scale
#: (the limbs and trunk times 0.93), seed 28 with points went from 296 to 15 mm joints
#: RMS. One number, read from the middle stage's best even where that pose is wrong: on
#: the capsule seeds it read 0.92-1.0, never above the truth, and the demo's figure (the
#: model itself) 1.0; a pose half a turn off with its limbs bent the wrong way read 1.0
#: for a 0.92 subject, so a badly wrong middle stage gets no size (``benches/README.md``,
#: branch body13).
SCALE_PROBES: tuple[float, ...] = (0.92, 0.96, 1.0, 1.04)
SCALE_ITERATIONS = 30

#: fit(state, shape, iterations, rays) -> fitted state; shape None fits the shape too, rays
#: None uses all silhouette rays.
Fit = Callable[[BodyState, Any, int, int | None], BodyState]
#: score(state) -> (mean clipped distance of the observations from the skin, explained share)
Score = Callable[[BodyState], tuple[float, float]]


def search_pose(
    model: BodyModel,
    centre: NDArray[np.float64],
    shape: NDArray[np.float64],
    fit: Fit,
    score: Score,
    *,
    fit_shape: bool,
    headings: int,
    starts: Sequence[BodyState] = (),
    volume: BodyVolume | None = None,
) -> BodyState:
    """The state that best explains one frame, from a global search.

    1. Coarse: the root at ``centre``, upright, at ``headings`` headings times
       :data:`COARSE_STARTS`, each fitted 25 iterations on a subset of the observations
       with ``shape`` held, ranked by ``score`` (the observations' clipped distance from
       the skin; the fit's cost is no ranking: it counts only the observations the fit
       kept, and a fit in a wrong valley drops many).
    2. Middle: the :data:`CARRIED` best of distinct headings, and each turned by half a
       turn (front and back look alike), fitted 30 iterations on more observations; the
       best by ``score`` is fitted fully.
    3. Restarts, while observations stay unexplained: for the best of stage 2 and for the
       best facing the other way (:data:`OPPOSITE_HEADING`) each, the better one kept at
       the end (the other facing is skipped when the best explains
       :data:`WELL_EXPLAINED` of the observations): each limb alone from a few swings,
       straight and bent (an arm's raise kept, then zeroed), untwisted; the legs swapped
       and restarted together from each stride. A restart is kept when it explains the
       observations better. Then further passes of the restarts over the better facing,
       up to :data:`RESTART_PASSES` in all, while a pass lowers the score by
       :data:`PASS_GAIN`: a limb restarted while another was still wrong can find its
       valley once that one is right.

    With ``fit_shape`` and :data:`TRUNK_SHAPE_FIRST`, stages 1 and 2 run twice: at
    ``shape``, then at the trunk's coefficients of the shape fitted to the middle stage's
    best and the limbs' from ``shape`` times the subject's overall size (the one of
    :data:`SCALE_PROBES` at which the middle stage's best, refitted with the shape held,
    scores best); stages 3 and 4 follow from the second.

    ``starts`` are further states (the tracker passes the last frame it held) fitted in
    stage 2 beside the carried ones (not turned): a pose the coarse grid does not reach (an
    arm raised high, the legs far apart) is found from a frame where it was already
    right.

    ``volume`` (:func:`~elastocap.body.starts.body_volume`: the visual hull, or the points'
    voxels) adds the starts read from the data (:func:`~elastocap.body.starts.data_starts`:
    the heading from the trunk, the limbs from the volume's far points, assigned both
    ways), fitted in stage 2 like ``starts``: poses the fixed starts do not reach (a
    heading between two of the grid's, an arm twisted and raised) are started where the
    data put them, and the best score still decides.
    4. With ``fit_shape``, the shape is fitted last: from each of the
       :data:`SHAPED_CANDIDATES` best distinct candidates the search scored (a part's
       origin :data:`DISTINCT_POSE` apart), and the best-scored after its shape fit is
       returned (the best alone when it explains :data:`WELL_EXPLAINED`). The held shape
       is not the subject's, and a wrong pose can score better than the right one at it
       and worse once each has the subject's shape.

    Every pose stage holds ``shape``: a shape fitted while the pose is still wrong explains
    the pose's error (on the capsule figure, seed 1: a shin stretched to twice its length
    put the ankle 42 cm off; a forearm halved and its hand doubled put the wrist 19 cm off),
    and those wrong valleys then explain the observations better than the right pose with
    the shape held (``benches/README.md``, branch clutter3).
    """
    names = model.motion_names
    # Every candidate the search scores, kept for the ranking at the fitted shape (step 4).
    scored: list[tuple[float, BodyState]] = []

    def ranked(state: BodyState) -> tuple[float, float]:
        s = score(state)
        scored.append((s[0], state))
        return s

    def start(heading: float, motion: NDArray[np.float64] | None = None) -> BodyState:
        state = model.rest_state(position=centre).replace(shape=shape)
        if motion is not None:
            state = state.replace(motion=motion.copy())
        state.motion[3] = heading
        return state

    def set_angles(state: BodyState, angles: dict[str, float]) -> BodyState:
        motion = state.motion.copy()
        for name, angle in angles.items():
            if name in names:
                motion[names.index(name)] = angle
        return state.replace(motion=motion)

    def first_stages() -> list[tuple[tuple[float, float], BodyState]]:
        """Stages 1 and 2 at ``shape``: the middle stage's results, best first."""
        return _first_stages(model, shape, fit, ranked, start, set_angles, headings, [*starts, *data_starts(model, shape, volume)])

    middle = first_stages()
    if fit_shape and TRUNK_SHAPE_FIRST and middle[0][0][1] < WELL_EXPLAINED:
        # The subject's overall size first (one number, which a wrong pose bends little),
        # then the trunk's shape from the middle stage's best at that size, the limbs'
        # held at it, and stages 1 and 2 again at that shape: a wrong pose's fitted shape
        # is wrong in the limbs that explain its error, not in the trunk, which the
        # heading and the root place.
        size = _overall_scale(middle[0][1], shape, fit, score) if SCALE_PROBES else 1.0
        scaled = _scaled(shape, size)
        trunk = _trunk_coefficients(model)
        fitted = fit(middle[0][1].replace(shape=scaled), None, 60, None).shape
        if size != 1.0 or np.max(np.abs(fitted - shape)[trunk]) > TRUNK_SHAPE_CHANGE:
            shape = np.where(trunk, fitted, scaled)
            middle = first_stages()
    # Front and back: the best of the middle stage and the best facing the other way are
    # both refined fully, limb restarts included, and the one that then explains the
    # observations better is kept. A figure seen with its limbs nearly straight explains
    # its silhouettes almost as well facing backwards; which facing is right shows only
    # once each has its elbows and knees bent the way its joints allow, which the limb
    # restarts find.
    facings = [middle[0][1]]
    opposite = [m for m in middle if abs(_turn(m[1].motion[3] - facings[0].motion[3])) > OPPOSITE_HEADING]
    if opposite:
        facings.append(opposite[0][1])
    results: list[list[Any]] = []
    for init in facings:
        if results and results[0][0][1] >= WELL_EXPLAINED:
            # The best facing explains nearly every observation: the other facing has
            # nothing left to explain better (the demo's body figure: 0.986 against the
            # other facing's 0.81, whose 54 restarts cost 9 of the search's 24 CPU s).
            break
        state = fit(init, shape, 60, None)
        best: list[Any] = [ranked(state), state]

        _restart_limbs(model, best, set_angles, fit, ranked, shape)
        results.append(best)
    results.sort(key=lambda b: b[0][0])
    best = results[0]
    for _ in range(RESTART_PASSES - 1):
        # Each restart moves one limb (or the legs) with the rest held where the previous
        # restarts left them, so a limb restarted while another limb was still wrong may
        # have a better valley once that one is right: another pass from the improved
        # state, while a pass still improves the score.
        before = best[0][0]
        _restart_limbs(model, best, set_angles, fit, ranked, shape)
        if best[0][0] > (1 - PASS_GAIN) * before:
            break
    if not fit_shape:
        return best[1]
    if best[0][1] >= WELL_EXPLAINED:
        # nearly every observation explained at the held shape: no other valley to rank
        # (the demo's body figure, which is the model itself)
        return fit(best[1], None, 60, None)
    return _best_with_shape(model, scored, fit, score)


def _first_stages(
    model: BodyModel, shape: Any, fit: Fit, score: Score, start: Callable[..., BodyState], set_angles: Callable[..., BodyState], headings: int,
    starts: Sequence[BodyState],
) -> list[tuple[tuple[float, float], BodyState]]:
    """Stages 1 and 2 of :func:`search_pose` at ``shape``: the middle stage's results
    ``((score, explained), state)``, best first."""
    coarse = []
    for h in np.linspace(-np.pi, np.pi, headings, endpoint=False):
        for arms, legs in COARSE_STARTS:
            init = set_angles(start(h), {"l_upperarm.0": arms[0], "r_upperarm.0": arms[1], "l_thigh.0": legs[0], "r_thigh.0": legs[1]})
            found = fit(init, shape, 25, 1000)
            coarse.append((score(found)[0], found))
    coarse.sort(key=lambda c: c[0])
    carried: list[BodyState] = []
    for _, found in coarse:
        # distinct headings: the best few of one valley would crowd out the others
        if all(abs(_turn(found.motion[3] - c.motion[3])) > DISTINCT_HEADING for c in carried):
            carried.append(found)
        if len(carried) == CARRIED:
            break
    middle = []
    for found in carried:
        for init in (found, start(found.motion[3] + np.pi, found.motion)):
            state = fit(init, shape, 30, 1200)
            middle.append((score(state), state))
    for init in starts:
        state = fit(init.replace(shape=shape), shape, 30, 1200)
        middle.append((score(state), state))
    middle.sort(key=lambda m: m[0][0])
    return middle


def _scaled(shape: Any, size: float) -> NDArray[np.float64]:
    """``shape`` with every part's length, width and depth times ``size`` (its taper
    kept): the same body ``size`` times as large."""
    table = np.array(shape, dtype=np.float64).reshape(-1, len(SHAPE_NAMES))
    table[:, :3] *= size
    return table.reshape(-1)


def _overall_scale(state: BodyState, shape: Any, fit: Fit, score: Score) -> float:
    """The subject's overall size relative to ``shape``: of :data:`SCALE_PROBES`, the one
    at which ``state``'s pose, refitted with the shape held at it, scores best."""
    best = (np.inf, 0.0, 1.0)
    for size in SCALE_PROBES:
        scaled = _scaled(shape, size)
        refit = fit(state.replace(shape=scaled), scaled, SCALE_ITERATIONS, 1200)
        # a tie keeps the size nearest the held shape's
        best = min(best, (score(refit)[0], abs(size - 1.0), size))
    return best[2]


def _trunk_coefficients(model: BodyModel) -> NDArray[np.bool_]:
    """Which shape coefficients belong to the trunk and head (the parts not of a left or
    right limb)."""
    trunk = np.array([name[:2] not in ("l_", "r_") for name in model.part_names])
    return np.repeat(trunk, model.n_shape // len(model.part_names))


def _best_with_shape(model: BodyModel, scored: list[tuple[float, BodyState]], fit: Fit, score: Score) -> BodyState:
    """Step 4 of :func:`search_pose`: the :data:`SHAPED_CANDIDATES` best distinct of
    ``scored`` (``(score at the held shape, state)``), each fitted with the shape free
    (60 iterations, all observations), the best-scored after that returned."""
    chosen: list[tuple[BodyState, Any]] = []
    for _, state in sorted(scored, key=lambda c: c[0]):
        joints = model.pose(state)[1]
        # distinct: the best few of one valley would crowd out the others
        if all(np.max(np.linalg.norm(joints - other, axis=1)) > DISTINCT_POSE for _, other in chosen):
            chosen.append((state, joints))
        if len(chosen) == SHAPED_CANDIDATES:
            break
    fitted = [fit(state, None, 60, None) for state, _ in chosen]
    return min(fitted, key=lambda state: score(state)[0])


def _attempt(trial: BodyState, best: list[Any], fit: Fit, score: Score, shape: Any) -> None:
    """One limb restart: ``trial`` fitted and kept in ``best`` (``[(score, explained),
    state]``) when it scores better."""
    # Fitted 30 iterations in one go: scored after 10, restarts that became the best after
    # 30 were up to 1.3 times the best's score, and a margin that kept every winner (1.5)
    # would drop only 11-15 of 108 restarts (capsule seeds 2 and 12, frame 0; branch body8).
    refined = fit(trial, shape, 30, 1200)
    s = score(refined)
    if s[0] < best[0][0]:
        best[:] = [s, refined]


def _restart_limbs(model: BodyModel, best: list[Any], set_angles: Callable[..., BodyState], fit: Fit, score: Score, shape: Any) -> None:
    """Stage 3 of :func:`search_pose`: ``best`` is ``[(score, explained), state]``, updated
    by :func:`_attempt`."""
    names = model.motion_names

    def attempt(trial: BodyState) -> None:
        _attempt(trial, best, fit, score, shape)

    # Each limb alone: an arm twisted or swung the other way, a leg bent the wrong way.
    for side in ("l", "r"):
        for root, distal, swings in (("upperarm", "forearm", ARM_SWINGS), ("thigh", "shin", LEG_SWINGS)):
            for angle in swings:
                for bend, keep_raise in ((0.0, True), (0.0, False), (0.5, True), (0.5, False)) if root == "upperarm" else ((0.0, False), (0.5, False)):
                    if best[0][1] >= WELL_EXPLAINED:
                        return
                    angles: dict[str, float] = {f"{side}_{root}.{k}": (angle if k == 0 else 0.0) for k in range(3)}
                    if keep_raise:
                        # The arm's raise (second angle) is what the silhouettes pin down
                        # best; zeroed, a 30-iteration fit from the other swings and
                        # twists settles with the twist at a bound (synth seed 3).
                        angles.pop(f"{side}_{root}.1", None)
                    name = f"{side}_{distal}.0"
                    if name in names:
                        i = names.index(name)
                        lo, hi = model.lower[i], model.upper[i]
                        # part-way into the joint's range, whichever its sign
                        angles[name] = float((1 - bend) * np.clip(0.0, lo, hi) + bend * (lo if abs(lo) > abs(hi) else hi))
                    attempt(set_angles(best[1], angles))
    # Both legs: one leg on the other's data is not undone by moving one leg at a time.
    if best[0][1] < WELL_EXPLAINED:
        attempt(_legs_swapped(best[1], names))
    for legs in LEG_STARTS:
        for bends in ((0.0, 0.6), (0.6, 0.0), (0.3, 0.3)):
            if best[0][1] >= WELL_EXPLAINED:
                return
            angles = {}
            for side, hip, bend in zip("lr", legs, bends):
                angles.update({f"{side}_thigh.0": hip, f"{side}_thigh.1": 0.0, f"{side}_thigh.2": 0.0, f"{side}_shin.0": -bend, f"{side}_foot.0": 0.0})
            attempt(set_angles(best[1], angles))


def _turn(angle: float) -> float:
    """``angle`` wrapped into [-pi, pi)."""
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


def _legs_swapped(state: BodyState, names: list[str]) -> BodyState:
    """``state`` with the legs' angles exchanged (mirrored: the hips' y and z axes flip)."""
    motion = state.motion.copy()
    for joint, sign in (("thigh.0", 1), ("thigh.1", -1), ("thigh.2", -1), ("shin.0", 1), ("foot.0", 1)):
        left, right = f"l_{joint}", f"r_{joint}"
        if left in names and right in names:
            i, j = names.index(left), names.index(right)
            motion[i], motion[j] = sign * state.motion[j], sign * state.motion[i]
    return state.replace(motion=motion)
