"""What the kill-and-resume tests (tests/test_resume_*.py) share: running a command in a
subprocess, killing it (SIGKILL) at its n-th atomic write (the ``ELASTOCAP_KILL_AT_WRITE``
hook of :mod:`elastocap._io`) or after a seeded random time, and comparing an output folder
with an uninterrupted run's."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh

# Generous: a run of these tiny captures takes seconds; a hang fails the test.
RUN_TIMEOUT = 120.0
# Figures that measure the run, not its result: allowed to differ after a resume.
TIMINGS = ("seconds",)


def command(argv: list[str], *, kill_at_write: int | None = None, kill_after: float | None = None) -> int:
    """Run ``elastocap argv`` (2 Rust threads, fixed so runs are comparable); returns the
    exit status (-9 when killed)."""
    env = {**os.environ, "RAYON_NUM_THREADS": "2"}
    env.pop("ELASTOCAP_KILL_AT_WRITE", None)
    if kill_at_write is not None:
        env["ELASTOCAP_KILL_AT_WRITE"] = str(kill_at_write)
    process = subprocess.Popen([sys.executable, "-m", "elastocap", *argv], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if kill_after is not None:
        try:
            process.wait(timeout=kill_after)
        except subprocess.TimeoutExpired:
            process.send_signal(signal.SIGKILL)
    try:
        _, stderr = process.communicate(timeout=RUN_TIMEOUT)
    except subprocess.TimeoutExpired:
        process.kill()
        raise AssertionError(f"elastocap {' '.join(argv)} hung") from None
    if process.returncode not in (0, -signal.SIGKILL):
        raise AssertionError(f"elastocap {' '.join(argv)} failed ({process.returncode}): {stderr}")
    return process.returncode


def count_writes(out: Path) -> int:
    """The atomic writes of a finished run: the files it left (each written once)."""
    return sum(1 for path in out.rglob("*") if path.is_file())


def visible_files(out: Path) -> list[Path]:
    """The files a user (or a resumed run) sees: not the hidden temporaries."""
    return sorted(p for p in out.rglob("*") if p.is_file() and not p.name.startswith("."))


def assert_whole(out: Path) -> None:
    """Every visible file of a killed run's folder reads back whole: no half-written file."""
    for path in visible_files(out):
        if path.suffix == ".npz":
            with zipfile.ZipFile(path) as archive:
                assert archive.testzip() is None, path
        elif path.suffix == ".ply":
            assert len(trimesh.load_mesh(path).faces) > 0, path
        elif path.suffix == ".json":
            json.loads(path.read_text())


def _without_timings(value: object) -> object:
    if isinstance(value, dict):
        return {k: _without_timings(v) for k, v in value.items() if not any(t in k for t in TIMINGS)}
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


def differences(reference: Path, resumed: Path, *, skip: tuple[str, ...] = ()) -> list[str]:
    """The files of ``resumed`` that differ from ``reference``'s: bytes, except ``.npz``
    (arrays equal to 1e-12, timing figures aside) and ``.json`` (timing figures aside).
    Names in ``skip`` are not compared (pages that print the run's timings). Files in one
    folder and not the other differ too; leftover temporary files count."""
    found = []
    names = {p.relative_to(reference) for p in reference.rglob("*") if p.is_file()}
    resumed_names = {p.relative_to(resumed) for p in resumed.rglob("*") if p.is_file()}
    for name in sorted(names ^ resumed_names):
        found.append(f"{name}: only in {'the reference' if name in names else 'the resumed run'}")
    for name in sorted(names & resumed_names):
        a, b = reference / name, resumed / name
        if name.name in skip:
            continue
        if a.suffix == ".npz":
            with np.load(a, allow_pickle=False) as x, np.load(b, allow_pickle=False) as y:
                keys = [k for k in x.files if not any(t in k for t in TIMINGS)]
                if sorted(keys) != sorted(k for k in y.files if not any(t in k for t in TIMINGS)):
                    found.append(f"{name}: arrays {x.files} vs {y.files}")
                    continue
                for key in keys:
                    u, v = x[key], y[key]
                    if u.shape != v.shape or u.dtype != v.dtype:
                        found.append(f"{name}[{key}]: {u.shape} {u.dtype} vs {v.shape} {v.dtype}")
                    elif u.dtype.kind == "f" and not np.allclose(u, v, rtol=0, atol=1e-12, equal_nan=True):
                        found.append(f"{name}[{key}]: max difference {np.nanmax(np.abs(u - v)):.3g}")
                    elif u.dtype.kind != "f" and not np.array_equal(u, v):
                        found.append(f"{name}[{key}] differs")
        elif a.suffix == ".json":
            if _without_timings(json.loads(a.read_text())) != _without_timings(json.loads(b.read_text())):
                found.append(f"{name} differs")
        elif a.read_bytes() != b.read_bytes():
            found.append(f"{name} differs")
    return found


def kill_and_resume(argv_for: Callable[[Path], list[str]], reference: Path, work: Path, *, kill_at_write: int | None = None,
                    kill_after: float | None = None, skip: tuple[str, ...] = ()) -> tuple[int, list[str]]:
    """Run ``argv_for(out)`` killed at a write or a time, check no half-written file is
    visible, rerun it to the end, and return (the killed run's status, the differences
    with ``reference``)."""
    out = work / "out"
    status = command(argv_for(out), kill_at_write=kill_at_write, kill_after=kill_after)
    if out.exists():
        assert_whole(out)
    assert command(argv_for(out)) == 0
    return status, differences(reference, out, skip=skip)


def seeded_times(seed: int, count: int, low: float, high: float) -> list[float]:
    """``count`` kill times (seconds) drawn with ``seed``."""
    return [float(t) for t in np.random.default_rng(seed).uniform(low, high, count)]


def kill_points(writes: int, seed: int, count: int) -> list[int]:
    """Every write when ``ELASTOCAP_RESUME_EVERY_WRITE`` is set (the closing note's run), else
    the first and the last write and ``count`` others drawn with ``seed``."""
    if os.environ.get("ELASTOCAP_RESUME_EVERY_WRITE"):
        return list(range(1, writes + 1))
    drawn = np.random.default_rng(seed).choice(np.arange(2, writes), size=min(count, writes - 2), replace=False)
    return [1, *sorted(int(k) for k in drawn), writes]


def timed(argv: list[str]) -> float:
    """Seconds of an uninterrupted run (to draw kill times within it)."""
    start = time.perf_counter()
    assert command(argv) == 0
    return time.perf_counter() - start
