"""Neighbour queries: k nearest and radius neighbours against scipy's cKDTree."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

import elastocap

from peer_cases._common import _clustered, _compare, _sphere, _uniform


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
