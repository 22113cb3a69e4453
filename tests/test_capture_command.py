"""``elastocap capture`` on a capture folder of videos with background plates (no masks):
one command writes silhouettes, hulls, the fit, metrics, the report and the animation files;
a rerun resumes; options come from TOML and flags, and are written back."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from elastocap import InvalidInputError
from elastocap.pipeline.cli import main
from elastocap.pipeline.options import CaptureOptions, resolve_options
from elastocap.synth.capture import write_synthetic_capture

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

FPS = 25.0
SMALL = ["--resolution", "32", "--nodes", "200", "--quiet"]


def video_capture(root: Path, *, frames: int = 4, cameras: int = 4, size: tuple[int, int] = (160, 120)) -> Path:
    """A synthetic capture whose colour frames are MPEG-4 videos at 25 fps, without masks:
    the silhouettes must come from the background plates (the rendered ones are moved to
    true_masks/)."""
    write_synthetic_capture(root, frames=frames, cameras=cameras, image_size=size, progress=False)
    (root / "videos").mkdir()
    for camera in sorted((root / "images").iterdir()):
        writer = cv2.VideoWriter(str(root / "videos" / f"{camera.name}.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), FPS, size)
        for image in sorted(camera.iterdir()):
            writer.write(cv2.imread(str(image)))
        writer.release()
    shutil.rmtree(root / "images")
    (root / "masks").rename(root / "true_masks")  # kept aside to score the silhouettes
    return root


@pytest.fixture(scope="module")
def captured(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("capture_command")
    capture = video_capture(root / "dance")
    out = root / "out"
    assert main(["capture", str(capture), "--out", str(out), *SMALL]) == 0
    return capture, out


def test_one_command_from_videos_to_meshes_report_metrics_and_exports(captured):
    capture, out = captured
    frames = [f"{i:06d}" for i in range(4)]
    for camera in ("cam00", "cam03"):
        assert sorted(p.stem for p in (out / "masks" / camera).glob("*.png")) == frames
    for folder in ("hull", "fit"):
        assert sorted(p.stem for p in (out / folder).glob("*.ply")) == frames
    assert (out / "model" / "rest.npz").exists()
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["capture"]["fps"] == pytest.approx(FPS) and metrics["capture"]["fps_source"] == "videos"
    assert metrics["summary"]["frames"] == 4 and len(metrics["frames"]) == 4
    assert sorted(metrics["exports"]) == ["export/dance.glb", "export/dance.obj", "export/dance.pc2"]
    page = (out / "report.html").read_text()
    for picture in ("fit_views.png", "hull_views.png", "fit_plots.png"):
        assert picture in page and (out / picture).exists()
    assert "export/dance.glb" in page
    config = tomllib.loads((out / "capture.toml").read_text())
    assert config["capture"] == str(capture.resolve()) and config["fps"] == FPS and config["nodes"] == 200
    # The silhouettes from the background plates (against compressed video) hold all of
    # the rendered ones (a missed pixel would carve the hull) and not much more (the
    # figure's shadow and the codec's blur at 160 x 120 add a rim).
    for mask in (out / "masks").rglob("*.png"):
        found = cv2.imread(str(mask), cv2.IMREAD_GRAYSCALE) > 0
        true = cv2.imread(str(capture / "true_masks" / mask.parent.name / mask.name), cv2.IMREAD_GRAYSCALE) > 0
        assert (found & true).sum() / true.sum() > 0.99
        assert (found & true).sum() / (found | true).sum() > 0.6
    assert not list(out.rglob(".*.tmp")), "temporary files left behind"


def test_a_rerun_resumes_without_redoing_frames(captured):
    capture, out = captured
    stages = [out / "masks" / "cam01" / "000002.png", out / "hull" / "000002.npz", out / "fit" / "000002.npz"]
    stamps = [p.stat().st_mtime_ns for p in stages]
    (out / "fit" / "000003.ply").unlink()  # as if stopped during the last frame's fit
    assert main(["capture", str(capture), "--out", str(out), *SMALL]) == 0
    assert [p.stat().st_mtime_ns for p in stages] == stamps
    assert (out / "fit" / "000003.ply").exists()


def test_the_written_config_reruns_the_same_options(captured):
    capture, out = captured
    options, extra = resolve_options(out / "capture.toml")
    assert extra == {"capture": str(capture.resolve())}
    assert (options.nodes, options.resolution, options.fps, options.exports) == (200, 32, FPS, ("glb", "pc2"))


def test_flags_override_the_config_file_and_bad_keys_are_named(tmp_path, capsys):
    config = tmp_path / "capture.toml"
    config.write_text('nodes = 150\nresolution = 40\nexports = ["glb", "usd"]\nup = "z"\n')
    options, _ = resolve_options(config, {"nodes": 180, "resolution": None})
    assert (options.nodes, options.resolution, options.exports, options.up) == (180, 40, ("glb", "usd"), "z")
    assert resolve_options(None, {"exports": "pc2, glb"})[0].exports == ("pc2", "glb")
    config.write_text("node = 150\n")
    with pytest.raises(InvalidInputError, match="unknown option.*'node'"):
        resolve_options(config)
    config.write_text('nodes = "many"\n')
    with pytest.raises(InvalidInputError, match="capture.toml: option nodes must be a int"):
        resolve_options(config)
    with pytest.raises(InvalidInputError, match="need the body fit"):
        CaptureOptions(exports=("glb", "bvh"))
    with pytest.raises(InvalidInputError, match="units"):
        CaptureOptions(units="feet")
    assert main(["capture", str(tmp_path / "missing"), "--out", str(tmp_path / "out"), "--config", str(config)]) == 2
    assert "nodes must be" in capsys.readouterr().err


def test_silhouettes_must_be_possible_for_the_capture(tmp_path, capsys):
    capture = write_synthetic_capture(tmp_path / "cap", frames=1, cameras=2, image_size=(64, 48), progress=False)
    shutil.rmtree(capture / "background")
    assert main(["capture", str(capture), "--out", str(tmp_path / "out"), "--silhouettes", "background", *SMALL]) == 2
    assert "no background/ folder" in capsys.readouterr().err
    shutil.rmtree(capture / "images")
    shutil.rmtree(capture / "masks")
    assert main(["capture", str(capture), "--out", str(tmp_path / "out"), *SMALL]) == 2
    assert "no frames: it needs images/, videos/ or masks/" in capsys.readouterr().err
    assert not np.any([p.suffix == ".ply" for p in (tmp_path / "out").rglob("*")])
