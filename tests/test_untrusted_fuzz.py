"""The loaders fuzzed (issue 13, items 4 and 6): random mutations of valid files of every
calibration format, of ``capture.toml`` and of a body model's JSON either load or raise
elastocap's own error (``ElastocapError``; ``FileNotFoundError`` for a file a folder format
lacks), never another exception, a panic or a hang. Hypothesis runs a bounded number of
examples per format (derandomised, see conftest.py)."""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from elastocap import BodyModel, Camera, ElastocapError, Rig
from elastocap.capture.config import read_config

# Examples per format in CI; ELASTOCAP_FUZZ_EXAMPLES=1000 HYPOTHESIS_PROFILE=explore searches longer.
EXAMPLES = int(os.environ.get("ELASTOCAP_FUZZ_EXAMPLES", "40"))
# The image size (Middlebury files do not hold it; the others must agree with it).
SIZE = (640, 480)

# name -> (file or folder to write with Rig.save, the file in it to mutate)
FORMATS = {
    "easymocap-intri": ("rig", "intri.yml"),
    "easymocap-extri": ("rig", "extri.yml"),
    "json": ("rig.json", "rig.json"),
    "middlebury": ("rig_par.txt", "rig_par.txt"),
    "colmap-cameras": ("colmap/cameras.txt", "cameras.txt"),
    "colmap-images": ("colmap/cameras.txt", "images.txt"),
    "colmap-binary-cameras": ("colmap/cameras.bin", "cameras.bin"),
    "colmap-binary-images": ("colmap/cameras.bin", "images.bin"),
    "anipose": ("calib.toml", "calib.toml"),
    "opencv-stereo": ("stereo.yml", "stereo.yml"),
    "nerf": ("transforms.json", "transforms.json"),
}


def _rig() -> Rig:
    """Two plain cameras (no skew, no distortion): a rig every format holds."""
    cameras = []
    for i, angle in enumerate((0.3, -0.4)):
        c, s = np.cos(angle), np.sin(angle)
        R = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
        K = np.array([[500.0 + 10 * i, 0.0, 319.5], [0.0, 505.0, 239.5], [0.0, 0.0, 1.0]])
        cameras.append(Camera(f"cam{i}", K, np.zeros(5), R, np.array([0.1 * i, 0.0, 3.0]), 640, 480))
    return Rig(cameras)


@pytest.fixture(scope="module")
def valid(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Path]]:
    """Per format: (the folder holding its files, the path Rig.load is given)."""
    made = {}
    rig = _rig()
    for key, (target, _) in FORMATS.items():
        folder = tmp_path_factory.mktemp(key)
        # The OpenCV stereo format puts the world at its first camera.
        (rig.relative_to("cam0") if key == "opencv-stereo" else rig).save(folder / target)
        load = folder / target
        if target.startswith("colmap/") or target == "rig":
            load = load.parent if target.startswith("colmap/") else load
        made[key] = (folder, load)
    return made


# A mutation: (kind, position in 0..1, bytes).
_MUTATION = st.tuples(
    st.sampled_from(["truncate", "flip", "insert", "delete", "number", "duplicate-line", "drop-line"]),
    st.floats(0.0, 1.0),
    st.binary(min_size=1, max_size=8),
)
_NUMBER = re.compile(rb"-?\d+(\.\d+)?([eE][-+]?\d+)?")
_REPLACEMENTS = [b"nan", b".Nan", b"inf", b"1e400", b"-0", b"", b"1e-400", b"99999999999999999999", b"-1", b"0", b"\"x\""]


def mutate(data: bytes, mutations: list[tuple[str, float, bytes]]) -> bytes:
    for kind, where, payload in mutations:
        at = int(where * len(data))
        if kind == "truncate":
            data = data[:at]
        elif kind == "flip" and data:
            at = min(at, len(data) - 1)
            data = data[:at] + bytes([data[at] ^ (payload[0] or 1)]) + data[at + 1:]
        elif kind == "insert":
            data = data[:at] + payload + data[at:]
        elif kind == "delete":
            data = data[:at] + data[at + len(payload) * 4:]
        elif kind == "number":
            numbers = list(_NUMBER.finditer(data))
            if numbers:
                m = numbers[min(int(where * len(numbers)), len(numbers) - 1)]
                data = data[: m.start()] + _REPLACEMENTS[payload[0] % len(_REPLACEMENTS)] + data[m.end():]
        else:
            lines = data.split(b"\n")
            i = min(int(where * len(lines)), len(lines) - 1)
            lines = lines[:i] + ([lines[i]] * 2 if kind == "duplicate-line" else []) + lines[i + 1:]
            data = b"\n".join(lines)
    return data


def _load_mutated(folder: Path, load: Path, file: str, mutations: list[tuple[str, float, bytes]]) -> None:
    with tempfile.TemporaryDirectory() as scratch:
        copy = Path(scratch) / "rig"
        shutil.copytree(folder, copy)
        target = next(copy.rglob(file))
        target.write_bytes(mutate(target.read_bytes(), mutations))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # printed-precision corrections are allowed
            try:
                rig = Rig.load(copy / load.relative_to(folder), size=SIZE)
            except (ElastocapError, FileNotFoundError) as error:
                assert str(error), "an error without a message"
                return
        for camera in rig.cameras:
            assert np.isfinite(camera.K).all() and np.isfinite(camera.R).all() and np.isfinite(camera.t).all()
            assert camera.width > 0 and camera.height > 0


@pytest.mark.parametrize("key", list(FORMATS))
def test_mutated_calibrations_load_or_raise_a_clear_error(key: str, valid: dict[str, tuple[Path, Path]]) -> None:
    folder, load = valid[key]
    file = FORMATS[key][1]

    @settings(max_examples=EXAMPLES, database=None)
    @given(st.lists(_MUTATION, min_size=1, max_size=3))
    def check(mutations: list[tuple[str, float, bytes]]) -> None:
        _load_mutated(folder, load, file, mutations)

    check()


def test_the_valid_files_load_back_exactly(valid: dict[str, tuple[Path, Path]]) -> None:
    """The fuzzers start from files that load: else they would test nothing."""
    for key, (_, load) in valid.items():
        rig = Rig.load(load, size=SIZE)
        assert rig.names == ["cam0", "cam1"], key
        np.testing.assert_allclose(rig["cam1"].K, _rig()["cam1"].K, atol=1e-9, err_msg=key)


_CONFIG = b'units = "mm"\nup = "z"\nmissing = "skip"\n\n[offsets]\ncam0 = 3\ncam1 = -2\n'


@settings(max_examples=EXAMPLES * 2, database=None)
@given(st.lists(_MUTATION, min_size=1, max_size=3))
def test_mutated_capture_toml_reads_or_raises_a_clear_error(mutations: list[tuple[str, float, bytes]]) -> None:
    with tempfile.TemporaryDirectory() as scratch:
        file = Path(scratch) / "capture.toml"
        file.write_bytes(mutate(_CONFIG, mutations))
        try:
            read_config(file)
        except ElastocapError as error:
            assert "capture.toml" in str(error)


@pytest.fixture(scope="module")
def body_json(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = tmp_path_factory.mktemp("body") / "human.json"
    BodyModel.default_human().save(path)
    return path.read_bytes()


def test_mutated_body_models_load_or_raise_a_clear_error(body_json: bytes) -> None:
    @settings(max_examples=EXAMPLES, database=None)
    @given(st.lists(_MUTATION, min_size=1, max_size=2))
    def check(mutations: list[tuple[str, float, bytes]]) -> None:
        with tempfile.TemporaryDirectory() as scratch:
            file = Path(scratch) / "human.json"
            file.write_bytes(mutate(body_json, mutations))
            try:
                BodyModel.load(file)
            except ElastocapError as error:
                assert str(error)

    check()
