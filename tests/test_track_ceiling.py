"""benches/track_ceiling.py: the tracker's matcher started at the truth (issue 15's oracle
ceiling) on the sphere scene, whose truth is exact, and its readings on constructed tracks."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import elastocap
from track_scene import blank_band, write_scene

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benches"))
import track_ceiling as tc  # noqa: E402


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    root = tmp_path_factory.mktemp("ceiling") / "scene"
    truth = write_scene(root, frames=5, cameras=6, seed=1, points=400)
    return root, truth


def _oracle(root: Path, truth: object, mode: str) -> tuple[tc.Oracle, np.ndarray]:
    capture = elastocap.Capture.open(root)
    uv = tc.true_views(truth.rig.cameras, truth.positions)  # type: ignore[attr-defined]
    seen = truth.visible.transpose(0, 2, 1)  # type: ignore[attr-defined]
    first = np.zeros(seen.shape[1], np.int64)
    return tc.oracle(tc.Matcher(capture, list(capture.frames)), uv, seen, first, mode), seen


@pytest.mark.parametrize("mode", tc.MODES)
def test_matches_started_at_the_truth_stay_on_it(scene: tuple[Path, object], mode: str) -> None:
    # The scene's truth is exact: the match converges a tenth of a pixel from it (noise,
    # shading and the affine model of a patch on a ball), and most matches are accepted.
    o, seen = _oracle(*scene, mode)
    live = seen[1:]
    ran = o.flag[1:] != 255
    assert (ran == (live & ~o.free[1:])).all()  # every seen view matched, none other
    e = o.error[np.isfinite(o.error)]
    assert e.size > 0.8 * ran.sum()
    assert np.median(e) < 0.15
    assert o.accepted[1:][ran].mean() > 0.7
    # Accepted matches did not fail: their errors are small.
    assert np.percentile(o.error[o.accepted], 95) < 0.8


def test_views_on_a_blanked_band_are_rejected_not_accepted(tmp_path: Path) -> None:
    # Texture wiped from the middle of every image on frame 3: the matches of the points
    # seen there must fail the acceptance tests (a ceiling counts them as lost).
    root = tmp_path / "band"
    truth = write_scene(root, frames=5, cameras=6, seed=1, points=400)
    blank_band(root, list(truth.rig.names), (3,), half=30)
    o, seen = _oracle(root, truth, "f2f")
    uv = tc.true_views(truth.rig.cameras, truth.positions)
    middle = truth.rig.cameras[0].width / 2
    inside = seen[3] & (np.abs(uv[3, ..., 0] - middle) < 20) & ~o.free[3]
    outside = seen[3] & (np.abs(uv[3, ..., 0] - middle) > 45) & ~o.free[3]
    assert inside.sum() > 20
    assert o.accepted[3][inside].mean() < 0.1
    assert o.accepted[3][outside].mean() > 0.7


def test_readings_on_constructed_tracks() -> None:
    # 4 frames, 3 points, 3 cameras. Point 0: seen by all, held with 0.2 px. Point 1: held,
    # but camera 2's view errs 1.5 px on every frame (RMS over its 12 views:
    # sqrt((8 * 0.04 + 4 * 2.25) / 12) = 0.88 > 0.5). Point 2: seen by cameras 0 and 1 on frames 0-1, by one camera on frame
    # 2 (the first span ends), by both again on frame 3 where camera 1's view is not held.
    f, n, c = 4, 3, 3
    seen = np.zeros((f, n, c), bool)
    seen[:, 0] = seen[:, 1] = True
    seen[:, 2, :2] = True
    seen[2, 2, 1] = False
    held = seen.copy()
    held[3, 2, 1] = False
    error = np.where(held, 0.2, np.nan)
    error[:, 1, 2] = 1.5
    first = np.zeros(n, np.int64)
    r = tc.readings(held, error, seen, first, np.arange(n))
    assert r["a_through"] == pytest.approx(2 / 3, abs=1e-4)  # point 2 has one view on frame 3
    assert r["b_through"] == pytest.approx(1.0)  # its first span ends on frame 2
    assert r["a_rms_le_0.5"] == pytest.approx(2 / 3, abs=1e-4)
    assert r["a_through_and_rms"] == pytest.approx(1 / 3, abs=1e-4)
    # (c): pairs (0, *), (1, *) run over 4 frames; (2, 0) over 4, (2, 1) over frames 0-1
    # (held there): 8 pairs, all held; (1, 2) errs 1.5 px.
    assert r["c_pairs"] == 8
    assert r["c_through"] == pytest.approx(1.0)
    assert r["c_through_and_rms"] == pytest.approx(7 / 8, abs=1e-4)
    # One view a frame is enough for a tracker that takes the depth from elsewhere.
    assert tc.readings(held, error, seen, first, np.arange(n), min_views=1)["a_through"] == pytest.approx(1.0)
    # A point seeded on frame 2 counts from there only.
    first2 = np.array([0, 0, 2])
    r2 = tc.readings(held, error, seen, first2, np.array([2]))
    assert r2["b_through"] == pytest.approx(1.0) and r2["a_through"] == 0.0
