"""The rigid residuals' leave-one-out fits in the core (elastocap._core.track_rigid_held_out):
the same fits, to the bit, as rigid_fits of every set gathered once per neighbour left out
(the numpy formulation they replace in rigidity.rigid_residuals)."""

import numpy as np
import pytest

from elastocap._core import InvalidInputError, rigid_fits, track_rigid_held_out


def _gathered_fits(a, b, weight, min_others):
    """The formulation of rigidity.rigid_residuals before the core did it: (M, K, 3, 3) and
    (M, K, 3), NaN where no fit."""
    m, k = weight.shape
    w = np.repeat(weight[:, None, :], k, axis=1) * (1.0 - np.eye(k))[None]
    ok = (weight > 0) & (w.sum(axis=2) >= min_others)
    r = np.full((m, k, 3, 3), np.nan)
    t = np.full((m, k, 3), np.nan)
    if ok.any():
        i, j = np.nonzero(ok)
        r[i, j], t[i, j] = rigid_fits(np.ascontiguousarray(a[i]), np.ascontiguousarray(b[i]), np.ascontiguousarray(w[i, j]))
    return r, t


def _sets(rng, m, k):
    a = rng.normal(0, 0.1, (m, k, 3)) + rng.normal(0, 1, (m, 1, 3))
    angle = rng.uniform(-0.3, 0.3, m)
    c, s = np.cos(angle), np.sin(angle)
    r = np.zeros((m, 3, 3))
    r[:, 0, 0], r[:, 0, 1], r[:, 1, 0], r[:, 1, 1], r[:, 2, 2] = c, -s, s, c, 1.0
    b = np.einsum("mij,mkj->mki", r, a) + rng.normal(0, 0.05, (m, 1, 3)) + rng.normal(0, 0.003, (m, k, 3))
    weight = (rng.random((m, k)) < 0.6).astype(np.float64)
    weight[0] = 0.0
    weight[1, :3] = 1.0
    weight[1, 3:] = 0.0
    return a, b, weight


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_fits_are_the_gathered_ones_to_the_bit(seed):
    rng = np.random.default_rng(seed)
    a, b, weight = _sets(rng, 300, 16)
    r, t = track_rigid_held_out(a, b, weight, min_others=3.0)
    re, te = _gathered_fits(a, b, weight, 3.0)
    assert r.shape == (300, 16, 3, 3) and t.shape == (300, 16, 3)
    assert np.array_equal(r.view(np.uint64), re.view(np.uint64))
    assert np.array_equal(t.view(np.uint64), te.view(np.uint64))
    # No neighbour chosen, or only three (two left without one): no fit.
    assert np.isnan(t[:2]).all()
    # A near-rigid motion: each left-out neighbour is predicted to about the noise.
    miss = np.linalg.norm(np.einsum("mkij,mkj->mki", r, a) + t - b, axis=2)
    assert np.nanmedian(miss) < 0.02


def test_an_outlier_is_missed_by_its_offset():
    rng = np.random.default_rng(5)
    a, b, _ = _sets(rng, 2, 8)
    a, b = a[1:], b[1:].copy()
    b[0, 4] += [0.3, 0.0, 0.0]
    r, t = track_rigid_held_out(a, b, np.ones((1, 8)), min_others=3.0)
    miss = np.linalg.norm(np.einsum("mkij,mkj->mki", r, a) + t - b, axis=2)[0]
    assert miss[4] > 0.2
    assert np.all(np.delete(miss, 4) < miss[4])


def test_bad_input_refused():
    a = np.zeros((2, 4, 3))
    with pytest.raises(InvalidInputError, match="shape"):
        track_rigid_held_out(a, np.zeros((2, 5, 3)), np.ones((2, 4)), min_others=3.0)
    with pytest.raises(InvalidInputError, match="shape"):
        track_rigid_held_out(a, a, np.ones((2, 3)), min_others=3.0)
    with pytest.raises(InvalidInputError, match="NaN"):
        track_rigid_held_out(a, a, np.ones((2, 4)), min_others=float("nan"))
    r, t = track_rigid_held_out(np.zeros((0, 4, 3)), np.zeros((0, 4, 3)), np.zeros((0, 4)), min_others=3.0)
    assert r.shape == (0, 4, 3, 3) and t.shape == (0, 4, 3)
