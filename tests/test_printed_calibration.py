"""Calibrations as real tools print them: rotations with 6 significant digits, both a
Rodrigues vector (R_) and a matrix (Rot_) per camera. They load with a CalibrationWarning
(the rotation projected onto the nearest one), carve the same hull as the full-precision
rig, and what no printing explains (a reflection, a scaled matrix, R_ and Rot_ describing
different rotations) is still refused with a message naming the camera."""

from __future__ import annotations

import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import elastocap
from elastocap import Camera, Rig
from elastocap.cameras import CalibrationWarning
from data_paths import TEMPLE

SIX_DIGITS = "{:.6g}"


def _matrix_yaml(key: str, matrix: np.ndarray, number: str) -> str:
    rows, cols = matrix.shape
    data = ", ".join(number.format(float(x)) for x in matrix.ravel())
    return f"{key}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {data} ]\n"


def print_rig(rig: Rig, folder: Path, number: str = SIX_DIGITS, rvec_number: str | None = None) -> None:
    """``rig`` as EasyMocap's intri.yml / extri.yml with every number printed by ``number``
    (a format string), both R_ (Rodrigues) and Rot_ (3x3) per camera, as real tools write
    them."""
    rvec_number = rvec_number or number
    names = "".join(f'   - "{name}"\n' for name in rig.names)
    intri = ["%YAML:1.0\n---\n", f"names:\n{names}"]
    extri = ["%YAML:1.0\n---\n", f"names:\n{names}"]
    for camera in rig.cameras:
        intri.append(_matrix_yaml(f"K_{camera.name}", camera.K, number))
        intri.append(_matrix_yaml(f"dist_{camera.name}", camera.dist[None], number))
        intri.append(f"H_{camera.name}: {camera.height}\nW_{camera.name}: {camera.width}\n")
        rvec, _ = cv2.Rodrigues(np.array(camera.R))
        extri.append(_matrix_yaml(f"R_{camera.name}", rvec, rvec_number))
        extri.append(_matrix_yaml(f"Rot_{camera.name}", camera.R, number))
        extri.append(_matrix_yaml(f"T_{camera.name}", camera.t[:, None], number))
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "intri.yml").write_text("".join(intri))
    (folder / "extri.yml").write_text("".join(extri))


def load_printed(folder: Path) -> tuple[Rig, list[warnings.WarningMessage]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rig = Rig.load(folder)
    return rig, [w for w in caught if issubclass(w.category, CalibrationWarning)]


def _rotation(seed: int) -> np.ndarray:
    rvec = np.random.default_rng(seed).normal(size=3)
    return cv2.Rodrigues(rvec)[0]


def camera_with(R: np.ndarray, name: str = "cam") -> Camera:
    K = [[800.0, 0.4, 320.0], [0.0, 790.0, 240.0], [0.0, 0.0, 1.0]]
    return Camera(name, K, [0.1, -0.05, 0.001, 0.002, 0.0], R, [0.1, 0.2, 3.0], 640, 480)


# ---------------------------------------------------------------------------------------
# the camera's rule
# ---------------------------------------------------------------------------------------


def test_an_exact_rotation_is_kept_bit_for_bit_without_a_warning():
    R = _rotation(0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        camera = camera_with(R)
    assert np.array_equal(camera.R, R)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), digits=st.integers(4, 8))
def test_a_printed_rotation_becomes_the_nearest_rotation_with_a_warning(seed, digits):
    R = _rotation(seed)
    printed = np.array([[float(f"{x:.{digits}g}") for x in row] for row in R])
    if np.abs(printed.T @ printed - np.eye(3)).max() <= 1e-12:
        return  # printing happened to keep it orthonormal
    with pytest.warns(CalibrationWarning, match=r"camera 'cam'.*nearest rotation.*changed by at most"):
        camera = camera_with(printed)
    assert np.abs(camera.R.T @ camera.R - np.eye(3)).max() < 1e-14
    assert np.linalg.det(camera.R) == pytest.approx(1.0, abs=1e-14)
    # The nearest rotation is at least as close to the truth as the printed matrix is, up
    # to the rounding itself.
    assert np.abs(camera.R - R).max() <= 2 * np.abs(printed - R).max() + 1e-15


def test_the_issue_camera_01_loads():
    # The message a real rig gave: max |R^T R - I| = 1.67e-06, det R = 0.999997843.
    R = _rotation(1) * (1.0 - 7.2e-7)
    with pytest.warns(CalibrationWarning, match="'01'"):
        camera = camera_with(R, "01")
    assert np.abs(camera.R - _rotation(1)).max() < 1e-12


@pytest.mark.parametrize(
    "matrix, message",
    [
        (np.diag([1.0, 1.0, -1.0]) @ _rotation(2), "reflection"),
        (1.01 * _rotation(3), "scaled"),
        (_rotation(4) + 0.01 * np.random.default_rng(4).normal(size=(3, 3)), "exceeds"),
        (np.zeros((3, 3)), "singular"),
        (np.outer([1.0, 2.0, 3.0], [1.0, 0.0, 0.0]), "singular"),
    ],
)
def test_what_printing_does_not_explain_is_refused(matrix, message):
    with pytest.raises(elastocap.InvalidInputError, match=rf"camera 'cam'.*{message}"):
        camera_with(matrix)


def test_printed_intrinsics_are_set_exactly():
    R = _rotation(5)
    K = [[800.0, 0.4, 320.0], [3e-9, 790.0, 240.0], [1e-9, -2e-9, 1.0000002]]
    camera = Camera("c", K, None, R, [0.0, 0.0, 3.0], 640, 480)
    assert camera.K[1, 0] == 0.0 and camera.K[2].tolist() == [0.0, 0.0, 1.0]
    assert camera.K[0, 1] == 0.4  # skew is kept
    with pytest.raises(elastocap.InvalidInputError, match=r"camera 'c'.*last row"):
        Camera("c", [[800.0, 0, 320.0], [0, 790.0, 240.0], [0, 0, 1.01]], None, R, [0, 0, 3.0], 640, 480)


# ---------------------------------------------------------------------------------------
# files printed to 6 digits with both R_ and Rot_
# ---------------------------------------------------------------------------------------


def test_a_synthetic_rig_printed_to_six_digits_loads_with_warnings(tmp_path):
    from elastocap.synth.capture import ring_rig

    rig = ring_rig(8, seed=3)
    print_rig(rig, tmp_path)
    loaded, caught = load_printed(tmp_path)
    assert loaded.names == rig.names
    assert caught, "6-digit rotations are not orthonormal to rounding: a warning is due"
    assert all(any(f"'{c.name}'" in str(w.message) for w in caught) for c in loaded.cameras[:1])
    for original, camera in zip(rig.cameras, loaded.cameras):
        assert np.abs(camera.R - original.R).max() < 5e-6
        assert np.abs(camera.R.T @ camera.R - np.eye(3)).max() < 1e-14
        np.testing.assert_allclose(camera.K, original.K, rtol=1e-5)
        # Reprojection of the scene changes by a small fraction of a pixel.
        points = np.random.default_rng(0).uniform(-0.5, 0.5, (200, 3)) + [0.0, 0.9, 0.0]
        uv0, _ = original.project(points)
        uv1, _ = camera.project(points)
        assert np.abs(uv1 - uv0).max() < 0.05


def test_rodrigues_and_matrix_must_agree_to_their_printed_precision(tmp_path):
    from elastocap.synth.capture import ring_rig

    rig = ring_rig(3, seed=4)
    # 17 digits: the check is as tight as the file; a disagreement of 1e-6 is refused.
    exact = tmp_path / "exact"
    print_rig(rig, exact, "{:.17g}")
    loaded, caught = load_printed(exact)
    assert not caught and all(np.array_equal(a.R, b.R) for a, b in zip(loaded.cameras, rig.cameras))
    text = (exact / "extri.yml").read_text()
    name = rig.names[1]
    rvec = cv2.Rodrigues(np.array(rig.cameras[1].R))[0].ravel()
    bumped = rvec + [1e-6, 0.0, 0.0]
    old = _matrix_yaml(f"R_{name}", rvec[:, None], "{:.17g}")
    assert old in text
    (exact / "extri.yml").write_text(text.replace(old, _matrix_yaml(f"R_{name}", bumped[:, None], "{:.17g}")))
    with pytest.raises(elastocap.InvalidInputError, match=rf"camera '{name}'.*Rot_{name} and R_{name}.*disagree"):
        Rig.load(exact)
    # 6 digits: the same 1e-6 (the real rig's 1.85e-06) is within what printing explains,
    # and the matrix wins.
    printed = tmp_path / "printed"
    print_rig(rig, printed, rvec_number="{:.6g}")
    text = (printed / "extri.yml").read_text()
    old = _matrix_yaml(f"R_{name}", rvec[:, None], "{:.6g}")
    (printed / "extri.yml").write_text(text.replace(old, _matrix_yaml(f"R_{name}", bumped[:, None], "{:.6g}")))
    loaded, _ = load_printed(printed)
    assert np.abs(loaded[name].R - rig[name].R).max() < 5e-6
    # ... but a different rotation is refused at any precision.
    (printed / "extri.yml").write_text(
        text.replace(old, _matrix_yaml(f"R_{name}", (rvec + [1e-2, 0, 0])[:, None], "{:.6g}"))
    )
    with pytest.raises(elastocap.InvalidInputError, match="disagree"):
        Rig.load(printed)


@pytest.mark.skipif(not TEMPLE.exists(), reason="shared data not present")
def test_the_temple_printed_to_six_digits_carves_the_same_hull(tmp_path):
    from test_hull import temple_rig_and_masks

    rig, masks, _, grid = temple_rig_and_masks()
    print_rig(rig, tmp_path)
    printed, caught = load_printed(tmp_path)
    assert len(caught) >= 1
    reference = elastocap.visual_hull(masks, rig, grid, footprint="center").occupancy
    carved = elastocap.visual_hull(masks, printed, grid, footprint="center").occupancy
    differing = np.count_nonzero(reference != carved) / reference.size
    print(f"temple printed to 6 digits: {differing:.2e} of the voxels differ")
    assert differing <= 1e-4
