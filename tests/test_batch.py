"""``elastocap batch`` on a LocalCluster of 2 worker processes: the same geometry as a serial
run, a corrupt take failing alone with its reason, reruns that skip what is done, and a
killed batch that resumes."""

from __future__ import annotations

import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")

from elastocap.pipeline.batch import find_takes, run_batch, run_take
from elastocap.pipeline.options import CaptureOptions
from elastocap.synth.capture import write_synthetic_capture

OPTIONS = CaptureOptions(resolution=32, nodes=120, fps=25.0)
GOOD = ["a", "b", "nested/d"]
# Per-frame timings: figures that differ between two runs.
TIMINGS = {"seconds", "solver_seconds"}
# The fit's per-frame figures other than positions (energy, distances) are sums over nodes
# that the Rust core reduces in parallel: the thread count changes their last bits.
FIGURE_RTOL, FIGURE_ATOL = 1e-9, 1e-15


@pytest.fixture(scope="module")
def takes(tmp_path_factory) -> Path:
    """Four small takes, one of them (``c``) with a corrupt mask file."""
    root = tmp_path_factory.mktemp("takes")
    for seed, name in enumerate(["a", "b", "c", "nested/d"]):
        write_synthetic_capture(root / name, frames=2, cameras=4, image_size=(96, 72), seed=seed, progress=False)
    corrupt = root / "c" / "masks" / "cam01" / "000001.png"
    corrupt.write_bytes(corrupt.read_bytes()[:20])
    (root / "notes").mkdir()  # not a take: no calibration
    return root


@pytest.fixture(scope="module")
def serial(takes, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("serial")
    run_batch(takes, out, OPTIONS, serial=True, progress=False)
    return out


def geometry(out: Path) -> tuple[dict[str, bytes], dict[str, np.ndarray]]:
    """Every geometry output of a take (masks, hulls, model, fit positions, exports) as
    bytes, and the fit's per-frame figures, timings aside."""
    files: dict[str, bytes] = {}
    figures: dict[str, np.ndarray] = {}
    for path in sorted(out.rglob("*")):
        relative = path.relative_to(out).as_posix()
        if not path.is_file() or relative.split("/")[0] not in ("hull", "fit", "model", "masks", "export"):
            continue
        if path.suffix == ".npz":
            with np.load(path) as data:
                for key in data.files:
                    if relative.startswith("fit/") and key != "positions":
                        if key not in TIMINGS:
                            figures[f"{relative}:{key}"] = data[key].astype(np.float64)
                    else:
                        files[f"{relative}:{key}"] = data[key].tobytes()
        else:
            files[relative] = path.read_bytes()
    return files, figures


def assert_same_geometry(out: Path, reference: Path) -> None:
    (files, figures), (expected_files, expected_figures) = geometry(out), geometry(reference)
    assert len(files) > 10 and files.keys() == expected_files.keys()
    assert [name for name in files if files[name] != expected_files[name]] == []
    assert figures.keys() == expected_figures.keys()
    for name, value in figures.items():
        np.testing.assert_allclose(value, expected_figures[name], rtol=FIGURE_RTOL, atol=FIGURE_ATOL, err_msg=name)


def test_takes_are_found_at_any_depth(takes):
    assert find_takes(takes) == ["a", "b", "c", "nested/d"]


def test_cluster_batch_matches_serial_and_isolates_the_bad_take(takes, serial, tmp_path):
    result = run_batch(takes, tmp_path, OPTIONS, workers=2, threads=1, progress=False)
    record = json.loads((tmp_path / "batch.json").read_text())
    assert record["summary"]["done"] == 3 and record["summary"]["failed"] == ["c"]
    assert record["takes"]["c"]["status"] == "failed"
    assert "masks/cam01/000001.png: unreadable image" in record["takes"]["c"]["reason"]
    index = (tmp_path / "index.html").read_text()
    assert "unreadable image" in index and "4 take(s), 1 failed" in index
    for take in GOOD:
        assert f'href="{take}/report.html"' in index
    assert 'href="c/report.html"' not in index
    for take in GOOD:
        assert record["takes"][take]["status"] == "done"
        assert record["takes"][take]["threads"] == "1"  # pinned in every worker
        assert record["takes"][take]["scheduler_seconds"] >= 0
        assert record["takes"][take]["exports"] == [f"export/{Path(take).name}.{e}" for e in ("glb", "obj", "pc2")]
        assert_same_geometry(tmp_path / take, serial / take)
    assert result.summary == record["summary"]
    # A rerun skips the takes done; the bad take is tried again and fails again alone.
    stamp = (tmp_path / "a" / "export" / "a.glb").stat().st_mtime_ns
    again = run_batch(takes, tmp_path, OPTIONS, serial=True, progress=False)
    assert again.summary["skipped_this_run"] == 3 and again.summary["ran_this_run"] == 1
    assert again.summary["failed"] == ["c"] and again.summary["done"] == 3
    assert (tmp_path / "a" / "export" / "a.glb").stat().st_mtime_ns == stamp


def test_a_task_takes_paths_and_returns_plain_data(tmp_path):
    arguments = (str(tmp_path / "missing"), str(tmp_path / "out"), json.loads(json.dumps(OPTIONS.__dict__)))
    assert pickle.loads(pickle.dumps(arguments)) == arguments
    outcome = run_take(*arguments)
    assert outcome["status"] == "failed" and outcome["reason"].startswith("FileNotFoundError: capture folder not found")
    assert json.loads(json.dumps(outcome)) == outcome


def test_a_killed_batch_resumes(takes, serial, tmp_path):
    out = tmp_path / "out"
    command = [sys.executable, "-m", "elastocap.pipeline.cli", "batch", str(takes), "--out", str(out), "--workers", "1",
               "--threads", "1", "--resolution", "32", "--nodes", "120", "--fps", "25", "--quiet"]
    process = subprocess.Popen(command, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    record = out / "batch.json"
    deadline = time.monotonic() + 240
    try:
        while time.monotonic() < deadline and process.poll() is None:
            if record.exists() and json.loads(record.read_text())["summary"]["done"] >= 1:
                break
            time.sleep(0.1)
    finally:
        os.killpg(process.pid, signal.SIGKILL)  # the batch, its cluster and its worker
        process.wait()
    first = json.loads(record.read_text())["takes"]
    done = [take for take, outcome in first.items() if outcome["status"] == "done"]
    assert 1 <= len(done) < 3, "the batch was not stopped halfway"
    stamps = {take: (out / take / "metrics.json").stat().st_mtime_ns for take in done}
    result = run_batch(takes, out, OPTIONS, serial=True, progress=False)
    assert result.summary["done"] == 3 and result.summary["skipped_this_run"] == len(done)
    assert {take: (out / take / "metrics.json").stat().st_mtime_ns for take in done} == stamps
    for take in GOOD:
        assert_same_geometry(out / take, serial / take)
