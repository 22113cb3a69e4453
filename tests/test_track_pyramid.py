"""The young views' coarse-to-fine search (tracking/pyramid_search.py): a patch moved 30-50
px between two frames is lost by the step's 6 px box and found coarse to fine; a repeated
print puts a look-alike in the wide box, and the peak guard refuses it; bad settings are
refused."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from elastocap.tracking.depth_weights import rust_step
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.pyramid_search import box_scores, check_options, coarse_peaks, pooled, pyramid, pyramid_search

OPTIONS = dict(size=15, min_correlation=0.75, box_correlation=0.5, forward_backward=0.6, min_texture=0.0,
               max_iterations=8)
COARSE = dict(level=2, radius=15, coarse_size=7, coarse_correlation=0.5, exclusion=2.0, margin=0.1)


def _texture(shape: tuple[int, int], seed: int, period: int | None = None) -> np.ndarray:
    """A print with detail at 3-12 px (it survives two pyrDowns); with ``period`` it repeats
    every ``period`` pixels along x."""
    rng = np.random.default_rng(seed)
    h, w = shape
    width = period if period is not None else w
    base = np.zeros((h, width), np.float32)
    for sigma, gain in ((1.5, 0.5), (3.0, 1.0), (6.0, 1.0)):
        noise = rng.normal(size=(h, width)).astype(np.float32)
        base += gain * gaussian_filter(noise, sigma, mode="wrap")
    if period is not None:
        base = np.tile(base, (1, w // period + 1))[:, :w]
    base = (base - base.min()) / (base.max() - base.min())
    return np.ascontiguousarray(40.0 + 180.0 * base, dtype=np.float32)


def _shifted(image: np.ndarray, shift: tuple[float, float]) -> np.ndarray:
    """``image`` moved by ``shift`` (dx, dy) pixels (content at p goes to p + shift)."""
    m = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
    return np.ascontiguousarray(cv2.warpAffine(image, m, image.shape[::-1], flags=cv2.INTER_LINEAR,
                                               borderMode=cv2.BORDER_REFLECT), dtype=np.float32)


def _points() -> np.ndarray:
    """(N, 1, 2) young views well inside a 480 x 640 image."""
    u, v = np.meshgrid(np.arange(200.0, 441.0, 40.0), np.arange(160.0, 321.0, 40.0))
    return np.stack([u.ravel(), v.ravel()], axis=1)[:, None, :]


def _lost_by_the_step(previous: np.ndarray, current: np.ndarray, last: np.ndarray):
    step = rust_step([previous], [current])
    before = np.full_like(last, np.nan)
    uv, flags, cov, corr = step(last, before, weights=None, radius=6, **{k: v for k, v in OPTIONS.items()
                                                                           if k not in ("box_correlation",)})
    weak = (flags == TrackFlag.TRACKED) & ~(corr >= OPTIONS["min_correlation"])
    flags[weak] = TrackFlag.LOW_CORRELATION
    return uv, flags, cov, corr, before


def _search(previous, current, last, before, uv, flags, cov, corr, **coarse):
    young = np.ones(flags.shape, bool)
    return pyramid_search([previous], [current], last, before, young, uv, flags, cov, corr, fine_radius=6,
                          weights=None, **{**COARSE, **coarse}, **OPTIONS)


@pytest.mark.parametrize("shift", [(30.0, 4.0), (-38.5, 12.0), (47.0, -20.0)])
def test_a_patch_moved_30_to_50_px_is_lost_by_the_step_and_found_coarse_to_fine(shift):
    previous = _texture((480, 640), 1)
    current = _shifted(previous, shift)
    last = _points()
    uv, flags, cov, corr, before = _lost_by_the_step(previous, current, last)
    # Without the pyramid: no view found at its true place (the box reaches 6 px).
    truth = last + np.asarray(shift)
    found_plain = (flags == TrackFlag.TRACKED) & (np.linalg.norm(uv - truth, axis=2) < 1.0)
    assert not found_plain.any()
    # (The step may even take a look-alike within its box: a lost view is not searched.)
    lost = np.isin(flags, (TrackFlag.LOW_CORRELATION, TrackFlag.FORWARD_BACKWARD, TrackFlag.MATCH_FAILED))
    assert lost.mean() >= 0.9
    out = _search(previous, current, last, before, uv, flags, cov, corr)
    assert np.array_equal(out.searched, lost)
    assert out.found[lost].mean() >= 0.9
    error = np.linalg.norm(out.uv[out.found] - truth[out.found], axis=1)
    assert error.max() < 0.2
    assert (out.flags2d[out.found] == TrackFlag.TRACKED).all()
    assert (out.corr[out.found] >= OPTIONS["min_correlation"]).all()
    # The inputs are not modified; only the found views change.
    assert np.isnan(uv[out.found]).all() or not np.allclose(uv[out.found], out.uv[out.found])
    assert np.array_equal(out.flags2d[~out.found], flags[~out.found])


def test_old_views_and_views_the_step_kept_are_left_alone():
    previous = _texture((480, 640), 2)
    current = _shifted(previous, (40.0, 0.0))
    last = _points()
    uv, flags, cov, corr, before = _lost_by_the_step(previous, current, last)
    young = np.zeros(flags.shape, bool)
    out = pyramid_search([previous], [current], last, before, young, uv, flags, cov, corr, fine_radius=6,
                         weights=None, **COARSE, **OPTIONS)
    assert not out.found.any() and not out.searched.any()
    np.testing.assert_array_equal(out.flags2d, flags)


def test_a_repeated_print_puts_a_look_alike_in_the_box_and_the_guard_refuses_it():
    # Period 28 px: the 60 px box holds four copies of every patch; 7 coarse pixels apart.
    previous = _texture((480, 640), 3, period=28)
    current = _shifted(previous, (36.0, 0.0))
    last = _points()
    uv, flags, cov, corr, before = _lost_by_the_step(previous, current, last)
    lost = np.isin(flags, (TrackFlag.LOW_CORRELATION, TrackFlag.FORWARD_BACKWARD, TrackFlag.MATCH_FAILED))
    guarded = _search(previous, current, last, before, uv, flags, cov, corr)
    assert guarded.ambiguous[lost].all()
    assert not guarded.found.any()
    # Without the guard (margin 0 lets an equal peak through) the look-alikes are taken:
    # most finds are whole periods off the truth.
    loose = _search(previous, current, last, before, uv, flags, cov, corr, margin=0.0)
    truth = last + np.array([36.0, 0.0])
    wrong = loose.found & (np.linalg.norm(loose.uv - truth, axis=2) > 5.0)
    assert wrong.sum() >= 0.5 * loose.found.sum() > 0


def test_the_coarse_peak_is_the_true_shift_and_unique_unless_the_print_repeats():
    # A single smooth print: the slope beside the true peak is high, but it is no local
    # maximum, so the peak is unique; the same print repeated 6 coarse pixels apart is not.
    points = np.array([[40.0, 30.0], [60.0, 50.0], [100.0, 60.0]])
    single = pyramid([_texture((240, 320), 4)], 1)[0]
    moved = pyramid([_shifted(_texture((240, 320), 4), (20.0, -8.0))], 1)[0]
    find, score, unique = coarse_peaks(*box_scores(single, points, moved, points, size=7, radius=12), radius=12,
                                       exclusion=2.0, margin=0.1)
    np.testing.assert_allclose(find, points + np.array([10.0, -4.0]))
    assert (score > 0.9).all() and unique.all()
    repeated = pyramid([_texture((240, 320), 5, period=12)], 1)[0]
    moved_r = pyramid([_shifted(_texture((240, 320), 5, period=12), (20.0, 0.0))], 1)[0]
    _, score_r, unique_r = coarse_peaks(*box_scores(repeated, points, moved_r, points, size=7, radius=12), radius=12,
                                        exclusion=2.0, margin=0.1)
    assert (score_r > 0.9).all() and not unique_r.any()


def test_pooling_lets_the_shift_a_neighbourhood_shares_beat_each_views_look_alike():
    # Five points 1 cm apart; each view's surface (K = 3 shifts) has its true shift 0 at
    # 0.6 and a look-alike of 0.9 at shift 1 or 2 (a different one per view); a sixth
    # point 1 m away has only the look-alike and keeps its own scores.
    scores = np.array([[0.6, 0.9, 0.1], [0.6, 0.1, 0.9], [0.6, 0.9, 0.1], [0.6, 0.1, 0.9], [0.6, 0.2, 0.2],
                       [0.1, 0.9, 0.1]])
    x = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.02, 0, 0], [0.03, 0, 0], [0.04, 0, 0], [1.0, 0, 0]])
    reach = np.full(6, 0.05)
    out = pooled(scores, x, 5, reach)
    assert (out[:5].argmax(axis=1) == 0).all()
    np.testing.assert_allclose(out[5], scores[5])
    np.testing.assert_allclose(pooled(scores, x, 1, reach), scores)
    assert (scores.argmax(axis=1)[:4] != 0).all()


@pytest.mark.parametrize("bad", [dict(level=0), dict(level=5), dict(level=1.5), dict(radius=0), dict(radius=100),
                                 dict(size=6), dict(size=1), dict(margin=-0.1), dict(margin=float("nan")),
                                 dict(exclusion=0.5), dict(exclusion=15.0),
                                 dict(correlation=1.5), dict(correlation=float("nan")),
                                 dict(pool=0), dict(pool=2.5), dict(reach=0.0), dict(reach=float("inf"))])
def test_bad_settings_are_refused(bad):
    good = dict(level=2, radius=15, size=7, correlation=0.5, margin=0.1, exclusion=2.0, pool=8, reach=30.0)
    check_options(**good)
    with pytest.raises(ValueError):
        check_options(**{**good, **bad})
