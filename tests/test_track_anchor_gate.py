"""The richer stage's cost (benches/README.md, anchorcost1): ``match_patches(refine=)``
reports the converged affine centre it started from beside its own (so the anchors' smoothed
correction needs no second, affine-only match), skips the richer stage where the affine
match's correlation already reaches ``refine["skip_correlation"]``, and the anchors run it
only on patches ``settings.ANCHOR_REFINE_MIN_AGE`` corrections old, every
``ANCHOR_REFINE_EVERY`` corrections, carrying the last smoothed departure in between."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st

from elastocap.stereo import match_patches
from elastocap.stereo.matching import MatchStatus, Refined
from elastocap.tracking import settings
from elastocap.tracking.anchors import Anchors

SIZE = 15
REFINE = {"warp": "quadratic", "gain_gradient": True, "warp_sigma": 0.1, "gain_sigma": 0.05, "fallback": True}


def _texture(seed: int, side: int = 200) -> np.ndarray:
    """A smooth random texture: blurred at 2 px, 40 grey levels RMS."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.normal(0, 1, (side, side)).astype(np.float32), (0, 0), 2.0)
    return (128 + 40 * tex / tex.std()).astype(np.float32)


def _points(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    grid = np.arange(40.0, 161.0, 30.0)
    return np.stack(np.meshgrid(grid, grid), axis=-1).reshape(-1, 2) + rng.uniform(-0.5, 0.5, (25, 2))


def _bent(tex: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``tex`` seen through a map that bends across every 15 px patch around ``points``
    (a compression that changes across the patch, as on a turning limb: the sampled
    position is pushed by 1.2 px x the square of the offset from the nearest point over the
    half-width) and shaded by a gain ramp of 30% across it. The points stay where they
    are (the push vanishes at them)."""
    v, u = np.mgrid[0 : tex.shape[0], 0 : tex.shape[1]].astype(np.float32)
    near = points[np.argmin((u[..., None] - points[:, 0]) ** 2 + (v[..., None] - points[:, 1]) ** 2, axis=-1)]
    xi, eta = (u - near[..., 0]) / 7.0, (v - near[..., 1]) / 7.0
    map_u = (u + 1.2 * xi * xi).astype(np.float32)
    map_v = (v + 1.2 * eta * eta - 0.6 * xi * eta).astype(np.float32)
    image = cv2.remap(tex, map_u, map_v, cv2.INTER_CUBIC)
    return (image * (1.0 + 0.15 * xi)).astype(np.float32)


def test_affine_centre_is_the_affine_match_to_the_bit() -> None:
    # Whatever the richer stage did (reported, fell back, skipped), the affine centre it
    # reports is the centre of the match without the richer model, bit for bit; where it
    # fell back or was skipped, the whole match is the affine one.
    tex = _texture(1)
    points = _points(1)
    shifted = cv2.warpAffine(tex, np.array([[1, 0, 0.37], [0, 1, -0.21]], np.float32), tex.shape[::-1],
                             flags=cv2.INTER_CUBIC)
    start = points + [0.3, -0.2]
    seen: set[int] = set()
    # The bent patches need the richer stage; the shifted ones reach the gate.
    for image, skip in ((_bent(tex, points), np.inf), (shifted, 0.999)):
        plain = match_patches(tex, points, [image], initial=start[:, None], size=SIZE, max_iterations=15)
        assert plain.affine_centre is not None and np.isnan(plain.affine_centre).all()
        assert plain.refined is not None and (plain.refined == Refined.NO).all()
        rich = match_patches(tex, points, [image], initial=start[:, None], size=SIZE, max_iterations=15,
                             refine={**REFINE, "skip_correlation": skip})
        assert rich.affine_centre is not None and rich.refined is not None
        ok = plain.status == MatchStatus.CONVERGED
        assert ok.sum() >= 20
        np.testing.assert_array_equal(rich.affine_centre[ok], plain.positions[ok])
        assert np.isnan(rich.affine_centre[~ok]).all()
        seen |= set(np.unique(rich.refined[ok]).tolist())
        same = ok & np.isin(rich.refined, [Refined.FELL_BACK, Refined.SKIPPED])
        np.testing.assert_array_equal(rich.positions[same], plain.positions[same])
        np.testing.assert_array_equal(rich.covariance[same[:, 0]], plain.covariance[same[:, 0]])
    assert {int(Refined.REPORTED), int(Refined.SKIPPED)} <= seen


@hsettings(max_examples=3, deadline=None)
@given(st.integers(0, 1000))
def test_the_richer_stage_is_skipped_where_the_affine_match_explains_the_patch(seed: int) -> None:
    # A texture that only moved: the affine match explains it (correlation ~1), so with the
    # gate the richer stage is skipped and the affine match reported. The same texture bent
    # and shaded across each patch: the affine match leaves a residual (correlation below
    # the gate), the richer stage runs and explains more of the patch.
    tex = _texture(seed)
    points = _points(seed)
    gate = {**REFINE, "skip_correlation": 0.995}
    shifted = cv2.warpAffine(tex, np.array([[1, 0, 0.37], [0, 1, -0.21]], np.float32), tex.shape[::-1],
                             flags=cv2.INTER_CUBIC)
    start = points + [0.37, -0.21] + [0.2, -0.1]
    moved = match_patches(tex, points, [shifted], initial=start[:, None], size=SIZE, max_iterations=15, refine=gate)
    assert moved.refined is not None
    ok = moved.status[:, 0] == MatchStatus.CONVERGED
    assert ok.sum() >= 20
    assert (moved.refined[ok, 0] == Refined.SKIPPED).mean() >= 0.9
    bent = _bent(tex, points)
    affine = match_patches(tex, points, [bent], initial=points[:, None] + 0.2, size=SIZE, max_iterations=15)
    rich = match_patches(tex, points, [bent], initial=points[:, None] + 0.2, size=SIZE, max_iterations=15,
                         refine=gate)
    assert rich.refined is not None
    ok = (affine.status[:, 0] == MatchStatus.CONVERGED)
    assert (affine.correlation[ok, 0] < 0.995).mean() >= 0.9
    taken = ok & (rich.refined[:, 0] == Refined.REPORTED)
    assert taken.sum() >= 0.7 * ok.sum()
    assert np.median(rich.correlation[taken, 0] - affine.correlation[taken, 0]) > 0
    # Nearer the points (the bend vanishes there) than the affine centre.
    truth = points[taken]
    assert np.median(np.linalg.norm(rich.positions[taken, 0] - truth, axis=1)) \
        < np.median(np.linalg.norm(affine.positions[taken, 0] - truth, axis=1))


@pytest.fixture
def restore() -> object:
    keys = ("ANCHOR_REFINE", "ANCHOR_REFINE_SMOOTH", "ANCHOR_REFINE_MIN_AGE", "ANCHOR_REFINE_EVERY")
    saved = {k: getattr(settings, k) for k in keys}
    yield None
    for k, v in saved.items():
        setattr(settings, k, v)


def _run(tex: np.ndarray, points: np.ndarray, frames: list[np.ndarray], refine: dict[str, object] | None, *,
         min_age: int, every: int) -> tuple[np.ndarray, np.ndarray]:
    """(F, N, 2) corrections and (F, N, 2) offsets after each frame."""
    settings.ANCHOR_REFINE, settings.ANCHOR_REFINE_SMOOTH = refine, 0.3
    settings.ANCHOR_REFINE_MIN_AGE, settings.ANCHOR_REFINE_EVERY = min_age, every
    anchors = Anchors(1, SIZE)
    anchors.cut([tex], points[:, None], np.ones((len(points), 1), bool), 0)
    out, offsets = [], []
    for image in frames:
        uv, stale = anchors.correct([image], points[:, None].copy(), min_correlation=0.7, reach=1.5, min_texture=1.0)
        out.append(np.where(stale[..., None], np.nan, uv)[:, 0])
        offsets.append(anchors.offset[:, 0].copy())
    return np.array(out), np.array(offsets)


def test_the_age_gate_carries_the_last_departure(restore: object) -> None:
    # New image noise every frame on a still texture. The richer stage from the third
    # correction on, every second one: before it the correction is the affine one to the
    # bit (no departure yet); on its turns the departure is updated; off them the affine
    # centre carries the last one unchanged.
    tex = _texture(5)
    points = _points(5)
    rng = np.random.default_rng(6)
    frames = [tex + rng.normal(0, 2.0, tex.shape).astype(np.float32) for _ in range(6)]
    affine, _ = _run(tex, points, frames, None, min_age=0, every=1)
    gated, offsets = _run(tex, points, frames, REFINE, min_age=2, every=2)
    np.testing.assert_array_equal(gated[:2], affine[:2])
    assert np.isnan(offsets[:2]).all()
    seen = np.isfinite(offsets[2, :, 0])
    assert seen.mean() >= 0.8
    # Turns at corrections 2 and 4; 3 and 5 carry.
    np.testing.assert_array_equal(offsets[3][seen], offsets[2][seen])
    np.testing.assert_array_equal(offsets[5][seen], offsets[4][seen])
    assert (offsets[4][seen] != offsets[3][seen]).any()
    kept = seen & np.isfinite(gated[3, :, 0]) & np.isfinite(affine[3, :, 0])
    np.testing.assert_allclose(gated[3][kept], affine[3][kept] + offsets[2][kept], atol=1e-12)
    # Every correction, from the cut: lsm29's W (offsets set from the first on).
    _, every = _run(tex, points, frames, REFINE, min_age=0, every=1)
    assert np.isfinite(every[0, :, 0]).mean() >= 0.8
