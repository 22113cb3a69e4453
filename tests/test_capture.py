"""Capture folders: listing, lazy reading, RGB order, the mask/ alias, videos, and one test
per kind of bad input."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

import elastocap
from elastocap.cameras import Camera, Rig
from elastocap.capture.folder import Capture

WIDTH, HEIGHT = 32, 24
NAMES = ["cam0", "cam1"]


def make_rig(names=NAMES, width=WIDTH, height=HEIGHT) -> Rig:
    K = [[40.0, 0.0, width / 2], [0.0, 40.0, height / 2], [0.0, 0.0, 1.0]]
    return Rig(Camera(name, K, None, np.eye(3), [0.0, 0.0, 3.0 + i], width, height) for i, name in enumerate(names))


def frame_mask(camera_index: int, frame: int) -> np.ndarray:
    """A distinct mask per camera and frame: a rectangle whose corner moves."""
    mask = np.zeros((HEIGHT, WIDTH), np.uint8)
    mask[2 + frame: 10 + frame, 3 + camera_index: 15 + camera_index] = 255
    return mask


def frame_image(camera_index: int, frame: int) -> np.ndarray:
    """A distinct RGB image per camera and frame."""
    rgb = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    rgb[..., 0] = 200  # red
    rgb[..., 1] = 10 * frame
    rgb[..., 2] = 30 * camera_index
    return rgb


def make_capture(
    root: Path,
    frames=(0, 1, 2),
    *,
    masks: str | None = "masks",
    images: bool = True,
    rig: Rig | None = None,
) -> Path:
    (rig or make_rig()).save(root)
    for index, name in enumerate(NAMES):
        for frame in frames:
            if masks:
                (root / masks / name).mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(root / masks / name / f"{frame:06d}.png"), frame_mask(index, frame))
            if images:
                (root / "images" / name).mkdir(parents=True, exist_ok=True)
                bgr = cv2.cvtColor(frame_image(index, frame), cv2.COLOR_RGB2BGR)
                cv2.imwrite(str(root / "images" / name / f"{frame:06d}.png"), bgr)
    return root


# ------------------------------------------------------------------------------------------
# reading
# ------------------------------------------------------------------------------------------


def test_listing(tmp_path):
    capture = Capture.open(make_capture(tmp_path, frames=(0, 1, 5)))
    assert capture.cameras == NAMES
    assert capture.frames == [0, 1, 5]
    assert capture.has_masks and capture.has_images and not capture.has_background
    assert capture.rig == make_rig()
    assert "2 cameras, 3 frames" in repr(capture)


def test_calibration_only(tmp_path):
    make_rig().save(tmp_path)
    capture = Capture.open(tmp_path)
    assert capture.frames == [] and not capture.has_masks and not capture.has_images
    with pytest.raises(FileNotFoundError, match="no masks/"):
        capture.mask("cam0", 0)
    with pytest.raises(FileNotFoundError, match="no images/ or videos/"):
        capture.image("cam0", 0)


def test_masks_and_images(tmp_path):
    capture = Capture.open(make_capture(tmp_path))
    mask = capture.mask("cam1", 2)
    assert mask.dtype == bool and mask.shape == (HEIGHT, WIDTH)
    np.testing.assert_array_equal(mask, frame_mask(1, 2) > 0)
    masks = capture.masks(1)
    assert list(masks) == NAMES
    for index, name in enumerate(NAMES):
        np.testing.assert_array_equal(masks[name], frame_mask(index, 1) > 0)
    image = capture.image("cam1", 2)
    assert image.dtype == np.uint8 and image.shape == (HEIGHT, WIDTH, 3)
    np.testing.assert_array_equal(image, frame_image(1, 2))
    assert image[0, 0].tolist() == [200, 20, 30]  # RGB, not BGR


def test_nothing_is_read_when_opening(tmp_path, monkeypatch):
    root = make_capture(tmp_path)
    reads: list[str] = []
    imread = cv2.imread
    monkeypatch.setattr(cv2, "imread", lambda file, *args: reads.append(file) or imread(file, *args))
    capture = Capture.open(root)
    assert capture.frames == [0, 1, 2] and reads == []
    capture.mask("cam0", 1)
    assert reads == [str(root / "masks" / "cam0" / "000001.png")]


def test_mask_alias_and_mask_encodings(tmp_path):
    root = make_capture(tmp_path, masks="mask", images=False)
    # A colour mask and a 0/1 mask count as non-zero = foreground too.
    colour = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    colour[5:9, 5:9] = (0, 0, 255)
    cv2.imwrite(str(root / "mask" / "cam0" / "000000.png"), colour)
    cv2.imwrite(str(root / "mask" / "cam1" / "000000.png"), (frame_mask(1, 0) > 0).astype(np.uint8))
    capture = Capture.open(root)
    assert capture.has_masks and not capture.has_images and capture.frames == [0, 1, 2]
    assert capture.mask("cam0", 0).sum() == 16
    np.testing.assert_array_equal(capture.mask("cam1", 0), frame_mask(1, 0) > 0)


def test_background(tmp_path):
    root = make_capture(tmp_path)
    (root / "background").mkdir()
    cv2.imwrite(str(root / "background" / "cam0.jpg"), np.full((HEIGHT, WIDTH, 3), (10, 20, 30), np.uint8))
    capture = Capture.open(root)
    assert capture.has_background
    background = capture.background("cam0")
    assert background.shape == (HEIGHT, WIDTH, 3)
    np.testing.assert_allclose(background[HEIGHT // 2, WIDTH // 2], [30, 20, 10], atol=2)  # RGB
    with pytest.raises(FileNotFoundError, match="no background for camera 'cam1'"):
        capture.background("cam1")


def test_video(tmp_path):
    make_rig().save(tmp_path)
    (tmp_path / "videos").mkdir()
    for index, name in enumerate(NAMES):
        writer = cv2.VideoWriter(str(tmp_path / "videos" / f"{name}.mp4"), cv2.VideoWriter_fourcc(*"mp4v"),
                                 10, (WIDTH, HEIGHT))
        if not writer.isOpened():
            pytest.skip("this OpenCV build cannot write mp4")
        for frame in range(4):
            writer.write(np.full((HEIGHT, WIDTH, 3), (0, 40 * frame, 200), np.uint8))  # BGR
        writer.release()
    with Capture.open(tmp_path) as capture:
        assert capture.has_images and capture.frames == [0, 1, 2, 3]
        for frame in (2, 3, 0):  # forward, sequential, then back
            image = capture.image("cam1", frame)
            assert image.shape == (HEIGHT, WIDTH, 3)
            np.testing.assert_allclose(image.reshape(-1, 3).mean(axis=0), [200, 40 * frame, 0], atol=12)
        with pytest.raises(FileNotFoundError, match="no frame 4"):
            capture.image("cam0", 4)


# ------------------------------------------------------------------------------------------
# bad input
# ------------------------------------------------------------------------------------------


def test_missing_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="capture folder not found"):
        Capture.open(tmp_path / "nowhere")


def test_no_calibration(tmp_path):
    (tmp_path / "masks" / "cam0").mkdir(parents=True)
    with pytest.raises(FileNotFoundError, match=r"has no calibration.*intri.yml"):
        Capture.open(tmp_path)


def test_missing_camera_folder(tmp_path):
    root = make_capture(tmp_path, images=False)
    for file in (root / "masks" / "cam1").iterdir():
        file.unlink()
    (root / "masks" / "cam1").rmdir()
    with pytest.raises(FileNotFoundError, match=r"camera folder missing: .*masks/cam1"):
        Capture.open(root)


def test_frames_missing_in_one_camera(tmp_path):
    root = make_capture(tmp_path, frames=(0, 1, 2, 3))
    (root / "images" / "cam1" / "000002.png").unlink()
    with pytest.raises(elastocap.InvalidInputError, match=r"images/cam1/? lacks frame\(s\) 2 "):
        Capture.open(root)
    capture = Capture.open(root, strict=False)
    assert capture.frames == [0, 1, 3]
    with pytest.raises(FileNotFoundError, match="frame 2 of camera 'cam1' not found"):
        capture.image("cam1", 2)


def test_image_size_disagrees_with_calibration(tmp_path):
    root = make_capture(tmp_path)
    cv2.imwrite(str(root / "masks" / "cam0" / "000001.png"), np.zeros((HEIGHT, WIDTH + 1), np.uint8))
    capture = Capture.open(root)
    with pytest.raises(elastocap.InvalidInputError, match=r"000001.png is 33x24 but .* 'cam0' says 32x24"):
        capture.mask("cam0", 1)


def test_unreadable_file(tmp_path):
    root = make_capture(tmp_path)
    (root / "images" / "cam1" / "000002.png").write_bytes(b"not an image")
    capture = Capture.open(root)
    with pytest.raises(elastocap.InvalidInputError, match=r"cam1/000002.png: unreadable image"):
        capture.image("cam1", 2)


def test_unknown_camera_and_bad_frame(tmp_path):
    capture = Capture.open(make_capture(tmp_path))
    with pytest.raises(elastocap.InvalidInputError, match="camera 'cam7' is not in the rig"):
        capture.mask("cam7", 0)
    with pytest.raises(elastocap.InvalidInputError, match=r"\bframe\b must be an integer"):
        capture.mask("cam0", 1.0)  # type: ignore[arg-type]


def test_two_files_for_one_frame(tmp_path):
    root = make_capture(tmp_path)
    cv2.imwrite(str(root / "images" / "cam0" / "000001.jpg"), frame_image(0, 1))
    with pytest.raises(elastocap.InvalidInputError, match="two files for frame 1"):
        Capture.open(root)


def test_masks_and_mask_both_present(tmp_path):
    root = make_capture(tmp_path)
    (root / "mask").mkdir()
    with pytest.raises(elastocap.InvalidInputError, match="both masks/ and mask/"):
        Capture.open(root)


def test_size_from_images_when_calibration_lacks_it(tmp_path):
    root = make_capture(tmp_path)
    for file in ("intri.yml",):
        text = (root / file).read_text()
        (root / file).write_text("\n".join(line for line in text.splitlines() if not line.startswith(("H_", "W_"))))
    capture = Capture.open(root)
    assert capture.rig["cam0"].size == (WIDTH, HEIGHT)
