"""``elastocap demo``: the kernels on generated data, checked against scipy and numpy.

For now the demo exercises what has landed (spatial hashing and polar decomposition) and
writes what it measured to ``OUT/metrics.json``; it grows into the full synthetic capture
as the capture stages land.
"""

from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree
from tqdm import tqdm

import elastocap
from elastocap._validate import as_count

__all__ = ["run_demo"]


def _timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    start = time.perf_counter()
    result = fn()
    return result, time.perf_counter() - start


def _surface_points(n: int, rng: np.random.Generator) -> np.ndarray:
    """Points on a torus: the kind of cloud a hull surface gives."""
    u, v = rng.uniform(0, 2 * np.pi, (2, n))
    major, minor = 1.0, 0.3
    return np.column_stack(
        [(major + minor * np.cos(v)) * np.cos(u), (major + minor * np.cos(v)) * np.sin(u), minor * np.sin(v)]
    )


def _neighbour_check(name: str, points: np.ndarray, k: int) -> dict[str, Any]:
    (indices, distances), seconds = _timed(lambda: elastocap.knn(points, k))
    (ref_distances, _), ref_seconds = _timed(lambda: cKDTree(points).query(points, k=k + 1, workers=-1))
    radius = float(np.median(distances[:, -1]))
    (indptr, _, _), radius_seconds = _timed(lambda: elastocap.radius_neighbors(points, radius))
    ref_counts = cKDTree(points).query_ball_point(points, radius, return_length=True, workers=-1) - 1
    return {
        "cloud": name,
        "points": len(points),
        "k": k,
        "knn_seconds": round(seconds, 4),
        "ckdtree_seconds": round(ref_seconds, 4),
        "knn_max_distance_error_vs_ckdtree": float(np.abs(distances - ref_distances[:, 1:]).max()),
        "radius": radius,
        "radius_seconds": round(radius_seconds, 4),
        "radius_rows_matching_ckdtree_counts": float(np.mean(np.diff(indptr) == ref_counts)),
    }


def _polar_check(n: int, rng: np.random.Generator) -> dict[str, Any]:
    matrices = rng.normal(size=(n, 3, 3))
    rotations, seconds = _timed(lambda: elastocap.polar_rotation(matrices))
    u, _, vt = np.linalg.svd(matrices)
    sign = np.sign(np.linalg.det(u @ vt))
    u[:, :, 2] *= sign[:, None]
    reference = u @ vt
    identity_error = np.abs(np.swapaxes(rotations, 1, 2) @ rotations - np.eye(3)).max()
    return {
        "matrices": n,
        "seconds": round(seconds, 4),
        "max_orthonormality_error": float(identity_error),
        "min_det": float(np.linalg.det(rotations).min()),
        "max_difference_to_svd_rotation": float(np.abs(rotations - reference).max()),
    }


def run_demo(out: Path, *, n_points: int = 100_000, progress: bool = True) -> Path:
    """Run the demo and write ``out/metrics.json``.

    Parameters
    ----------
    out : path
        Output folder, created if missing.
    n_points : int
        Points per generated cloud (and ten times as many matrices for the polar check).
    progress : bool
        Show a progress bar.

    Returns
    -------
    path
        The metrics file.
    """
    n_points = as_count("n_points", n_points)
    if n_points < 100:
        raise elastocap.InvalidInputError(f"n_points must be at least 100, got {n_points}")
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    steps = [
        ("knn: uniform cube", lambda: _neighbour_check("uniform cube", rng.random((n_points, 3)), 20)),
        ("knn: torus surface", lambda: _neighbour_check("torus surface", _surface_points(n_points, rng), 20)),
        ("knn: 2-D disc", lambda: _neighbour_check("2-D disc", rng.normal(size=(n_points, 2)), 12)),
        ("polar decomposition", lambda: _polar_check(10 * n_points, rng)),
    ]
    results: dict[str, Any] = {"neighbours": []}
    with tqdm(steps, desc="elastocap demo", unit="step", disable=not progress) as bar:
        for label, step in bar:
            bar.set_postfix_str(label)
            result = step()
            if label.startswith("knn"):
                results["neighbours"].append(result)
            else:
                results["polar"] = result
    results["machine"] = {"cpus": os.cpu_count(), "python": platform.python_version(), "elastocap": elastocap.__version__}
    path = out / "metrics.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(results, indent=2) + "\n")
    tmp.replace(path)  # atomic: an interrupted demo leaves no half-written file
    return path
