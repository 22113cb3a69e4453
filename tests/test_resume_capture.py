"""Kill-and-resume of ``elastocap capture`` (issue 13, item 5): every stage, the report's
pictures and the animation files, killed with SIGKILL at seeded atomic writes (set
``ELASTOCAP_RESUME_EVERY_WRITE=1`` for every one in turn) and at a seeded random time, then
rerun: no half-written file is visible, and the resumed folder equals an uninterrupted
run's: hulls, model, fits, pictures, GLB / PC2 / OBJ byte for byte or to 1e-12, metrics
with timings aside (report.html prints the run's timings and is not compared)."""

from __future__ import annotations

from pathlib import Path

import pytest

from elastocap.synth.capture import write_synthetic_capture
from resume_runs import count_writes, kill_and_resume, kill_points, seeded_times, timed

SEED = 29
# The page prints this run's stage times.
SKIP = ("report.html",)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, float]:
    root = tmp_path_factory.mktemp("resume_capture")
    capture = write_synthetic_capture(root / "capture", frames=4, cameras=4, image_size=(96, 72), spacing=0.04,
                                      progress=False)
    reference = root / "reference"
    seconds = timed(_argv(capture)(reference))
    return capture, reference, seconds


def _argv(capture: Path):  # type: ignore[no-untyped-def]
    return lambda out: ["capture", str(capture), "--out", str(out), "--resolution", "32", "--nodes", "150",
                        "--silhouettes", "masks", "--fps", "25", "--quiet"]


def test_killed_at_writes_resumes_to_the_same_outputs(runs: tuple[Path, Path, float], tmp_path: Path) -> None:
    capture, reference, _ = runs
    # 27 files; metrics.json and report.html are written twice (fit stage, then capture).
    writes = count_writes(reference) + 2
    for k in kill_points(writes, SEED, 2):
        status, differences = kill_and_resume(_argv(capture), reference, tmp_path / f"kill{k}", kill_at_write=k,
                                              skip=SKIP)
        assert status == -9, f"the run was not killed at write {k}"
        assert differences == [], f"killed at write {k}: {differences}"


def test_killed_at_a_random_time_resumes_to_the_same_outputs(runs: tuple[Path, Path, float], tmp_path: Path) -> None:
    capture, reference, seconds = runs
    for i, after in enumerate(seeded_times(SEED, 1, 0.3 * seconds, seconds)):
        _, differences = kill_and_resume(_argv(capture), reference, tmp_path / f"time{i}", kill_after=after, skip=SKIP)
        assert differences == [], f"killed after {after:.2f} s: {differences}"
