"""``elastocap body CAPTURE --out OUT`` on a small synthetic capture: it runs, writes the
files DESIGN names, and locates the body (the synthetic figure is not the body model, so
only the placement is checked)."""

from __future__ import annotations

import json

import numpy as np

from elastocap.pipeline.cli import main


def test_body_command_writes_shape_motion_meshes_and_picture(tmp_path) -> None:
    capture, out = tmp_path / "capture", tmp_path / "out"
    assert main(["synth", "--out", str(capture), "--frames", "2", "--cameras", "4", "--quiet"]) == 0
    assert main(["body", str(capture), "--out", str(out), "--frames", "0", "--quiet"]) == 0
    record = json.loads((out / "body" / "fit.json").read_text())
    assert record["frames"] == [0]
    assert len(record["motion"][0]) == len(record["motion_names"])
    assert set(record["shape"]) == set(record["parts"])
    assert (out / "body" / "000000.ply").exists() and (out / "body_views.png").exists()
    # the pelvis ends up near the figure's hips: about 0.9 m above the floor (world y up)
    pelvis = np.array(record["R_body_to_world"]) @ np.array(record["motion"][0][:3])
    assert 0.6 < pelvis[1] < 1.2
    # a second run finds the result and does nothing
    assert main(["body", str(capture), "--out", str(out), "--frames", "0", "--quiet"]) == 0


def test_body_command_reports_a_missing_capture(tmp_path, capsys) -> None:
    assert main(["body", str(tmp_path / "nothing"), "--out", str(tmp_path / "out")]) != 0
    assert "elastocap body: error" in capsys.readouterr().err
