"""``elastocap demo``: ``elastocap capture`` on a synthetic capture (the same code path as on
real data), measured against its ground truth, and the kernels checked against scipy and
numpy.

Writes ``OUT/capture/`` (the synthetic capture), ``OUT/hull/`` (hull surfaces and signed
distances per frame), ``OUT/model/`` and ``OUT/fit/`` (the elastic model and its fit through
every frame), ``OUT/report.html`` with ``fit_views.png`` (fitted surfaces over camera
images), ``fit_strip.png`` (the sequence), ``fit_plots.png`` (error and volume per frame)
and ``hull_views.png``, ``OUT/export/capture.glb``, ``.pc2`` and ``.obj`` (the fitted
sequence as animation files), and ``OUT/metrics.json`` (what was measured). Rerunning resumes:
finished frames are not redone.
"""

from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from tqdm import tqdm

import elastocap
from elastocap._validate import as_count
from elastocap.capture.folder import Capture
from elastocap.pipeline.capture import run_capture
from elastocap.pipeline.hull import load_hull
from elastocap.pipeline.options import CaptureOptions
from elastocap.synth.capture import write_synthetic_capture

__all__ = ["run_demo"]

# The synthetic capture's frame rate: 30 frames are one walk cycle of about a second.
DEMO_FPS = 30.0


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
    (distances, indices), seconds = _timed(lambda: elastocap.knn(points, k))
    (ref_distances, _), ref_seconds = _timed(lambda: cKDTree(points).query(points, k=k + 1, workers=-1))
    radius = float(np.median(distances[:, -1]))
    (_, _, indptr), radius_seconds = _timed(lambda: elastocap.radius_neighbors(points, radius))
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


# The polar decomposition is timed on all the matrices but checked against numpy's SVD on
# this many of them: the SVD of a million took 2.5 s of the demo's minute.
_POLAR_CHECKED = 100_000


def _polar_check(n: int, rng: np.random.Generator) -> dict[str, Any]:
    matrices = rng.normal(size=(n, 3, 3))
    rotations, seconds = _timed(lambda: elastocap.polar_rotation(matrices))
    checked = min(n, _POLAR_CHECKED)
    u, _, vt = np.linalg.svd(matrices[:checked])
    sign = np.sign(np.linalg.det(u @ vt))
    u[:, :, 2] *= sign[:, None]
    reference = u @ vt
    identity_error = np.abs(np.swapaxes(rotations, 1, 2) @ rotations - np.eye(3)).max()
    return {
        "matrices": n,
        "checked_against_svd": checked,
        "seconds": round(seconds, 4),
        "max_orthonormality_error": float(identity_error),
        "min_det": float(np.linalg.det(rotations).min()),
        "max_difference_to_svd_rotation": float(np.abs(rotations[:checked] - reference).max()),
    }


def _hull_metrics(capture_dir: Path, out: Path, frames: list[int]) -> list[dict[str, Any]]:
    """Per frame: hull volume against the ground truth's, and how far the ground-truth
    surface lies from the hull's zero level (it should lie inside, within a voxel or so)."""
    import trimesh

    rows = []
    for frame in frames:
        hull = load_hull(out, frame)
        truth = trimesh.load_mesh(capture_dir / "ground_truth" / f"{frame:06d}.ply")
        d = hull.sdf().sample(truth.sample(5000))
        rows.append(
            {
                "frame": frame,
                "voxel_m": hull.grid.spacing,
                "hull_volume_m3": round(hull.volume, 6),
                "truth_volume_m3": round(float(truth.volume), 6),
                "truth_surface_outside_hull_max_m": round(float(d.max()), 5),
                "truth_surface_depth_in_hull_median_m": round(float(-np.median(d)), 5),
            }
        )
    return rows


def _truth_distance(capture_dir: Path, frame: int, meshes: list[Any]) -> list[float]:
    """Mean distance of each mesh's vertices to the frame's ground-truth surface."""
    from elastocap.geometry._distance import distance_to_mesh

    truth = trimesh.load_mesh(capture_dir / "ground_truth" / f"{frame:06d}.ply")
    # At most 4,000 vertices per mesh (the hull's surface has about 12,000): a frame's mean
    # is then known to about 0.2 mm and the sequence's to about 0.04 mm, at a third of the time.
    rng = np.random.default_rng(frame)
    samples = [np.asarray(m.vertices) for m in meshes]
    samples = [v if len(v) <= 4000 else v[rng.choice(len(v), 4000, replace=False)] for v in samples]
    return [float(distance_to_mesh(v, truth).mean()) for v in samples]


class _TruthFigures:
    """The capture command's report hook: each fitted frame's distance to the ground truth
    (and the hull's), kept in ``rows`` and ``summary`` for metrics.json."""

    def __init__(self, capture_dir: Path, out: Path) -> None:
        self.capture_dir, self.out = capture_dir, out
        self.rows: list[dict[str, Any]] = []
        self.summary: dict[str, Any] = {}

    def __call__(self, fit: Any) -> tuple[dict[str, Sequence[float]], dict[str, Any]]:
        rows = self.rows
        for frame in fit.frames:
            hull_surface_mesh = trimesh.load_mesh(self.out / "hull" / f"{frame:06d}.ply")  # as the hull stage wrote it
            fitted, hull_surface = _truth_distance(self.capture_dir, frame, [fit.surface(frame), hull_surface_mesh])
            rows.append({"frame": frame, "fit_to_truth_mean_m": fitted, "hull_to_truth_mean_m": hull_surface, **fit.fits[frame].metrics})
        self.summary = {
            "mean fit-to-truth distance (mm)": 1000 * float(np.mean([r["fit_to_truth_mean_m"] for r in rows])),
            "mean hull-to-truth distance (mm)": 1000 * float(np.mean([r["hull_to_truth_mean_m"] for r in rows])),
            "volume ratio min": float(min(r.get("volume_ratio", 1.0) for r in rows)),
            "volume ratio max": float(max(r.get("volume_ratio", 1.0) for r in rows)),
        }
        series: dict[str, Sequence[float]] = {
            "fit to truth (mm)": [1000 * r["fit_to_truth_mean_m"] for r in rows],
            "hull to truth (mm)": [1000 * r["hull_to_truth_mean_m"] for r in rows],
        }
        return series, self.summary


def _body(out: Path, progress: bool) -> dict[str, Any]:
    """The body stage on a small capture of the body model itself (1 frame, 6 cameras,
    320x240, so it takes ~10 s): skin over the camera views and the error against the
    written truth, added to report.html."""
    from elastocap.pipeline.body import run_body_stage
    from elastocap.pipeline.report import add_body_section

    capture_dir = write_synthetic_capture(
        out / "body_capture", frames=1, cameras=6, image_size=(320, 240), figure="body", seed=1, progress=False
    )
    body_out = out / "body_fit"
    result, seconds = _timed(lambda: run_body_stage(capture_dir, body_out, max_rays_per_mask=500, progress=progress))
    fit = json.loads(Path(result).read_text())
    truth = json.loads((capture_dir / "ground_truth" / "body.json").read_text())
    error = np.degrees(np.array(fit["motion"])[:, 6:] - np.array(truth["motion"])[: len(fit["motion"]), 6:])
    names = truth["motion_names"][6:]
    legs = [i for i, n in enumerate(names) if n.split(".")[0][2:] in ("thigh", "shin", "foot")]
    metrics = {
        "seconds_this_run": round(seconds, 2),
        "joint_angle_rms_deg": round(float(np.sqrt(np.mean(error**2))), 2),
        "leg_joint_angle_rms_deg": round(float(np.sqrt(np.mean(error[:, legs] ** 2))), 2),
        # Share of the observations (mask rays) within reach of the fitted skin, worst frame.
        "explained": round(min(q["explained"] for q in fit["quality"]), 3),
        "picture": str((body_out / "body_views.png").relative_to(out)),
    }
    report = out / "report.html"
    if report.exists():
        add_body_section(report, metrics)
    return metrics


def run_demo(
    out: Path,
    *,
    n_points: int = 100_000,
    frames: int = 30,
    cameras: int = 8,
    resolution: int = 128,
    n_nodes: int = 2500,
    progress: bool = True,
) -> Path:
    """Run the demo and write ``out/metrics.json`` (and the capture, hulls and picture).

    Parameters
    ----------
    out : path
        Output folder, created if missing; a second run resumes the first.
    n_points : int
        Points per generated cloud of the kernel checks (and ten times as many matrices).
    frames, cameras : int
        Size of the synthetic capture.
    resolution : int
        Voxels along the longest side of each hull's grid.
    n_nodes : int
        Nodes of the elastic model fitted through the sequence.
    progress : bool
        Show progress bars.

    Returns
    -------
    path
        The metrics file.
    """
    n_points = as_count("n_points", n_points)
    if n_points < 100:
        raise elastocap.InvalidInputError(f"n_points must be at least 100, got {n_points}")
    out.mkdir(parents=True, exist_ok=True)
    capture_dir = write_synthetic_capture(
        out / "capture", frames=as_count("frames", frames), cameras=as_count("cameras", cameras, minimum=2), progress=progress
    )
    capture = Capture.open(capture_dir)
    options = CaptureOptions(resolution=resolution, nodes=as_count("n_nodes", n_nodes, minimum=50), fps=DEMO_FPS)
    truth = _TruthFigures(capture_dir, out)
    run = run_capture(capture_dir, out, options, progress=progress, report_figures=truth)
    results: dict[str, Any] = {
        "capture": {"frames": len(capture.frames), "cameras": len(capture.cameras), "fps": run.fps},
        "hull": {"seconds_this_run": run.stages["hull"], "frames": _hull_metrics(capture_dir, out, capture.frames)},
        "picture": "hull_views.png",
        "neighbours": [],
        "fit": {
            "summary": {"frames fitted": len(truth.rows), "nodes": options.nodes, "fit seconds (this run)": run.stages["fit"], **truth.summary},
            "frames": truth.rows,
            "report": "report.html",
        },
        "stages_seconds_this_run": run.stages,
        "exports": [str(p.relative_to(out)) for p in run.exports],
    }
    results["body"] = _body(out, progress)
    rng = np.random.default_rng(0)
    steps = [
        ("knn: uniform cube", lambda: _neighbour_check("uniform cube", rng.random((n_points, 3)), 20)),
        ("knn: torus surface", lambda: _neighbour_check("torus surface", _surface_points(n_points, rng), 20)),
        ("knn: 2-D disc", lambda: _neighbour_check("2-D disc", rng.normal(size=(n_points, 2)), 12)),
        ("polar decomposition", lambda: _polar_check(10 * n_points, rng)),
    ]
    with tqdm(steps, desc="kernels", unit="step", disable=not progress) as bar:
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
