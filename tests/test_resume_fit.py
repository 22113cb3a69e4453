"""Kill-and-resume of ``elastocap fit`` (issue 13, item 5): hulls, the model, every fitted
frame and the metrics, killed with SIGKILL at seeded atomic writes (set
``ELASTOCAP_RESUME_EVERY_WRITE=1`` for every one in turn) and at seeded random times, then
rerun: no half-written file is visible, and the resumed folder equals an uninterrupted
run's (node positions to 1e-12, timings aside)."""

from __future__ import annotations

from pathlib import Path

import pytest

from elastocap.synth.capture import write_synthetic_capture
from resume_runs import count_writes, kill_and_resume, kill_points, seeded_times, timed

SEED = 5


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, float]:
    root = tmp_path_factory.mktemp("resume_fit")
    capture = write_synthetic_capture(root / "capture", frames=4, cameras=4, image_size=(96, 72), spacing=0.04,
                                      progress=False)
    reference = root / "reference"
    seconds = timed(_argv(capture)(reference))
    return capture, reference, seconds


def _argv(capture: Path):  # type: ignore[no-untyped-def]
    return lambda out: ["fit", str(capture), "--out", str(out), "--resolution", "32", "--nodes", "150", "--quiet"]


def test_killed_at_writes_resumes_to_the_same_fit(runs: tuple[Path, Path, float], tmp_path: Path) -> None:
    capture, reference, _ = runs
    writes = count_writes(reference)
    assert writes == 18  # 4 hulls and 4 fits (.npz + .ply), the model, metrics.json
    for k in kill_points(writes, SEED, 3):
        status, differences = kill_and_resume(_argv(capture), reference, tmp_path / f"kill{k}", kill_at_write=k)
        assert status == -9, f"the run was not killed at write {k}"
        assert differences == [], f"killed at write {k}: {differences}"


def test_killed_at_a_random_time_resumes_to_the_same_fit(runs: tuple[Path, Path, float], tmp_path: Path) -> None:
    capture, reference, seconds = runs
    for i, after in enumerate(seeded_times(SEED, 1, 0.4 * seconds, seconds)):
        _, differences = kill_and_resume(_argv(capture), reference, tmp_path / f"time{i}", kill_after=after)
        assert differences == [], f"killed after {after:.2f} s: {differences}"
