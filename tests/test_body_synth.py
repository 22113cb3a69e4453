"""Synthetic ground truth for the body model (issue 6, Build 7): the synth capture renders
the body model itself, ``elastocap body`` is scored against the written truth, and the
stage resumes frame by frame."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import scipy.ndimage as ndimage

import elastocap.pipeline.body as stage
from elastocap.body.model import Z_UP_TO_WORLD
from elastocap.synth.body import BodyFigure
from elastocap.cameras.rig import Rig
from elastocap.pipeline.cli import main
from elastocap.render import render_silhouette
from elastocap.synth.capture import write_synthetic_capture
from tolerances import (
    BODY_SYNTH_HEADING_DEG,
    BODY_SYNTH_LEG_ANGLE_DEG,
    BODY_SYNTH_ROOT_M,
    BODY_SYNTH_SHAPE_RTOL,
)

SEED = 1


@pytest.fixture(scope="module")
def body_capture(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A 2-frame body capture (6 cameras, 320x240) and the body stage's output on it."""
    root = tmp_path_factory.mktemp("body_synth")
    capture, out = root / "capture", root / "out"
    write_synthetic_capture(capture, frames=2, cameras=6, seed=SEED, image_size=(320, 240),
                            figure="body", progress=False)
    stage.run_body_stage(capture, out, max_rays_per_mask=600, progress=False)
    return capture, out


def test_truth_file_holds_the_model_shape_and_states(body_capture: tuple[Path, Path]) -> None:
    capture, _ = body_capture
    truth = json.loads((capture / "ground_truth" / "body.json").read_text())
    figure = BodyFigure.from_dict(truth)
    assert figure == BodyFigure(SEED) and truth["frames"] == 2
    np.testing.assert_array_equal(truth["shape"], figure.shape)
    assert np.abs(figure.shape - 1).max() <= 0.04 and np.abs(figure.shape - 1).max() > 0.01
    for n in range(2):
        np.testing.assert_array_equal(truth["motion"][n], figure.state(n).motion)
    motion = np.array(truth["motion"])
    assert np.all(motion >= figure.model.lower) and np.all(motion <= figure.model.upper)
    # A smooth motion: consecutive frames differ by a few degrees at most.
    assert np.degrees(np.abs(np.diff(motion[:, 6:], axis=0))).max() < 6.0
    # Resuming with the same settings rewrites nothing.
    stamps = {p: p.stat().st_mtime_ns for p in capture.rglob("*") if p.is_file()}
    write_synthetic_capture(capture, frames=2, cameras=6, seed=SEED, image_size=(320, 240), figure="body",
                            progress=False)
    assert stamps == {p: p.stat().st_mtime_ns for p in capture.rglob("*") if p.is_file()}


def test_masks_are_the_model_silhouette_to_a_pixel(body_capture: tuple[Path, Path]) -> None:
    """The rasterised skin mesh (what synth writes) against the model's exact silhouette
    (the field maximum along each pixel's ray): every differing pixel is on the outline."""
    capture, _ = body_capture
    figure = BodyFigure(SEED)
    mesh = figure.mesh(0)
    for camera in Rig.load(capture).cameras:
        raster = render_silhouette(mesh, camera)
        exact = figure.model.silhouette(figure.state(0), camera.replace(R=camera.R @ Z_UP_TO_WORLD))
        outline = ndimage.binary_dilation(raster) & ~ndimage.binary_erosion(raster)
        off_outline = (raster ^ exact) & ~ndimage.binary_dilation(outline)
        assert not off_outline.any(), camera.name
        assert raster.sum() > 500


def test_body_stage_recovers_legs_root_and_shape(body_capture: tuple[Path, Path]) -> None:
    capture, out = body_capture
    truth = json.loads((capture / "ground_truth" / "body.json").read_text())
    fit = json.loads((out / "body" / "fit.json").read_text())
    names = truth["motion_names"]
    got, want = np.array(fit["motion"]), np.array(truth["motion"])
    assert got.shape == want.shape
    legs = [i for i, n in enumerate(names) if n.split(".")[0][2:] in ("shin", "foot") or n[2:] in ("thigh.0", "thigh.2")]
    assert len(legs) == 8
    assert np.degrees(np.abs(got[:, legs] - want[:, legs])).max() <= BODY_SYNTH_LEG_ANGLE_DEG
    assert np.abs(got[:, :3] - want[:, :3]).max() <= BODY_SYNTH_ROOT_M
    assert np.degrees(np.abs(got[:, 3] - want[:, 3])).max() <= BODY_SYNTH_HEADING_DEG
    parts = truth["parts"]
    shape_truth = np.array(truth["shape"]).reshape(len(truth["parts"]), -1)  # (length, width, ...) per part
    for b, name in enumerate(parts):
        if name in ("pelvis", "head") or name[2:] in ("thigh", "shin", "foot"):
            fitted = fit["shape"][name]
            assert abs(fitted["length"] - shape_truth[b, 0]) <= BODY_SYNTH_SHAPE_RTOL, name
            assert abs(fitted["width"] - shape_truth[b, 1]) <= BODY_SYNTH_SHAPE_RTOL, name
    # Silhouettes alone: the tracker fits the narrow family, held exactly.
    assert all(s["depth"] == s["width"] and s["taper"] == 1.0 for s in fit["shape"].values())


def test_body_stage_resumes_per_frame(body_capture: tuple[Path, Path], tmp_path: Path,
                                      monkeypatch: pytest.MonkeyPatch) -> None:
    capture, finished = body_capture
    out = tmp_path / "out"
    shutil.copytree(finished, out)
    frames = out / "body" / "frames"
    assert sorted(p.name for p in frames.iterdir()) == ["000000.json", "000001.json"]
    # A run killed during frame 1: frame 0 saved, nothing after it.
    (out / "body" / "fit.json").unlink()
    (frames / "000001.json").unlink()
    stamp = (frames / "000000.json").stat().st_mtime_ns
    calls: list[str] = []
    tracker = stage.BodyTracker

    def counting(name: str) -> Any:
        real = getattr(tracker, name)

        def method(self: Any, *args: Any, **kwargs: Any) -> Any:
            calls.append(name)
            return real(self, *args, **kwargs)

        return method

    for name in ("update", "resume", "search"):
        monkeypatch.setattr(tracker, name, counting(name))
    stage.run_body_stage(capture, out, max_rays_per_mask=600, progress=False)
    # Frame 0 resumed from its saved state (no pose search), frame 1 tracked from it.
    assert calls == ["resume", "update"]
    assert (frames / "000000.json").stat().st_mtime_ns == stamp
    assert (frames / "000001.json").exists() and (out / "body" / "fit.json").exists()
    assert not list((out / "body").rglob(".*")), "temporary files left behind"


def test_synth_command_writes_a_body_capture(tmp_path: Path) -> None:
    capture = tmp_path / "capture"
    assert main(["synth", "--out", str(capture), "--frames", "1", "--cameras", "2", "--seed", "3",
                 "--figure", "body", "--quiet"]) == 0
    truth = json.loads((capture / "ground_truth" / "body.json").read_text())
    assert truth["seed"] == 3 and len(truth["motion"]) == 1
    assert not (capture / "ground_truth" / "figure.json").exists()
    assert (capture / "masks" / "cam01" / "000000.png").exists()
