"""framefast2 (issue 15's speed line): the tracked frame's pieces made cheaper, each held
to the code it replaced, to the bit: the rows' NaN-ignoring median
(:func:`~elastocap.tracking.rigidity.nanmedian_rows`) and the z-buffer's grid in the core
(``_core.track_occluded``) against scipy's k-d tree."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from elastocap._core import InvalidInputError, track_occluded
from elastocap.tracking.rigidity import nanmedian_rows


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**31), m=st.integers(0, 40), k=st.integers(0, 20), nan=st.floats(0, 1),
       rounded=st.booleans(), inf=st.booleans())
@example(seed=0, m=3, k=1, nan=1.0, rounded=False, inf=False)
@example(seed=1, m=5, k=8, nan=0.5, rounded=True, inf=True)
def test_nanmedian_rows_equals_numpy(seed: int, m: int, k: int, nan: float, rounded: bool, inf: bool) -> None:
    rng = np.random.default_rng(seed)
    values = rng.normal(size=(m, k)) * 10 ** rng.uniform(-3, 3)
    if rounded:
        values = np.round(values, 1)  # ties
    if inf:
        values[rng.random((m, k)) < 0.2] = np.inf
    values[rng.random((m, k)) < nan] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        expected = np.nanmedian(values, axis=1) if k else np.full(m, np.nan)
    got = nanmedian_rows(values)
    assert got.shape == (m,)
    assert np.array_equal(np.isnan(got), np.isnan(expected))
    assert np.array_equal(got[~np.isnan(got)].view(np.uint64), expected[~np.isnan(expected)].view(np.uint64))


def occluded_by_tree(ouv, odepth, uv, threshold, radius, nearest):
    """The former z-buffer test (visibility.predicted_visible with scipy's tree)."""
    k_near = min(nearest, len(odepth))
    dist, near = cKDTree(ouv).query(uv, k=k_near, distance_upper_bound=radius)
    dist, near = dist.reshape(-1, k_near), near.reshape(-1, k_near)
    hit = np.isfinite(dist)
    return (np.where(hit, odepth[np.minimum(near, len(odepth) - 1)], np.inf) < threshold[:, None]).any(axis=1)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), o=st.integers(1, 600), q=st.integers(0, 400), span=st.floats(5, 200),
       radius=st.sampled_from([0.5, 3.0, 6.0]), nearest=st.sampled_from([1, 3, 12]), whole=st.booleans())
@example(seed=0, o=1, q=1, span=5.0, radius=6.0, nearest=12, whole=True)
@example(seed=2, o=500, q=300, span=10.0, radius=6.0, nearest=12, whole=False)  # crowded
def test_the_core_z_buffer_equals_the_tree(seed: int, o: int, q: int, span: float, radius: float, nearest: int,
                                           whole: bool) -> None:
    rng = np.random.default_rng(seed)
    ouv = rng.uniform(-10, span, (o, 2))
    if whole:
        ouv = np.round(ouv)  # distances exactly at the radius
    odepth = rng.uniform(1, 3, o)
    uv = rng.uniform(0, span, (q, 2))
    if whole:
        uv = np.round(uv)
    threshold = rng.uniform(1, 3, q)
    got = track_occluded(ouv, odepth, uv, threshold, radius=radius, nearest=nearest)
    assert got.dtype == np.bool_ and got.shape == (q,)
    if q:
        # Where two occluders tie at the nearest-th place (whole pixels), the tree's choice
        # among them is its own: compared elsewhere (projections of tracked points do not
        # tie to the bit).
        d2 = ((uv[:, None] - ouv[None]) ** 2).sum(axis=2)
        d2 = np.sort(np.where(d2 < radius * radius, d2, np.inf), axis=1)
        if d2.shape[1] > nearest:
            untied = ~np.isfinite(d2[:, nearest]) | (d2[:, nearest - 1] != d2[:, nearest])
        else:
            untied = np.ones(q, bool)
        expected = occluded_by_tree(ouv, odepth, uv, threshold, radius, nearest)
        assert np.array_equal(got[untied], expected[untied])
        if not whole:
            assert untied.all()


def test_the_core_z_buffer_refuses_bad_input() -> None:
    ouv, d = np.zeros((3, 2)), np.zeros(3)
    with pytest.raises(InvalidInputError):
        track_occluded(ouv, d[:2], np.zeros((1, 2)), np.zeros(1), radius=6.0, nearest=12)
    with pytest.raises(InvalidInputError):
        track_occluded(ouv, d, np.zeros((1, 2)), np.zeros(2), radius=6.0, nearest=12)
    with pytest.raises(InvalidInputError):
        track_occluded(ouv, d, np.zeros((1, 2)), np.zeros(1), radius=-1.0, nearest=12)
    with pytest.raises(InvalidInputError):
        track_occluded(np.zeros((3, 3)), d, np.zeros((1, 2)), np.zeros(1), radius=6.0, nearest=12)
    assert not track_occluded(ouv, d, np.zeros((1, 2)), np.ones(1), radius=6.0, nearest=0).any()
