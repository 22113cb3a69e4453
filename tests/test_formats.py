"""Calibration formats: every format round-trips (exactly where it stores the same numbers,
to rounding where it stores the rotation another way), detection by name and content,
COLMAP's and OpenGL's conventions on hand-made cameras, refusals naming what a format
cannot hold, units and up axes."""

from __future__ import annotations

import json
import struct
import warnings

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import elastocap
from elastocap import Camera, Rig
from tolerances import PROJECTION_ATOL_PX

# output name -> (format, exact R, exact t, distortion coefficients it holds, skew)
FORMATS = {
    "easy": ("easymocap", True, True, 12, True),
    "rig.json": ("json", True, True, 12, True),
    "rig_par.txt": ("middlebury", True, True, 0, True),
    "cameras.txt": ("colmap", False, True, 8, False),
    "cameras.bin": ("colmap-binary", False, True, 8, False),
    "calib.toml": ("anipose", False, True, 12, True),
    "stereo.yml": ("opencv-stereo", True, True, 12, True),
    "transforms.json": ("nerf", True, False, 5, False),
}
# Rounding of a rotation stored as a quaternion or Rodrigues vector, or of a camera centre
# turned back into t: a few units in the last place of entries of size ~1 (R) or of the
# rig's size (t, here ~5). A Rodrigues vector near a half turn loses a few more digits
# (hypothesis found 2.1e-14 there).
ROTATION_ROUNDING = 1e-13
TRANSLATION_ROUNDING = 1e-13


def make_camera(name, fx, fy, cx, cy, skew, dist, rvec, t, size) -> Camera:
    K = [[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]
    return Camera(name, K, dist, cv2.Rodrigues(np.asarray(rvec, float))[0], t, *size)


def holdable(camera: Camera, coefficients: int, skew: bool) -> Camera:
    dist = np.zeros(12)
    dist[:coefficients] = camera.full_dist[:coefficients]
    K = np.array(camera.K)
    if not skew:
        K[0, 1] = 0.0
    return camera.replace(K=K, dist=dist)


def save_and_load(rig: Rig, folder, name: str) -> Rig:
    target = rig.save(folder / name)
    return Rig.load(target, size=(rig.cameras[0].width, rig.cameras[0].height) if "par" in name else None)


def assert_round_trip(rig: Rig, back: Rig, exact_R: bool, exact_t: bool, exact_K: bool = True) -> None:
    assert back.names == rig.names
    for a, b in zip(rig.cameras, back.cameras):
        assert (a.width, a.height) == (b.width, b.height)
        if exact_K:
            assert np.array_equal(a.K, b.K), (a.K, b.K)
        else:  # cx + 0.5 stored as a double: one unit in its last place at most
            assert np.abs(a.K - b.K).max() <= np.spacing(np.abs(a.K[:2, 2]).max() + 0.5), (a.K, b.K)
        assert np.array_equal(a.dist, b.dist), (a.dist, b.dist)
        if exact_R:
            assert np.array_equal(a.R, b.R)
        else:
            assert np.abs(a.R - b.R).max() <= ROTATION_ROUNDING
        if exact_t:
            assert np.array_equal(a.t, b.t)
        else:
            assert np.abs(a.t - b.t).max() <= TRANSLATION_ROUNDING


finite = st.floats(allow_nan=False, allow_infinity=False)
cameras = st.builds(
    make_camera,
    name=st.just("cam"),
    fx=st.floats(50, 5000), fy=st.floats(50, 5000),
    cx=st.floats(0, 2000), cy=st.floats(0, 2000),
    skew=st.floats(-2, 2),
    dist=st.lists(st.floats(-0.3, 0.3), min_size=12, max_size=12).map(lambda d: np.array(d) * 0.1),
    rvec=st.lists(st.floats(-3, 3), min_size=3, max_size=3),
    t=st.lists(st.floats(-5, 5), min_size=3, max_size=3),
    size=st.tuples(st.integers(1, 4000), st.integers(1, 4000)),
)


@pytest.mark.parametrize("name", list(FORMATS))
@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(first=cameras, second=cameras)
def test_every_format_round_trips(tmp_path, name, first, second):
    fmt, exact_R, exact_t, coefficients, skew = FORMATS[name]
    first = holdable(first.replace(name="left"), coefficients, skew)
    second = holdable(second.replace(name="right"), coefficients, skew)
    if fmt == "middlebury":  # the format has no image size: one size= for all cameras
        second = second.replace(width=first.width, height=first.height)
    rig = Rig([first, second])
    if fmt == "opencv-stereo":
        rig = rig.relative_to("left")
    back = save_and_load(rig, tmp_path, name)
    assert_round_trip(rig, back, exact_R, exact_t, exact_K=fmt != "colmap-binary")


@pytest.mark.parametrize("name", ["cameras.txt", "transforms.json"])
def test_half_pixel_shift_is_exact_even_where_float_addition_rounds(tmp_path, name):
    # cx + 0.5 crosses a power of two and cx's last bit is set: float arithmetic would
    # lose it; the text formats shift in exact decimal arithmetic.
    cx = np.nextafter(255.75, 256.0)
    assert (cx + 0.5) - 0.5 != cx
    camera = make_camera("c", 800, 800, cx, 239.5, 0, None, [0.1, 0.2, 0.3], [0, 0, 3], (640, 480))
    back = save_and_load(Rig([camera]), tmp_path, name)
    assert back.cameras[0].K[0, 2] == cx


def test_colmap_binary_half_pixel_is_off_by_one_ulp_at_most(tmp_path):
    cx = np.nextafter(255.75, 256.0)
    camera = make_camera("c", 800, 800, cx, 239.5, 0, None, [0.1, 0.2, 0.3], [0, 0, 3], (640, 480))
    back = save_and_load(Rig([camera]), tmp_path, "cameras.bin").cameras[0]
    assert abs(back.K[0, 2] - cx) <= np.spacing(256.0)


# ---------------------------------------------------------------------------------------
# conventions on hand-made cameras
# ---------------------------------------------------------------------------------------


def colmap_text(folder, model: str, params: str, pose: str = "1 0 0 0 0 0 0") -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "cameras.txt").write_text(f"# a comment\n1 {model} 640 480 {params}\n")
    (folder / "images.txt").write_text(f"# comment\n7 {pose} 1 view.png\n\n")


def test_colmap_principal_point_is_moved_half_a_pixel(tmp_path):
    colmap_text(tmp_path, "PINHOLE", "800 810 320 240")
    camera = Rig.load(tmp_path).cameras[0]
    assert camera.name == "view"
    assert camera.K.tolist() == [[800, 0, 319.5], [0, 810, 239.5], [0, 0, 1]]
    # COLMAP maps camera point (x, y, z) to the corner-origin pixel (fx x/z + cx, fy y/z + cy);
    # the same point lies half a pixel up and left in pixel-centre coordinates.
    X = np.array([[0.1, -0.2, 2.0], [0.0, 0.0, 1.0]])
    colmap_pixel = np.column_stack([800 * X[:, 0] / X[:, 2] + 320, 810 * X[:, 1] / X[:, 2] + 240])
    np.testing.assert_allclose(camera.project(X)[0], colmap_pixel - 0.5, atol=1e-12)
    # So the centre of the top-left pixel, COLMAP's (0.5, 0.5), is elastocap's (0, 0).
    _, direction = camera.rays(np.array([[0.0, 0.0]]))
    np.testing.assert_allclose(direction[0] / direction[0, 2], [(0.5 - 320) / 800, (0.5 - 240) / 810, 1], atol=1e-15)


@pytest.mark.parametrize(
    ("model", "params", "K", "dist"),
    [
        ("SIMPLE_PINHOLE", "700 320 240", [700, 700, 319.5, 239.5], [0, 0, 0, 0, 0]),
        ("SIMPLE_RADIAL", "700 320 240 0.1", [700, 700, 319.5, 239.5], [0.1, 0, 0, 0, 0]),
        ("RADIAL", "700 320 240 0.1 -0.02", [700, 700, 319.5, 239.5], [0.1, -0.02, 0, 0, 0]),
        ("OPENCV", "700 710 320 240 0.1 -0.02 0.001 0.002", [700, 710, 319.5, 239.5], [0.1, -0.02, 0.001, 0.002, 0]),
        ("FULL_OPENCV", "700 710 320 240 0.1 -0.02 0.001 0.002 0.01 0.2 0.03 0.004", [700, 710, 319.5, 239.5],
         [0.1, -0.02, 0.001, 0.002, 0.01, 0.2, 0.03, 0.004]),
    ],
)
def test_colmap_models_read_and_write_back_the_same_model(tmp_path, model, params, K, dist):
    colmap_text(tmp_path / "in", model, params)
    camera = Rig.load(tmp_path / "in").cameras[0]
    assert [camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]] == K
    assert camera.dist.tolist() == dist
    Rig([camera]).save(tmp_path / "out" / "cameras.txt")
    line = (tmp_path / "out" / "cameras.txt").read_text().splitlines()[-1].split()
    assert line[1] == model and [float(v) for v in line[4:]] == [float(v) for v in params.split()]


def test_colmap_binary_written_by_hand_reads_like_the_text(tmp_path):
    cameras = struct.pack("<Q", 1) + struct.pack("<iiQQ", 3, 4, 640, 480) + struct.pack("<8d", 700, 710, 320, 240, 0.1, -0.02, 0.001, 0.002)
    q = np.array([0.9, 0.1, -0.2, 0.3])
    images = struct.pack("<Q", 1) + struct.pack("<idddddddi", 5, *q, 0.1, 0.2, 3.0, 3) + b"sub/view.jpg\x00"
    images += struct.pack("<Q", 2) + struct.pack("<ddq", 1.0, 2.0, -1) * 2
    (tmp_path / "cameras.bin").write_bytes(cameras)
    (tmp_path / "images.bin").write_bytes(images)
    camera = Rig.load(tmp_path).cameras[0]
    colmap_text(tmp_path / "text", "OPENCV", "700 710 320 240 0.1 -0.02 0.001 0.002", " ".join(repr(float(v)) for v in [*q, 0.1, 0.2, 3.0]))
    assert camera == Rig.load(tmp_path / "text").cameras[0].replace(name="view")
    w, x, y, z = q / np.linalg.norm(q)
    expected = cv2.Rodrigues(np.array([x, y, z]) / np.linalg.norm([x, y, z]) * 2 * np.arccos(w))[0]
    np.testing.assert_allclose(camera.R, expected, atol=1e-14)


def test_nerf_opengl_axes_on_a_hand_made_camera(tmp_path):
    # A Blender camera at (0, 0, 5) with the identity rotation looks down world -z, with
    # world +x to its right and world +y up in its image.
    document = {"camera_angle_x": 0.6911112070083618,
                "frames": [{"file_path": "./train/r_0", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 5], [0, 0, 0, 1]]}]}
    (tmp_path / "transforms.json").write_text(json.dumps(document))
    camera = Rig.load(tmp_path, size=(800, 800)).cameras[0]
    assert camera.name == "r_0"
    f = 400 / np.tan(0.6911112070083618 / 2)
    assert camera.K.tolist() == [[f, 0, 399.5], [0, f, 399.5], [0, 0, 1]]
    np.testing.assert_array_equal(camera.center, [0, 0, 5])
    uv, depth = camera.project(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 6.0]]))
    assert depth[0] == 5 and depth[3] < 0  # the origin is in front, a point above the camera behind
    np.testing.assert_allclose(uv[0], [399.5, 399.5])
    assert uv[1, 0] > 399.5 and uv[1, 1] == 399.5  # world +x: right
    assert uv[2, 1] < 399.5 and uv[2, 0] == 399.5  # world +y: up in the image


def test_nerf_per_frame_intrinsics_and_image_size_from_the_image(tmp_path):
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((30, 40), np.uint8))
    document = {"fl_x": 50.0, "fl_y": 51.0, "cx": 20.0, "cy": 15.0, "k1": 0.1,
                "frames": [{"file_path": "a", "transform_matrix": np.eye(4).tolist()},
                           {"file_path": "b.jpg", "transform_matrix": np.eye(4).tolist(), "fl_x": 60.0, "w": 40, "h": 30}]}
    (tmp_path / "transforms.json").write_text(json.dumps(document))
    a, b = Rig.load(tmp_path / "transforms.json").cameras
    assert (a.width, a.height, a.K[0, 0], a.K[0, 2], a.dist[0]) == (40, 30, 50.0, 19.5, 0.1)
    assert b.K[0, 0] == 60.0 and b.K[1, 1] == 51.0


# ---------------------------------------------------------------------------------------
# refusals
# ---------------------------------------------------------------------------------------


def plain(name="c", dist=None, skew=0.0, fy=800.0) -> Camera:
    return make_camera(name, 800.0, fy, 320.0, 240.0, skew, dist, [0.1, 0.2, 0.3], [0, 0, 3], (640, 480))


@pytest.mark.parametrize(
    ("camera", "name", "message"),
    [
        (plain(skew=0.5), "cameras.txt", r"camera 'c' has skew .* no COLMAP camera model"),
        (plain(skew=0.5), "transforms.json", r"camera 'c' has skew .* NeRF transforms.json format cannot hold"),
        (plain(dist=np.r_[np.zeros(8), 1e-3, 0, 0, 0]), "cameras.bin", r"thin-prism distortion s1-s4 .* no COLMAP"),
        (plain(dist=[0, 0, 0, 0, 0, 0.1, 0, 0]), "transforms.json", r"k4 = 0.1, which the NeRF .* k1 k2 p1 p2 k3"),
        (plain(dist=[0.1]), "rig_par.txt", r"distortion .* Middlebury \*_par.txt format cannot hold"),
    ],
)
def test_what_a_format_cannot_hold_is_refused_by_name(tmp_path, camera, name, message):
    with pytest.raises(elastocap.InvalidInputError, match=message):
        Rig([camera]).save(tmp_path / name)


def test_a_chosen_colmap_model_too_small_is_refused(tmp_path):
    with pytest.raises(elastocap.InvalidInputError, match=r"p1 = 0.001, which COLMAP's RADIAL model cannot hold"):
        Rig([plain(dist=[0.1, 0, 0.001])]).save(tmp_path / "cameras.txt", model="RADIAL")
    with pytest.raises(elastocap.InvalidInputError, match=r"fx = 800.0 != fy = 810.0, which COLMAP's SIMPLE_RADIAL"):
        Rig([plain(dist=[0.1], fy=810.0)]).save(tmp_path / "cameras.txt", model="SIMPLE_RADIAL")
    Rig([plain(dist=[0.1], fy=810.0)]).save(tmp_path / "cameras.txt")
    assert " OPENCV " in (tmp_path / "cameras.txt").read_text()


def test_opencv_stereo_needs_a_pair_at_the_origin(tmp_path):
    with pytest.raises(elastocap.InvalidInputError, match="holds two cameras, the rig has 3"):
        Rig([plain("a"), plain("b"), plain("c")]).save(tmp_path / "s.yml")
    with pytest.raises(elastocap.InvalidInputError, match=r"camera 'a' is not at the origin .*relative_to\('a'\)"):
        Rig([plain("a"), plain("b")]).save(tmp_path / "s.yml")


@pytest.mark.parametrize(
    ("files", "message"),
    [
        ({"cameras.txt": "1 OPENCV_FISHEYE 640 480 700 710 320 240 0 0 0 0\n", "images.txt": "1 1 0 0 0 0 0 0 1 a.png\n\n"},
         "camera model OPENCV_FISHEYE is not supported"),
        ({"cameras.bin": struct.pack("<QiiQQ", 1, 1, 10, 640, 480) + bytes(8 * 16), "images.bin": struct.pack("<Q", 0)},
         "camera model THIN_PRISM_FISHEYE is not supported"),
        ({"calib.toml": '[cam_0]\nname = "a"\nsize = [640, 480]\nmatrix = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n'
                        "distortions = [0, 0, 0, 0]\nrotation = [0, 0, 0]\ntranslation = [0, 0, 0]\nfisheye = true\n"},
         "fisheye = true: the fisheye lens model is not supported"),
        ({"transforms.json": json.dumps({"camera_model": "OPENCV_FISHEYE", "fl_x": 1, "w": 4, "h": 4,
                                         "frames": [{"file_path": "a", "transform_matrix": np.eye(4).tolist()}]})},
         "camera_model 'OPENCV_FISHEYE' is not supported"),
        ({"transforms.json": json.dumps({"fl_x": 1, "w": 4, "h": 4, "k4": 0.01,
                                         "frames": [{"file_path": "a", "transform_matrix": np.eye(4).tolist()}]})},
         r"k4 = 0.01 \(nerfstudio's r\^8 radial term\)"),
        ({"cameras.txt": "1 PINHOLE 640 480 700 710 320 240\n", "images.txt": "1 1 0 0 0 0 0 0 1 a/x.png\n\n2 1 0 0 0 0 0 0 1 b/x.png\n\n"},
         "same stem 'x'"),
    ],
)
def test_unsupported_models_are_refused_on_reading(tmp_path, files, message):
    for name, content in files.items():
        (tmp_path / name).write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(elastocap.InvalidInputError, match=message):
        Rig.load(tmp_path)


# ---------------------------------------------------------------------------------------
# detection, other spellings, units and axes
# ---------------------------------------------------------------------------------------


def test_opencv_stereo_spellings_and_the_sample_pair_of_files(tmp_path):
    K1, K2 = plain().K, plain(fy=805.0).K
    R = cv2.Rodrigues(np.array([0.01, 0.2, 0.0]))[0]
    storage = cv2.FileStorage(str(tmp_path / "calib.yaml"), cv2.FILE_STORAGE_WRITE)
    for key, value in {"K1": K1, "D1": np.zeros((1, 5)), "K2": K2, "D2": np.array([[0.1, 0, 0, 0]]),
                       "R": cv2.Rodrigues(R)[0], "T": np.array([[-0.1], [0], [0]])}.items():
        storage.write(key, value)
    storage.write("image_width", 640)
    storage.write("image_height", 480)
    storage.release()
    left, right = Rig.load(tmp_path / "calib.yaml").cameras
    assert (left.name, right.name) == ("left", "right") and right.K[1, 1] == 805.0
    np.testing.assert_allclose(right.R, R, atol=1e-15)
    assert right.t.tolist() == [-0.1, 0, 0] and left.t.tolist() == [0, 0, 0]
    sample = tmp_path / "sample"
    sample.mkdir()
    intrinsics = cv2.FileStorage(str(sample / "intrinsics.yml"), cv2.FILE_STORAGE_WRITE)
    for key, value in {"M1": K1, "D1": np.zeros((1, 5)), "M2": K2, "D2": np.zeros((1, 5))}.items():
        intrinsics.write(key, value)
    intrinsics.release()
    extrinsics = cv2.FileStorage(str(sample / "extrinsics.yml"), cv2.FILE_STORAGE_WRITE)
    for key, value in {"R": R, "T": np.array([[-0.1], [0], [0]]), "R1": np.eye(3), "Q": np.eye(4)}.items():
        extrinsics.write(key, value)
    extrinsics.release()
    rig = Rig.load(sample, size=(640, 480))
    assert np.array_equal(rig["right"].R, R)


def test_a_folder_is_read_in_the_documented_order_and_sparse_0_is_found(tmp_path):
    rig = Rig([plain("a"), plain("b")])
    rig.save(tmp_path / "sparse" / "0" / "cameras.bin")
    assert Rig.load(tmp_path) == Rig.load(tmp_path / "sparse" / "0")
    rig.save(tmp_path / "rig.json")
    assert Rig.load(tmp_path) == rig  # rig.json comes before COLMAP
    with pytest.raises(elastocap.InvalidInputError, match="format must be one of"):
        Rig.load(tmp_path, format="bundler")
    assert Rig.load(tmp_path / "sparse" / "0", format="colmap-binary") == Rig.load(tmp_path / "sparse" / "0")


def test_units_and_up_axis(tmp_path):
    rig = Rig([plain("a"), make_camera("b", 700, 700, 300, 200, 0, [0.1], [1.0, -0.5, 0.2], [10, 20, 3000], (640, 480))])
    rig.save(tmp_path / "rig.json")
    metres = Rig.load(tmp_path / "rig.json", units="mm", up="z")
    X_mm = np.array([[100.0, 200.0, 300.0], [-50.0, 20.0, 2500.0]])
    # The same world point in metres and y up: (x, y, z) mm -> (x, z, -y) / 1000 m.
    X_m = np.column_stack([X_mm[:, 0], X_mm[:, 2], -X_mm[:, 1]]) / 1000
    for before, after in zip(rig.cameras, metres.cameras):
        np.testing.assert_allclose(after.project(X_m)[0], before.project(X_mm)[0], rtol=0, atol=PROJECTION_ATOL_PX)
        np.testing.assert_allclose(after.center, np.array([1, 0, 0, 0, 0, 1, 0, -1, 0.0]).reshape(3, 3) @ before.center / 1000,
                                   atol=1e-15)
    assert Rig.load(tmp_path / "rig.json", scale=0.001) == Rig.load(tmp_path / "rig.json", units="mm")
    for bad, message in [({"units": "inch"}, "units must be one of m, cm, mm"), ({"up": "w"}, "up must be one of"),
                         ({"units": "mm", "scale": 2.0}, "units or scale, not both"), ({"scale": -1.0}, "positive")]:
        with pytest.raises(elastocap.InvalidInputError, match=message):
            Rig.load(tmp_path / "rig.json", **bad)


def test_relative_to_keeps_every_projection(tmp_path):
    rig = Rig([plain("a"), make_camera("b", 700, 700, 300, 200, 0, [0.1], [1.0, -0.5, 0.2], [0.1, 0.2, 3], (640, 480))])
    moved = rig.relative_to("a")
    assert np.array_equal(moved["a"].R, np.eye(3)) and not moved["a"].t.any()
    X = np.random.default_rng(0).normal(size=(20, 3)) * 0.3
    X_moved = X @ rig["a"].R.T + rig["a"].t
    for before, after in zip(rig.cameras, moved.cameras):
        np.testing.assert_allclose(after.project(X_moved)[0], before.project(X)[0], atol=1e-9)


def test_printed_rotations_in_other_formats_load_with_a_warning(tmp_path):
    R = cv2.Rodrigues(np.array([0.3, -0.2, 0.1]))[0]
    c2w = np.eye(4)
    c2w[:3, :3] = np.round(R.T @ np.diag([1, -1, -1]), 6)
    document = {"fl_x": 500.0, "w": 64, "h": 48, "frames": [{"file_path": "a.png", "transform_matrix": c2w.tolist()}]}
    (tmp_path / "transforms.json").write_text(json.dumps(document))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        camera = Rig.load(tmp_path).cameras[0]
    assert any(issubclass(w.category, elastocap.cameras.CalibrationWarning) and "'a'" in str(w.message) for w in caught)
    np.testing.assert_allclose(camera.R, R, atol=2e-6)
