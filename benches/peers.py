"""Side-by-side timings of elastocap against the peer a user would pick instead.

Each case runs the same input through elastocap and through the peer in one process,
alternating, several times, and prints one JSON line:
``{"case", "n", "ours_s", "peer", "peer_s", "ratio", "repeats"}`` where the times are
medians and ``ratio = peer_s / ours_s`` (above 1: elastocap is faster).

Run: ``python benches/peers.py`` (all cases) or ``python benches/peers.py knn`` (cases whose
name contains ``knn``). ``--repeats R`` sets the number of alternating rounds (default 7).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

import elastocap


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


def knn_cases(repeats: int) -> list[dict[str, Any]]:
    """k = 20 nearest neighbours of every point (itself excluded), build + query."""
    rng = np.random.default_rng(0)
    n, k = 100_000, 20
    rows = []
    for name, cloud in (("uniform", _uniform), ("surface", _sphere), ("clustered", _clustered)):
        points = cloud(n, rng)
        rows.append(
            _compare(
                f"knn_{name}_100k_k20",
                n,
                lambda p=points: elastocap.knn(p, k),
                "scipy.spatial.cKDTree(points).query(points, k=21, workers=-1)",
                lambda p=points: cKDTree(p).query(p, k=k + 1, workers=-1),
                repeats,
            )
        )
    return rows


def radius_cases(repeats: int) -> list[dict[str, Any]]:
    """All neighbours within a radius holding about 20 points, build + query."""
    rng = np.random.default_rng(1)
    n = 100_000
    points = _uniform(n, rng)
    radius = (20 / (n * 4 / 3 * np.pi)) ** (1 / 3)
    return [
        _compare(
            "radius_uniform_100k_avg20",
            n,
            lambda: elastocap.radius_neighbors(points, radius),
            "scipy.spatial.cKDTree(points).query_ball_point(points, r, workers=-1)",
            lambda: cKDTree(points).query_ball_point(points, radius, workers=-1),
            repeats,
        )
    ]


def polar_cases(repeats: int) -> list[dict[str, Any]]:
    """Nearest rotations of 1,000,000 random 3x3 matrices; the peer is numpy's batched SVD
    alone (the sign fix and product that turn it into a rotation are not even counted)."""
    rng = np.random.default_rng(2)
    n = 1_000_000
    matrices = rng.normal(size=(n, 3, 3))
    return [
        _compare(
            "polar_random_1m",
            n,
            lambda: elastocap.polar_rotation(matrices),
            "numpy.linalg.svd(matrices)",
            lambda: np.linalg.svd(matrices),
            max(3, repeats // 2),
        )
    ]


def sdf_cases(repeats: int) -> list[dict[str, Any]]:
    """Signed distance of a 256^3 occupancy grid (a smoothed random blob); the peer is
    scipy's exact EDT of the inside and of the outside, which the SDF is made of."""
    from scipy import ndimage

    rng = np.random.default_rng(3)
    occupancy = ndimage.zoom(ndimage.gaussian_filter(rng.random((64, 64, 64)), 4), 4, order=1) > 0.5
    return [
        _compare(
            "sdf_blob_256^3",
            occupancy.size,
            lambda: elastocap.signed_distance(occupancy),
            "scipy.ndimage.distance_transform_edt(occ) and (~occ)",
            lambda: (ndimage.distance_transform_edt(occupancy), ndimage.distance_transform_edt(~occupancy)),
            max(3, repeats // 2),
        )
    ]


CASES = {"knn": knn_cases, "radius": radius_cases, "polar": polar_cases, "sdf": sdf_cases}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("filter", nargs="?", default="", help="run only case groups whose name contains this")
    parser.add_argument("--repeats", type=int, default=7, help="alternating rounds per case (median reported)")
    args = parser.parse_args()
    for name, run in CASES.items():
        if args.filter in name:
            for row in run(args.repeats):
                print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
