"""Visual hull carving against a numpy carve, and its peak memory."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

import elastocap

from peer_cases._common import _compare


def _carve_numpy(masks, rig, grid):
    """The vectorised numpy reference: project every voxel centre into every camera."""
    centres = grid.centers().reshape(-1, 3)
    rejections = np.zeros(len(centres), np.int32)
    for mask, camera in zip(masks, rig.cameras):
        uv, depth = camera.project(centres)
        px = np.floor(uv + 0.5).astype(np.int64)
        seen = (depth > 0) & (px[:, 0] >= 0) & (px[:, 1] >= 0) & (px[:, 0] < camera.width) & (px[:, 1] < camera.height)
        background = np.zeros(len(centres), bool)
        background[seen] = ~mask[px[seen, 1], px[seen, 0]]
        rejections += background
    return (rejections == 0).reshape(grid.shape)


def carve_cases(repeats: int) -> list[dict[str, Any]]:
    """Carving a 256^3 grid with 8 cameras of 1024x1024 masks (an ellipsoid's silhouettes),
    centre footprint, against the vectorised numpy reference (and Open3D's
    VoxelGrid.carve_silhouette when open3d is installed: `pip install open3d`)."""
    masks, rig, grid = _carve_setup()
    cams = rig.cameras
    ours = lambda: elastocap.visual_hull(masks, rig, grid, footprint="center")  # noqa: E731
    assert np.array_equal(ours().occupancy, _carve_numpy(masks, rig, grid)), "carving differs from the reference"
    return _carve_rows(masks, rig, grid, cams, ours, repeats)


def _carve_setup():
    """8 cameras of 1024x1024 around an ellipsoid, its silhouettes, and a 256^3 grid."""
    import cv2
    import trimesh

    from elastocap import Camera, Grid, Rig

    cams = []
    for i in range(8):
        a = 2 * np.pi * i / 8
        eye = np.array([3 * np.cos(a), 3 * np.sin(a), 0.8 * (-1) ** i])
        z = -eye / np.linalg.norm(eye)
        x = np.cross(z, [0, 0, 1.0])
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        cams.append(Camera(f"c{i}", [[1100, 0, 511.5], [0, 1100, 511.5], [0, 0, 1]], np.zeros(5), R, -R @ eye, 1024, 1024))
    rig = Rig(cams)
    mesh = trimesh.creation.icosphere(subdivisions=5)
    mesh.apply_scale([0.6, 0.45, 0.35])
    masks = []
    for camera in cams:
        uv, _ = camera.project(mesh.vertices)
        mask = np.zeros((1024, 1024), np.uint8)
        for triangle in np.round(uv[mesh.faces] * 256).astype(np.int32):
            cv2.fillConvexPoly(mask, triangle, 1, shift=8)
        masks.append(mask.astype(bool))
    grid = Grid.around([-0.8] * 3, [0.8] * 3, 256)
    return masks, rig, grid


def _carve_rows(masks, rig, grid, cams, ours, repeats):
    rows = [
        _compare(
            "carve_256^3_8cams_1024px",
            grid.shape[0] * grid.shape[1] * grid.shape[2],
            ours,
            "vectorised numpy reference (centre footprint)",
            lambda: _carve_numpy(masks, rig, grid),
            max(3, repeats // 2),
        )
    ]
    try:
        import open3d as o3d
    except ImportError:
        return rows

    def open3d_carve():
        voxels = o3d.geometry.VoxelGrid.create_dense(
            origin=grid.bounds[0], color=[0, 0, 0], voxel_size=grid.spacing,
            width=grid.spacing * grid.shape[0], height=grid.spacing * grid.shape[1], depth=grid.spacing * grid.shape[2],
        )
        for mask, camera in zip(masks, cams):
            params = o3d.camera.PinholeCameraParameters()
            params.intrinsic = o3d.camera.PinholeCameraIntrinsic(1024, 1024, camera.K)
            extrinsic = np.eye(4)
            extrinsic[:3, :3], extrinsic[:3, 3] = camera.R, camera.t
            params.extrinsic = extrinsic
            voxels.carve_silhouette(o3d.geometry.Image(mask.astype(np.float32)), params)
        return voxels

    rows.append(
        _compare(
            "carve_256^3_8cams_1024px",
            grid.shape[0] * grid.shape[1] * grid.shape[2],
            ours,
            "open3d VoxelGrid.carve_silhouette",
            open3d_carve,
            max(3, repeats // 2),
        )
    )
    return rows


# VmHWM (peak resident set of this process image), not ru_maxrss, which Linux carries over
# from the parent across fork + exec: peers.py itself peaks at gigabytes.
_MEMORY_SCRIPT = """
import sys, json
sys.path.insert(0, {benches!r})
from peer_cases.hull import _carve_setup
def peak_mb():
    line = next(l for l in open("/proc/self/status") if l.startswith("VmHWM:"))
    return int(line.split()[1]) / 1024
masks, rig, grid = _carve_setup()
before = peak_mb()
import elastocap
hull = elastocap.visual_hull(masks, rig, grid, footprint="center")
sdf = hull.sdf()
print(json.dumps({{"before_mb": before, "after_mb": peak_mb()}}))
"""


def memory_cases(repeats: int) -> list[dict[str, Any]]:
    """Peak resident memory of carving a 256^3 hull and computing its signed distance, in a
    fresh process (VmHWM); `input_mb` is the peak before (the masks and interpreter)."""
    import subprocess
    import sys
    from pathlib import Path

    script = _MEMORY_SCRIPT.format(benches=str(Path(__file__).resolve().parents[1]))
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    row = json.loads(out.stdout.strip().splitlines()[-1])
    return [
        {
            "case": "peak_memory_hull_and_sdf_256^3",
            "n": 256**3,
            "peak_mb": round(row["after_mb"], 1),
            "input_mb": round(row["before_mb"], 1),
            "added_mb": round(row["after_mb"] - row["before_mb"], 1),
        }
    ]
