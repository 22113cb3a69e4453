"""`elastocap track` and `elastocap capture --tracks` make the elastic fit's tracks: seeded
at the fit's density (``pipeline.track.FIT_SPACING``) and with the fit's seeding
(``pipeline.track.FIT_TRACK_OPTIONS``), not at ``track_points``' own defaults."""

from __future__ import annotations

import inspect
import json

import numpy as np
import pytest

import elastocap
from elastocap import InvalidInputError
from elastocap.pipeline.cli import main
from elastocap.pipeline.options import CaptureOptions
from elastocap.pipeline.track import FIT_SPACING, FIT_TRACK_OPTIONS
from elastocap.tracking import load_tracks, track_points
from track_scene import write_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("track_cli_scene")
    write_scene(root, frames=3, cameras=6, seed=2, points=2500)
    return root


def test_the_track_command_seeds_at_the_fits_density(scene, tmp_path) -> None:
    # The tracker's own defaults stay coarser (its speed line) and seed a patch inside the
    # masks, only on its seeding frames; the command's are the fit's.
    assert FIT_SPACING < inspect.signature(track_points).parameters["spacing"].default
    assert inspect.signature(track_points).parameters["reseed_bare"].default == 0 < FIT_TRACK_OPTIONS["reseed_bare"]
    assert inspect.signature(track_points).parameters["seed_margin"].default is None
    out = tmp_path / "cli"
    assert main(["track", str(scene), "--out", str(out), "--quiet"]) == 0
    made = load_tracks(out)
    capture = elastocap.Capture.open(scene)
    dense = track_points(capture, spacing=FIT_SPACING, **FIT_TRACK_OPTIONS)
    np.testing.assert_array_equal(made.ids, dense.ids)
    np.testing.assert_array_equal(made.flags, dense.flags)
    np.testing.assert_allclose(made.positions, dense.positions, equal_nan=True)
    # Half the spacing: several times the seeds of the tracker's default.
    assert len(made.ids) >= 2 * len(track_points(capture).ids)


def test_the_track_command_takes_another_spacing(scene, tmp_path) -> None:
    out = tmp_path / "coarse"
    assert main(["track", str(scene), "--out", str(out), "--spacing", "10", "--quiet"]) == 0
    made = load_tracks(out)
    default = track_points(elastocap.Capture.open(scene), **FIT_TRACK_OPTIONS)
    np.testing.assert_array_equal(made.ids, default.ids)
    np.testing.assert_allclose(made.positions, default.positions, equal_nan=True)


# A 200-node model of 32-voxel hulls is coarse: the report's reprojection warning is expected.
@pytest.mark.filterwarnings("ignore::elastocap.pipeline.reprojection.ReprojectionWarning")
def test_the_one_command_pipeline_tracks_for_the_fit_when_asked(scene, tmp_path) -> None:
    out = tmp_path / "capture"
    assert main(["capture", str(scene), "--out", str(out), "--tracks", "--track-spacing", "8", "--resolution", "32",
                 "--nodes", "200", "--exports", "pc2", "--fps", "25", "--quiet"]) == 0
    made = load_tracks(out)
    coarse = track_points(elastocap.Capture.open(scene), spacing=8, **FIT_TRACK_OPTIONS)
    np.testing.assert_array_equal(made.ids, coarse.ids)
    # The fit stage used them (and says so).
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["summary"]["tracks"] == len(made.ids) > 0
    assert "tracks" in metrics["stages_seconds_this_run"]


def test_the_one_command_pipeline_does_not_track_by_default_and_refuses_a_bad_spacing(tmp_path) -> None:
    assert not CaptureOptions().tracks and CaptureOptions().track_spacing == FIT_SPACING
    with pytest.raises(InvalidInputError, match="track_spacing"):
        CaptureOptions(track_spacing=1)
