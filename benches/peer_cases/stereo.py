"""Stereo: disparity on Tsukuba against StereoSGBM, least-squares matching against ECC, dense
points on the textured synthetic capture against SGBM's own points."""

from __future__ import annotations

import statistics
import time
from typing import Any

import numpy as np

from peer_cases._common import _compare, _time


def disparity_cases(repeats: int) -> list[dict[str, Any]]:
    """Tsukuba (Middlebury): elastocap's disparity stage against the best of the 864
    StereoSGBM settings of benches/sgbm_grid.py, both scored as bad-1 with unmatched pixels
    counted wrong (sgbm_grid.py prints the grid's details)."""
    from sgbm_grid import peer_disparity, peer_settings, score, tsukuba

    from elastocap.stereo import compute_disparity

    left, right, truth = tsukuba()
    best = min(peer_settings(), key=lambda setting: score(peer_disparity(left, right, setting), truth)[0])
    row = _compare(
        "tsukuba_disparity_384x288",
        left.shape[0] * left.shape[1],
        lambda: compute_disparity(left, right, min_disparity=0, num_disparities=16),
        "StereoSGBM, best of 864 settings",
        lambda: peer_disparity(left, right, best),
        repeats,
    )
    ours_bad, ours_matched = score(compute_disparity(left, right, min_disparity=0, num_disparities=16).disparity, truth)
    peer_bad, peer_matched = score(peer_disparity(left, right, best), truth)
    row.update(ours_bad=round(ours_bad, 4), peer_bad=round(peer_bad, 4), peer_bad_matched_only=round(peer_matched, 4), peer_setting=best)
    return [row]


def _lsm_mosaic(side: int, seed: int, searches: int = 1) -> tuple[np.ndarray, list[np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
    """``side^2`` independent 49x49 scenes tiled into one template and ``searches`` search
    images: per tile a procedural texture (24 sinusoids, wavelengths 6-30 px, contrast 35
    grey levels), an affine warp (scale 0.8-1.25, shear +-0.2, rotation +-15 degrees,
    aspect 0.9-1.1), gain 0.7-1.3, offset +-20, noise sigma 2 in every image, and a start
    with the identity linear part and the centre +-2 px off. Returns template, search
    images, points (P, 2), true maps (P, 2, 3), starts (P, 2, 3) in mosaic pixels."""
    n, half = 49, 24
    rng = np.random.default_rng(seed)
    template = np.zeros((side * n, side * n), np.float32)
    images = [np.zeros_like(template) for _ in range(searches)]
    g = np.arange(n, dtype=np.float64)
    U, V = np.meshgrid(g, g)
    points, truths, starts = [], [], []
    for k in range(side * side):
        r, c = divmod(k, side)
        angle, frequency, phase = rng.uniform(0, 2 * np.pi, 24), rng.uniform(2 * np.pi / 30, 2 * np.pi / 6, 24), rng.uniform(0, 2 * np.pi, 24)
        w = np.stack([frequency * np.cos(angle), frequency * np.sin(angle)], axis=1)
        texture = lambda u, v, w=w, phase=phase: 128 + 35 * np.sqrt(2 / 24) * np.sin(u[..., None] * w[:, 0] + v[..., None] * w[:, 1] + phase).sum(-1)  # noqa: E731
        scale, shear, rot, aspect = rng.uniform(0.8, 1.25), rng.uniform(-0.2, 0.2), np.deg2rad(rng.uniform(-15, 15)), rng.uniform(0.9, 1.1)
        gain, offset = rng.uniform(0.7, 1.3), rng.uniform(-20, 20)
        A = np.array([[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]]) @ np.array([[scale, shear * scale], [0, scale * aspect]])
        b = np.array([half, half]) + rng.uniform(-0.5, 0.5, 2)
        tile = (slice(r * n, (r + 1) * n), slice(c * n, (c + 1) * n))
        template[tile] = texture(U - half, V - half) + rng.normal(0, 2, (n, n))
        Y = np.stack([U - b[0], V - b[1]], axis=-1) @ np.linalg.inv(A).T
        clean = (texture(Y[..., 0], Y[..., 1]) - offset) / gain
        for image in images:
            image[tile] = clean + rng.normal(0, 2, (n, n))
        corner = np.array([c * n, r * n], np.float64)
        points.append(corner + half)
        truths.append(np.hstack([A, (corner + b)[:, None]]))
        starts.append(np.hstack([np.eye(2), (corner + b + rng.uniform(-2, 2, 2))[:, None]]))
    return template, images, np.array(points), np.array(truths), np.array(starts)


def lsm_cases(repeats: int) -> list[dict[str, Any]]:
    """Issue 14: least-squares matching of 400 11x11 patches (held-out seed 5000 of the
    scenes of tests/test_lsm.py: warps, gain/offset, noise 2, starts 2 px off) against
    cv2.findTransformECC(MOTION_AFFINE) on the same patches: the same 11x11 template crop,
    the tile as input image, the same start, no Gaussian pre-filter (gaussFiltSize 1), at
    most 30 iterations, both single-threaded. ECC stops on the change of its correlation
    (eps 1e-5, where its accuracy stops improving), ours on the 0.01 px shift update. Rows:
    bilinear and bicubic resampling; accuracy (RMS 2-D centre error) on the patches both
    matched, gross errors (> 0.5 px) counted apart; then the throughput with all cores
    (two search images per point)."""
    import cv2

    from elastocap.stereo import match_patches

    cv2.setNumThreads(1)
    side, n, half = 20, 49, 24
    template, images, points, truths, starts = _lsm_mosaic(side, 5000)
    search = images[0]
    crops = []
    for k in range(len(points)):
        r, c = divmod(k, side)
        patch = np.ascontiguousarray(template[r * n + half - 5 : r * n + half + 6, c * n + half - 5 : c * n + half + 6])
        tile = np.ascontiguousarray(search[r * n : (r + 1) * n, c * n : (c + 1) * n])
        b = starts[k, :, 2] - [c * n, r * n]
        crops.append((patch, tile, np.array([[1, 0, b[0] - 5], [0, 1, b[1] - 5]], np.float32), np.array([c * n, r * n])))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-5)

    def ecc() -> np.ndarray:
        out = np.full((len(crops), 2), np.nan)
        for k, (patch, tile, warp, corner) in enumerate(crops):
            try:
                _, w = cv2.findTransformECC(patch, tile, warp.copy(), cv2.MOTION_AFFINE, criteria, None, 1)
            except cv2.error:  # it raises where it does not converge
                continue
            out[k] = w[:, :2] @ [5.0, 5.0] + w[:, 2] + corner
        return out

    rows = []
    truth = truths[:, :, 2]
    peer_positions = ecc()
    peer_error = np.linalg.norm(peer_positions - truth, axis=1)
    for interpolation in ("bilinear", "bicubic"):
        # min_texture: twice the noise, as the default estimates it (not timed here: the
        # default estimates the noise over the whole 980x980 mosaic).
        ours = lambda interpolation=interpolation: match_patches(  # noqa: E731
            template, points, search, initial=starts[:, None], threads=1, min_texture=4.0, interpolation=interpolation
        )
        row = _compare(f"lsm_11x11_one_thread_{interpolation}", len(points), ours, "cv2.findTransformECC(MOTION_AFFINE), one thread", ecc, repeats)
        # CPU seconds too (this process, all threads): the machine is shared and loaded.
        cpu_ours, cpu_peer = [], []
        for _ in range(repeats):
            start_cpu = time.process_time()
            ours()
            cpu_ours.append(time.process_time() - start_cpu)
            start_cpu = time.process_time()
            ecc()
            cpu_peer.append(time.process_time() - start_cpu)
        row.update(
            ours_cpu_s=round(statistics.median(cpu_ours), 6),
            peer_cpu_s=round(statistics.median(cpu_peer), 6),
            cpu_ratio=round(statistics.median(cpu_peer) / statistics.median(cpu_ours), 2),
        )
        m = ours()
        converged = m.status[:, 0] == 0
        error = np.linalg.norm(m.positions[:, 0] - truth, axis=1)
        both = converged & np.isfinite(peer_error)
        fine = both & (error < 0.5) & (peer_error < 0.5)
        rms = lambda e: round(float(np.sqrt(np.mean(e**2))), 4)  # noqa: E731
        row.update(
            ours_us_per_patch=round(row["ours_s"] / len(points) * 1e6, 1),
            peer_us_per_patch=round(row["peer_s"] / len(points) * 1e6, 1),
            ours_matched=int(converged.sum()),
            peer_matched=int(np.isfinite(peer_error).sum()),
            ours_gross=int((converged & (error >= 0.5)).sum()),
            peer_gross=int((np.isfinite(peer_error) & (peer_error >= 0.5)).sum()),
            ours_rms_px=rms(error[both]),
            peer_rms_px=rms(peer_error[both]),
            ours_rms_px_no_gross=rms(error[fine]),
            peer_rms_px_no_gross=rms(peer_error[fine]),
        )
        rows.append(row)
    template2, images2, points2, _, starts2 = _lsm_mosaic(side, 5001, searches=2)
    initial = np.repeat(starts2[:, None], 2, axis=1)
    run = lambda: match_patches(template2, points2, images2, initial=initial, min_texture=4.0)  # noqa: E731
    run()
    times = [_time(run) for _ in range(repeats)]
    median = statistics.median(times)
    rows.append(
        {
            "case": "lsm_11x11_two_images_all_cores",
            "n": len(points2),
            "ours_s": round(median, 6),
            "points_per_s": round(len(points2) / median),
            "matches_per_s": round(2 * len(points2) / median),
            "repeats": repeats,
        }
    )
    return rows


# ------------------------------------------------------------------------------------------
# Dense points on the textured synthetic capture (issue 14 item 7)
# ------------------------------------------------------------------------------------------

# Textured captures written once per seed (1024 x 768, 8 cameras in 4 pairs).
DENSE_CAPTURES = "/tmp/elastocap_bench_textured"


def textured_capture(seed: int, frames: int = 2) -> str:
    """The textured synthetic capture of ``seed`` (written on first use, then reused)."""
    from elastocap.synth import write_textured_capture

    root = f"{DENSE_CAPTURES}/seed{seed}"
    write_textured_capture(root, frames=frames, cameras=8, seed=seed, progress=False)
    return root


def score_points(points: np.ndarray, pixels: np.ndarray, pair: Any, truth: Any, mesh: Any, frame: int, step: float) -> dict[str, float]:
    """Issue 14's figures for one pair's points: distance to the ground-truth mesh in pixels
    of disparity (``distance * f B / Z^2``) and metres, the depth of 0.3 px of disparity,
    the share beyond 5 px, and the coverage of the surface points both cameras see (a point
    is covered when a template pixel lies within ``1.5 step`` px of its projection)."""
    from scipy.spatial import cKDTree

    distance = mesh.distances(points)
    depth = pair.left.to_camera(points)[:, 2]
    per_metre = pair.focal * pair.baseline / depth**2
    error = distance * per_metre
    left, right = truth.cameras.index(pair.left.name), truth.cameras.index(pair.right.name)
    both = truth.visible[frame, left] & truth.visible[frame, right]
    uv, _ = pair.left.project(truth.positions[frame][both])
    nearest = cKDTree(pixels).query(uv)[0] if len(pixels) else np.full(len(uv), np.inf)
    return {
        "points": len(points),
        "median_px": float(np.median(error)),
        "median_mm": 1000 * float(np.median(distance)),
        "depth_of_0.3px_mm": 1000 * float(np.median(0.3 / per_metre)),
        "beyond_5px": float((error > 5).mean()),
        "coverage": float((nearest <= 1.5 * step).mean()),
    }


def evaluate_dense(root: str, frames: list[int], **options: Any) -> list[dict[str, Any]]:
    """Per frame and pair: the stage's dense points (ours) and SGBM's checked disparity
    points in the same silhouette (the peer), scored by :func:`score_points`, with times."""
    import cv2
    import trimesh

    from elastocap import Capture
    from elastocap.geometry.mesh_distance import TriangleMesh
    from elastocap.pipeline.stereo import read_stereo_pairs
    from elastocap.stereo import rectify_pair
    from elastocap.stereo.disparity_stage import disparity_to_points, pair_disparity
    from elastocap.stereo.points import pair_points
    from elastocap.synth import load_textured_truth

    capture, truth = Capture.open(root), load_textured_truth(root)
    volume = np.array([[-1.5, -0.3, -1.5], [1.5, 2.1, 1.5]])
    rows = []
    for frame in frames:
        mesh = TriangleMesh(trimesh.load(truth.mesh_path(frame)))
        for left_name, right_name in read_stereo_pairs(root, capture.rig) or []:
            pair = rectify_pair(capture.rig[left_name], capture.rig[right_name])
            pair.maps  # built once per pair in the stage; not timed
            left, right = capture.image(pair.left.name, frame), capture.image(pair.right.name, frame)
            silhouette = capture.mask(pair.left.name, frame)
            mask = cv2.dilate(silhouette.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
            start = time.perf_counter()
            ours = pair_points(pair, left, right, volume, mask=mask, **options)
            ours_s = time.perf_counter() - start
            start = time.perf_counter()
            sgbm = pair_disparity(pair, left, right, volume, fill=False)
            inside = pair.rectify(silhouette.astype(np.uint8), silhouette.astype(np.uint8), interpolation=cv2.INTER_NEAREST)[0] > 0
            peer_points, peer_pixels = disparity_to_points(sgbm.disparity.disparity, pair, mask=sgbm.disparity.valid & inside)
            peer_s = time.perf_counter() - start
            # The peer's pixels are rectified: its coverage is measured in the left original.
            peer_original = pair.left.project(peer_points)[0]
            rows.append({
                "frame": frame, "pair": pair.name, "ours_s": round(ours_s, 3), "peer_s": round(peer_s, 3),
                "ours": score_points(ours.points, ours.pixels, pair, truth, mesh, frame, options.get("step", 2)),
                "sgbm": score_points(peer_points, peer_original, pair, truth, mesh, frame, 1.0),
            })
    return rows


def dense_cases(repeats: int) -> list[dict[str, Any]]:
    """Dense points of one pair of the textured capture (seed 2, held out from tuning):
    the stereo stage's pair_points (SGBM seeds + region-grown LSM + intersection) against
    SGBM's own checked points, time and accuracy in one row."""
    root = textured_capture(2)
    rows = evaluate_dense(root, [0])
    first = rows[0]
    return [{
        "case": f"dense_points_{first['pair']}_1024x768",
        "n": first["ours"]["points"],
        "ours_s": first["ours_s"],
        "peer": "StereoSGBM checked disparity -> points",
        "peer_s": first["peer_s"],
        "ratio": round(first["peer_s"] / first["ours_s"], 2),
        "repeats": 1,
        "ours_accuracy": first["ours"],
        "peer_accuracy": first["sgbm"],
    }]
