"""Kill-and-resume of ``elastocap hull`` (issue 13, item 5): killed with SIGKILL at each of
its atomic writes in turn (half-way through writing the temporary file, the worst moment)
and at seeded random times, then rerun: no half-written file is ever visible, and the
resumed folder equals an uninterrupted run's byte for byte."""

from __future__ import annotations

from pathlib import Path

import pytest

from elastocap.synth.capture import write_synthetic_capture
from resume_runs import count_writes, kill_and_resume, seeded_times, timed

SEED = 13


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, float]:
    """(the capture, an uninterrupted run's output, its seconds)."""
    root = tmp_path_factory.mktemp("resume_hull")
    capture = write_synthetic_capture(root / "capture", frames=3, cameras=4, image_size=(96, 72), spacing=0.04,
                                      progress=False)
    reference = root / "reference"
    seconds = timed(_argv(capture)(reference))
    return capture, reference, seconds


def _argv(capture: Path):  # type: ignore[no-untyped-def]
    return lambda out: ["hull", str(capture), "--out", str(out), "--resolution", "32", "--quiet"]


def test_killed_at_every_write_resumes_to_the_same_files(runs: tuple[Path, Path, float], tmp_path: Path) -> None:
    capture, reference, _ = runs
    writes = count_writes(reference)
    assert writes == 6  # a .npz and a .ply per frame
    for k in range(1, writes + 1):
        work = tmp_path / f"kill{k}"
        status, differences = kill_and_resume(_argv(capture), reference, work, kill_at_write=k)
        assert status == -9, f"the run was not killed at write {k}"
        assert differences == [], f"killed at write {k}: {differences}"


def test_killed_at_random_times_resumes_to_the_same_files(runs: tuple[Path, Path, float], tmp_path: Path) -> None:
    capture, reference, seconds = runs
    for i, after in enumerate(seeded_times(SEED, 1, 0.3 * seconds, seconds)):
        work = tmp_path / f"time{i}"
        _, differences = kill_and_resume(_argv(capture), reference, work, kill_after=after)
        assert differences == [], f"killed after {after:.2f} s: {differences}"
