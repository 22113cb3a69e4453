"""The global pose search's front/back stage (:func:`elastocap.body.search.search_pose`),
on a constructed fit and score: the facing that explains the observations best after the
middle stage is not always the right one; the right one wins only once its limbs are
restarted (a walking figure's elbows and knees bend one way only)."""

from __future__ import annotations

import numpy as np

from elastocap.body import BodyModel, BodyState
from elastocap.body.search import search_pose

MODEL = BodyModel.default_human()
ELBOW = MODEL.motion_names.index("l_forearm.0")


def _facing(heading: float) -> float:
    """Distance of ``heading`` from the true facing (0), radians."""
    return abs((heading + np.pi) % (2 * np.pi) - np.pi)


def test_the_other_facing_is_refined_and_wins_when_it_explains_better() -> None:
    calls = {"fits": 0}

    def fit(state: BodyState, shape, iterations: int, rays) -> BodyState:
        # A fit that stays where it starts: the scores below decide everything.
        calls["fits"] += 1
        return state

    def score(state: BodyState) -> tuple[float, float]:
        heading = _facing(float(state.motion[3]))
        if heading < 0.2:
            # The right facing: poor with the elbow straight, best with it bent.
            return (0.005 if state.motion[ELBOW] > 0.3 else 0.02), 0.9
        if heading > np.pi - 0.2:
            # Facing backwards: better than the right facing with its elbow straight,
            # never better than that.
            return 0.01, 0.9
        return 0.05, 0.5

    state = search_pose(MODEL, np.zeros(3), np.ones(MODEL.n_shape), fit, score, fit_shape=False, headings=8)
    # Before the front/back stage the search kept refining only the middle stage's best,
    # the backward facing (score 0.01), and returned it.
    assert _facing(float(state.motion[3])) < 0.2
    assert state.motion[ELBOW] > 0.3
    assert score(state)[0] == 0.005


def test_a_search_without_an_opposite_facing_keeps_its_best() -> None:
    """Every heading but the true one explains nothing: the result is the true facing, as
    before the front/back stage."""

    def fit(state: BodyState, shape, iterations: int, rays) -> BodyState:
        return state

    def score(state: BodyState) -> tuple[float, float]:
        return (0.001, 1.0) if _facing(float(state.motion[3])) < 0.2 else (0.05, 0.2)

    state = search_pose(MODEL, np.array([0.1, -0.2, 0.9]), np.ones(MODEL.n_shape), fit, score, fit_shape=False, headings=8)
    assert _facing(float(state.motion[3])) < 0.2
    assert np.allclose(state.motion[:3], [0.1, -0.2, 0.9])
