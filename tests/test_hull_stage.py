"""The hull stage on a small synthetic capture: files, resume, accuracy against the ground
truth, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

import elastocap

from elastocap import InvalidInputError
from elastocap.pipeline.hull import load_hull, parse_frames, run_hull_stage
from elastocap.synth.capture import write_synthetic_capture


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("capture")
    return write_synthetic_capture(out, frames=3, cameras=8, spacing=0.02, image_size=(320, 240), progress=False)


def test_writes_every_frame_and_resumes_without_redoing(capture, tmp_path):
    written = run_hull_stage(capture, tmp_path, resolution=48, progress=False)
    assert written == [0, 1, 2]
    files = sorted((tmp_path / "hull").iterdir())
    assert [f.name for f in files] == [f"{i:06d}.{ext}" for i in range(3) for ext in ("npz", "ply")]
    stamps = {f: f.stat().st_mtime_ns for f in files}
    assert run_hull_stage(capture, tmp_path, resolution=48, progress=False) == []
    assert stamps == {f: f.stat().st_mtime_ns for f in files}
    # An interrupted run loses only the unfinished frame.
    (tmp_path / "hull" / "000001.ply").unlink()
    assert run_hull_stage(capture, tmp_path, resolution=48, progress=False) == [1]
    assert not list((tmp_path / "hull").glob(".*")), "temporary files left behind"


def test_hull_contains_the_ground_truth_and_hugs_it(capture, tmp_path):
    run_hull_stage(capture, tmp_path, resolution=64, frames=[0], progress=False)
    hull = load_hull(tmp_path, 0)
    truth = trimesh.load(capture / "ground_truth" / "000000.ply")
    sdf = hull.sdf()
    on_truth = sdf.sample(truth.sample(3000))
    # The carving is of rendered silhouettes at 320x240: allow a voxel and a pixel or so.
    assert np.quantile(on_truth, 0.99) <= 1.5 * hull.grid.spacing
    assert hull.volume / truth.volume < 1.6
    surface = trimesh.load(tmp_path / "hull" / "000000.ply")
    assert surface.is_watertight
    # The signed distance the stage saved is the one read back (not computed again), and
    # it is the occupancy's own to float32 precision.
    with np.load(tmp_path / "hull" / "000000.npz") as data:
        np.testing.assert_array_equal(sdf.values, data["sdf"].astype(np.float64))
    recomputed = elastocap.SDF.from_occupancy(hull.occupancy, hull.grid).values
    np.testing.assert_allclose(sdf.values, recomputed, rtol=1e-6, atol=1e-7 * hull.grid.spacing)


def test_parse_frames():
    assert parse_frames("1:3", [0, 1, 2, 3, 4]) == [1, 2]
    assert parse_frames(":2", [0, 1, 2]) == [0, 1]
    assert parse_frames("2", [0, 1, 2]) == [2]
    assert parse_frames(None, [0, 1]) is None
    with pytest.raises(InvalidInputError, match="--frames"):
        parse_frames("a:b", [0])


def test_bad_input(capture, tmp_path):
    with pytest.raises(InvalidInputError, match="not in the capture"):
        run_hull_stage(capture, tmp_path, frames=[99], progress=False)
    with pytest.raises(InvalidInputError, match="phantoms must be 'drop' or 'keep'"):
        run_hull_stage(capture, tmp_path, phantoms="maybe", progress=False)
    empty = tmp_path / "nomasks"
    empty.mkdir()
    with pytest.raises((InvalidInputError, FileNotFoundError)):
        run_hull_stage(empty, tmp_path, progress=False)


def test_a_camera_with_an_all_black_mask_stops_with_its_name(capture, tmp_path):
    import shutil

    import cv2

    broken = tmp_path / "broken"
    shutil.copytree(capture, broken)
    mask_file = broken / "masks" / "cam03" / "000001.png"
    cv2.imwrite(str(mask_file), np.zeros_like(cv2.imread(str(mask_file), cv2.IMREAD_GRAYSCALE)))
    out = tmp_path / "out"
    with pytest.raises(InvalidInputError, match=r"frame 1: .*cam03"):
        run_hull_stage(broken, out, resolution=32, progress=False)
    assert (out / "hull" / "000000.ply").exists(), "the frame before the bad one is kept"


def test_grid_seen_by_the_rig_holds_the_figure(capture):
    from elastocap import Capture, Grid

    cap = Capture.open(capture)
    grid = Grid.seen_by(cap.rig, 32)
    truth = trimesh.load_mesh(capture / "ground_truth" / "000000.ply")
    lower, upper = grid.bounds
    assert np.all(truth.bounds[0] >= lower) and np.all(truth.bounds[1] <= upper)
