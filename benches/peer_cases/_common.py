"""Shared pieces of the peer cases: point sets, timing, the side-by-side row, peak memory."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np


def _uniform(n: int, rng: np.random.Generator) -> np.ndarray:
    return rng.random((n, 3))


def _sphere(n: int, rng: np.random.Generator) -> np.ndarray:
    """Points on the unit sphere: a surface, as hull and model surfaces are."""
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _clustered(n: int, rng: np.random.Generator) -> np.ndarray:
    """20 tight clusters plus 5% outliers in a box 100 times larger."""
    centres = rng.random((20, 3))
    points = centres[rng.integers(0, 20, n)] + 1e-3 * (rng.random((n, 3)) - 0.5)
    outliers = rng.random(n) < 0.05
    points[outliers] = rng.uniform(-50, 50, (int(outliers.sum()), 3))
    return points


def _time(fn: Callable[[], Any]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def _compare(case: str, n: int, ours: Callable[[], Any], peer_name: str, peer: Callable[[], Any], repeats: int) -> dict[str, Any]:
    ours(), peer()  # warm up: page in, build lazy tables, start thread pools
    ours_times, peer_times = [], []
    for _ in range(repeats):
        ours_times.append(_time(ours))
        peer_times.append(_time(peer))
    ours_s, peer_s = statistics.median(ours_times), statistics.median(peer_times)
    return {
        "case": case,
        "n": n,
        "ours_s": round(ours_s, 6),
        "peer": peer_name,
        "peer_s": round(peer_s, 6),
        "ratio": round(peer_s / ours_s, 2),
        "repeats": repeats,
    }


def _peak_mb() -> float:
    """VmHWM of this process, MB."""
    line = next(line for line in open("/proc/self/status") if line.startswith("VmHWM:"))
    return int(line.split()[1]) / 1024
