"""Capture folders as users have them: videos per camera in any container OpenCV reads (and
PyAV when it cannot), masks as a video, unsynchronised starts (offsets), frames missing in
one camera (refused, skipped or carved with the cameras present, reported), 16-bit and
RGBA images."""

from __future__ import annotations

import builtins
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

import elastocap
from elastocap import visual_hull
from elastocap.hull import drop_phantoms
from elastocap.capture import Capture, CaptureWarning
from elastocap.capture import media
from elastocap.pipeline.hull import load_hull, run_hull_stage
from test_capture import HEIGHT, NAMES, WIDTH, frame_image, frame_mask, make_capture, make_rig
from test_hull import ring, render

CODECS = {".mp4": "mp4v", ".avi": "MJPG", ".mkv": "MJPG"}
# Compressed video changes 8-bit values by a few levels (MJPG at OpenCV's default quality).
VIDEO_LEVELS = 12


def write_video(file: Path, frames: list[np.ndarray]) -> None:
    """RGB (or grey) frames into ``file`` with a codec opencv-python-headless has."""
    file.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(file), cv2.VideoWriter_fourcc(*CODECS[file.suffix]), 10, (WIDTH, HEIGHT))
    if not writer.isOpened():
        pytest.skip(f"this OpenCV build cannot write {file.suffix}")
    for frame in frames:
        bgr = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR) if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)
        writer.write(bgr)
    writer.release()


def video_capture(root: Path, suffixes=(".mp4", ".avi"), frames=4, mask_suffix=".avi") -> Path:
    make_rig().save(root)
    for index, (name, suffix) in enumerate(zip(NAMES, suffixes)):
        write_video(root / "videos" / f"{name}{suffix}", [frame_image(index, f) for f in range(frames)])
        if mask_suffix:
            write_video(root / "masks" / f"{name}{mask_suffix}", [frame_mask(index, f) for f in range(frames)])
    return root


@pytest.mark.parametrize("suffixes", [(".mp4", ".avi"), (".mkv", ".mp4")])
def test_videos_in_any_container_and_masks_as_a_video(tmp_path, suffixes):
    with Capture.open(video_capture(tmp_path, suffixes)) as capture:
        assert capture.has_images and capture.has_masks and capture.frames == [0, 1, 2, 3]
        for frame in (3, 1, 2):
            for index, name in enumerate(NAMES):
                image = capture.image(name, frame)
                assert image.dtype == np.uint8 and image.shape == (HEIGHT, WIDTH, 3)
                np.testing.assert_allclose(image.reshape(-1, 3).mean(axis=0), frame_image(index, frame)[0, 0],
                                           atol=VIDEO_LEVELS)
                truth = frame_mask(index, frame) > 0
                mask = capture.mask(name, frame)
                assert (mask & truth).sum() / (mask | truth).sum() >= 0.9
        with pytest.raises(FileNotFoundError, match="has no frame 4"):
            capture.mask("cam0", 4)


def test_images_for_one_camera_and_a_video_for_another(tmp_path):
    root = make_capture(tmp_path, frames=(0, 1, 2), masks=None)
    for file in (root / "images" / "cam1").iterdir():
        file.unlink()
    (root / "images" / "cam1").rmdir()
    write_video(root / "videos" / "cam1.avi", [frame_image(1, f) for f in range(3)])
    capture = Capture.open(root)
    assert capture.frames == [0, 1, 2]
    np.testing.assert_array_equal(capture.image("cam0", 2), frame_image(0, 2))
    np.testing.assert_allclose(capture.image("cam1", 2).reshape(-1, 3).mean(axis=0), frame_image(1, 2)[0, 0],
                               atol=VIDEO_LEVELS)


def test_offsets_align_unsynchronised_starts(tmp_path):
    # cam0 recorded frames 0..5; cam1 started two frames late, so its file 000000 shows
    # capture frame 2, and its video (masks) likewise.
    root = make_capture(tmp_path, frames=range(6), masks=None)
    for file in sorted((root / "images" / "cam1").iterdir()):
        file.unlink()
    for n in range(4):
        cv2.imwrite(str(root / "images" / "cam1" / f"{n:06d}.png"), cv2.cvtColor(frame_image(1, n + 2), cv2.COLOR_RGB2BGR))
    write_video(root / "masks" / "cam0.avi", [frame_mask(0, f) for f in range(6)])
    write_video(root / "masks" / "cam1.avi", [frame_mask(1, f + 2) for f in range(4)])
    # Without offsets the recordings are cut to the span both cover (and out of sync).
    with pytest.warns(CaptureWarning, match=r"frame\(s\) 4, 5 \(lacking cam1\) cut: recordings of different"):
        unsynchronised = Capture.open(root)
    assert unsynchronised.frames == [0, 1, 2, 3] and unsynchronised.trimmed == {4: ["cam1"], 5: ["cam1"]}
    (root / "capture.toml").write_text("[offsets]\ncam1 = 2\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # with offsets, cut ends are expected: no warning
        capture = Capture.open(root)
    assert capture.frames == [2, 3, 4, 5] and not capture.skipped and capture.trimmed == {0: ["cam1"], 1: ["cam1"]}
    for frame in capture.frames:
        np.testing.assert_array_equal(capture.image("cam1", frame), frame_image(1, frame))
        truth = frame_mask(1, frame) > 0
        mask = capture.mask("cam1", frame)
        assert (mask & truth).sum() / (mask | truth).sum() >= 0.9
    with pytest.raises(FileNotFoundError, match=r"frame 1 of camera 'cam1' not found: no .*cam1/-00001"):
        capture.image("cam1", 1)


def test_missing_frames_skipped_or_kept_and_reported(tmp_path):
    names = ["cam0", "cam1", "cam2"]
    make_rig(names).save(tmp_path)
    for index, name in enumerate(names):
        (tmp_path / "masks" / name).mkdir(parents=True)
        for frame in range(4):
            if (name, frame) not in (("cam1", 2), ("cam1", 1), ("cam2", 1)):
                cv2.imwrite(str(tmp_path / "masks" / name / f"{frame:06d}.png"), frame_mask(index, frame))
    with pytest.raises(elastocap.InvalidInputError, match=r"masks/cam1 lacks frame\(s\) 1, 2 .*capture.toml"):
        Capture.open(tmp_path)
    with pytest.warns(CaptureWarning, match=r"missing = 'skip'\): frame\(s\) 1 \(lacking cam1, cam2\); 2 \(lacking cam1\) left out"):
        skipping = Capture.open(tmp_path, missing="skip")
    assert skipping.frames == [0, 3] and skipping.skipped == {1: ["cam1", "cam2"], 2: ["cam1"]}
    (tmp_path / "capture.toml").write_text('missing = "present"\n')
    with pytest.warns(CaptureWarning, match=r"1 \(lacking cam1, cam2\) left out; frame\(s\) 2 \(lacking cam1\) kept with the cameras present"):
        keeping = Capture.open(tmp_path)
    assert keeping.frames == [0, 2, 3] and keeping.incomplete == {2: ["cam1"]} and keeping.skipped == {1: ["cam1", "cam2"]}
    assert keeping.cameras_at(2) == ["cam0", "cam2"] and keeping.cameras_at(3) == names
    assert list(keeping.masks(2)) == ["cam0", "cam2"] and keeping.rig_at(2).names == ["cam0", "cam2"]
    assert keeping.rig_at(3) is keeping.rig


def test_hull_stage_carves_a_frame_with_the_cameras_present(tmp_path):
    rig = ring(4)
    mesh = trimesh.creation.icosphere(subdivisions=3)
    mesh.apply_scale(0.4)
    root = tmp_path / "capture"
    rig.save(root)
    for name, camera in zip(rig.names, rig.cameras):
        (root / "masks" / name).mkdir(parents=True)
        for frame in (0, 1, 2):
            if name == "cam3" and frame == 1:
                continue
            cv2.imwrite(str(root / "masks" / name / f"{frame:06d}.png"), render(mesh, camera).astype(np.uint8) * 255)
    (root / "capture.toml").write_text('missing = "present"\n')
    with pytest.warns(CaptureWarning, match="lacking cam3"):
        capture = Capture.open(root)
    assert run_hull_stage(capture, tmp_path / "out", resolution=40, frames=[0, 1], progress=False) == [0, 1]
    full, partial = load_hull(tmp_path / "out", 0), load_hull(tmp_path / "out", 1)
    # Three cameras carve less than four; the stage carved frame 1 with exactly those three.
    assert partial.volume > full.volume > 0.9 * 4 / 3 * np.pi * 0.4**3
    masks3 = {n: render(mesh, rig[n]) for n in rig.names[:3]}
    # (Less its phantoms: space the three see badly or not at all, 5x the sphere's voxels.)
    rig3 = elastocap.Rig(rig.cameras[:3])
    direct = drop_phantoms(visual_hull(masks3, rig3, partial.grid, footprint="center"), masks3, rig3)
    assert np.array_equal(direct.occupancy, partial.occupancy)
    centres = partial.grid.centers()
    assert partial.occupancy[np.linalg.norm(centres, axis=-1) < 0.4 - partial.grid.spacing].all()


def test_sixteen_bit_and_rgba_images(tmp_path):
    root = make_capture(tmp_path, frames=(0,))
    rgb = frame_image(0, 0).astype(np.uint16) * 257 + 3  # 16-bit, not a multiple of 257
    cv2.imwrite(str(root / "images" / "cam0" / "000000.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    rgba = np.dstack([cv2.cvtColor(frame_image(1, 0), cv2.COLOR_RGB2BGR), np.full((HEIGHT, WIDTH), 77, np.uint8)])
    cv2.imwrite(str(root / "images" / "cam1" / "000000.png"), rgba)
    # A 16-bit mask, and an RGBA cut-out whose alpha is the silhouette (RGB all set).
    cv2.imwrite(str(root / "masks" / "cam0" / "000000.png"), (frame_mask(0, 0) > 0).astype(np.uint16) * 40000)
    cutout = np.dstack([np.full((HEIGHT, WIDTH, 3), 90, np.uint8), frame_mask(1, 0)])
    cv2.imwrite(str(root / "masks" / "cam1" / "000000.png"), cutout)
    capture = Capture.open(root)
    np.testing.assert_array_equal(capture.image("cam0", 0), frame_image(0, 0))
    np.testing.assert_array_equal(capture.image("cam1", 0), frame_image(1, 0))  # alpha dropped
    np.testing.assert_array_equal(capture.mask("cam0", 0), frame_mask(0, 0) > 0)
    np.testing.assert_array_equal(capture.mask("cam1", 0), frame_mask(1, 0) > 0)
    opaque = np.dstack([np.where(frame_mask(1, 0)[..., None] > 0, 255, 0).repeat(3, 2), np.full((HEIGHT, WIDTH), 255)])
    cv2.imwrite(str(root / "masks" / "cam1" / "000000.png"), opaque.astype(np.uint8))
    np.testing.assert_array_equal(capture.mask("cam1", 0), frame_mask(1, 0) > 0)  # opaque: colour decides
    grey16 = np.full((HEIGHT, WIDTH), 65535, np.uint16)
    cv2.imwrite(str(root / "images" / "cam0" / "000000.png"), grey16)
    assert (capture.image("cam0", 0) == 255).all()
    assert media.to_uint8(np.array([0, 128, 257, 32896, 65535], np.uint16), "x").tolist() == [0, 0, 1, 128, 255]


def _opencv_cannot_open(monkeypatch):
    real = cv2.VideoCapture

    class Closed:
        def __init__(self, *args):
            real_capture = real()
            self._inner = real_capture

        def isOpened(self):
            return False

        def get(self, *args):
            return 0.0

        def release(self):
            pass

    monkeypatch.setattr(media.cv2, "VideoCapture", Closed)


def test_pyav_reads_what_opencv_cannot(tmp_path, monkeypatch):
    pytest.importorskip("av")
    root = video_capture(tmp_path, mask_suffix=None)
    _opencv_cannot_open(monkeypatch)
    with Capture.open(root) as capture:
        assert capture.frames == [0, 1, 2, 3]
        for frame in (2, 3, 0):
            np.testing.assert_allclose(capture.image("cam1", frame).reshape(-1, 3).mean(axis=0), frame_image(1, frame)[0, 0],
                                       atol=VIDEO_LEVELS)


def test_without_pyav_an_unreadable_video_says_what_would_help(tmp_path, monkeypatch):
    root = video_capture(tmp_path, mask_suffix=None)
    _opencv_cannot_open(monkeypatch)
    real_import = builtins.__import__

    def no_av(name, *args, **kwargs):
        if name == "av":
            raise ImportError("no av")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_av)
    with pytest.raises(elastocap.InvalidInputError, match=r"cam0.mp4: unreadable video .*pip install av"):
        Capture.open(root)


@pytest.mark.parametrize(
    ("config", "message"),
    [
        ("offset = 3\n", r"unknown key\(s\) \['offset'\]"),
        ('missing = "maybe"\n', "missing must be one of error, skip, present"),
        ("[offsets]\ncam9 = 1\n", r"offsets name camera\(s\) \['cam9'\]"),
        ("[offsets]\ncam1 = 1.5\n", "offsets.cam1 must be a whole number"),
        ("missing = \n", "not valid TOML"),
    ],
)
def test_bad_configuration_is_a_clear_error(tmp_path, config, message):
    root = make_capture(tmp_path)
    (root / "capture.toml").write_text(config)
    with pytest.raises(elastocap.InvalidInputError, match=message):
        Capture.open(root)


def test_configuration_converts_the_rig_to_metres_and_y_up(tmp_path):
    root = make_capture(tmp_path, frames=(0,))
    (root / "capture.toml").write_text('units = "mm"\nup = "z"\n')
    capture = Capture.open(root)
    before = make_rig()
    for a, b in zip(before.cameras, capture.rig.cameras):
        np.testing.assert_allclose(b.center, [a.center[0], a.center[2], -a.center[1]] / np.float64(1000), atol=1e-15)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert capture.frames == [0]
