"""Geometry kernels: polar decomposition, signed distance transforms, exact mesh distances."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

import elastocap

from peer_cases._common import _compare


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


def _centroid_heuristic(points: np.ndarray, mesh: Any) -> np.ndarray:
    """The distance elastocap used before parry (kept here only as a baseline): the exact
    distance to the 16 triangles with the nearest centroids, the smallest kept. Not exact on
    uneven meshes."""
    import trimesh

    triangles = np.asarray(mesh.triangles)
    _, near = cKDTree(triangles.mean(axis=1)).query(points, k=16, workers=-1)
    repeated = np.repeat(points, 16, axis=0)
    closest = trimesh.triangles.closest_point(triangles[near.reshape(-1)], repeated)
    return np.linalg.norm(closest - repeated, axis=1).reshape(-1, 16).min(axis=1)


def _figure_skin() -> Any:
    """The synthetic figure's skin at rest: a closed human-shaped mesh of 19,396 vertices."""
    from elastocap.synth import CapsuleFigure

    return CapsuleFigure(0).mesh(0, spacing=0.012)


def _mesh_queries(mesh: Any, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``near``: points on the surface moved up to 2 cm along random directions (fit and
    ground-truth measures query there); ``box``: uniform in the bounding box grown by 10%."""
    import trimesh

    on, _ = trimesh.sample.sample_surface(mesh, n, seed=int(rng.integers(2**31)))
    lo, hi = mesh.bounds
    pad = 0.1 * (hi - lo)
    return {"near": on + rng.uniform(-0.02, 0.02, (n, 3)), "box": rng.uniform(lo - pad, hi + pad, (n, 3))}


def mesh_distance_cases(repeats: int) -> list[dict[str, Any]]:
    """Unsigned distance of 100,000 points to the figure's skin (19,396 vertices, 38,788
    triangles), index build + query each time, against open3d's RaycastingScene (Embree,
    float32), the old 16-centroid heuristic and (on 10,000 points: it is slow) trimesh's
    ``proximity.closest_point`` (rtree)."""
    import trimesh

    from elastocap.geometry.mesh_distance import TriangleMesh

    mesh = _figure_skin()
    queries = _mesh_queries(mesh, 100_000, np.random.default_rng(11))
    rows = []
    for where, points in queries.items():
        ours = lambda p=points: TriangleMesh(mesh).distances(p)  # noqa: E731
        rows.append(_compare(f"mesh_distance_{where}", len(points), ours, "16-centroid heuristic (cKDTree + trimesh)",
                             lambda p=points: _centroid_heuristic(p, mesh), repeats))
        try:
            import open3d as o3d
        except ImportError as error:  # the bench extra, and Debian's libusb-1.0-0
            rows.append({"case": f"mesh_distance_{where}", "peer": "open3d", "skipped": str(error)})
        else:
            def open3d_distances(p: np.ndarray = points) -> np.ndarray:
                scene = o3d.t.geometry.RaycastingScene()
                scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.faces.astype(np.uint32)))
                return scene.compute_distance(o3d.core.Tensor(p.astype(np.float32))).numpy()

            def open3d_closest(p: np.ndarray = points) -> Any:
                scene = o3d.t.geometry.RaycastingScene()
                scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.faces.astype(np.uint32)))
                return scene.compute_closest_points(o3d.core.Tensor(p.astype(np.float32)))

            rows.append(_compare(f"mesh_closest_points_{where}", len(points), lambda p=points: TriangleMesh(mesh).closest_points(p),
                                 "open3d RaycastingScene.compute_closest_points (float32)", open3d_closest, repeats))
            rows.append(_compare(f"mesh_distance_{where}", len(points), ours,
                                 "open3d RaycastingScene.compute_distance (float32)", open3d_distances, repeats))
        few = points[:10_000]
        rows.append(_compare(f"mesh_closest_points_{where}", len(few), lambda p=few: TriangleMesh(mesh).closest_points(p),
                             "trimesh.proximity.closest_point (rtree)",
                             lambda p=few: trimesh.proximity.closest_point(mesh.copy(), p), max(1, repeats // 3)))
    return rows
