"""The command line: the demo writes sound metrics; bad input exits non-zero with one line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from elastocap.pipeline.cli import main


def test_demo_writes_metrics_that_agree_with_the_references(tmp_path: Path) -> None:
    assert main(["demo", "--out", str(tmp_path), "--points", "3000", "--frames", "2", "--cameras", "8", "--quiet"]) == 0
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert (tmp_path / "hull_views.png").stat().st_size > 10_000
    for frame in metrics["hull"]["frames"]:
        # The ground truth lies inside the hull, to within a voxel.
        assert frame["truth_surface_outside_hull_max_m"] <= frame["voxel_m"]
        assert frame["truth_volume_m3"] < frame["hull_volume_m3"] < 2 * frame["truth_volume_m3"]
    assert len(metrics["neighbours"]) == 3
    for cloud in metrics["neighbours"]:
        assert cloud["knn_max_distance_error_vs_ckdtree"] < 1e-12
        assert cloud["radius_rows_matching_ckdtree_counts"] == 1.0
    polar = metrics["polar"]
    assert polar["max_orthonormality_error"] < 1e-12
    assert polar["min_det"] > 1 - 1e-12
    assert polar["max_difference_to_svd_rotation"] < 1e-6
    # The body fit on its own small capture: legs found, skin pictured in the report.
    body = metrics["body"]
    assert body["leg_joint_angle_rms_deg"] < 6.0
    assert (tmp_path / body["picture"]).stat().st_size > 10_000
    assert body["picture"] in (tmp_path / "report.html").read_text()
    assert not list(tmp_path.rglob("*.tmp")), "an atomic write left a temporary file"


def test_bad_demo_input_exits_non_zero_with_one_line(tmp_path: Path) -> None:
    run = subprocess.run(
        [sys.executable, "-m", "elastocap", "demo", "--out", str(tmp_path), "--points", "5"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert run.returncode == 2
    assert run.stderr.strip().count("\n") == 0
    assert "n_points must be at least 100" in run.stderr


def test_unknown_command_is_a_usage_error() -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["carve-everything"])
    assert exit_info.value.code == 2
