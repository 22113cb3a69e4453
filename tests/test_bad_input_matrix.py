"""The bad-input matrix (issue 13, item 4): every command of the command line and the main
Python entry points, each fed one malformed input per row. Every row must end in a clear
error: elastocap's own (``ElastocapError``, or ``FileNotFoundError`` / ``OSError`` for paths),
exit status 2 from the command line with one line naming the file or the argument, no
traceback, no panic, no hang (each command runs under a timeout).

The command-line rows are generated: each defect of a capture folder x each command that
reads a capture folder, plus the rows of the commands that read other things (``export``
an output folder, ``rig convert`` / ``rig show`` a calibration, ``calibrate`` board images).
They run through :func:`elastocap.pipeline.cli.main` in one server process (imported once,
restarted after a timeout or a crash), so that a hang or a segfault fails its row and only
its row; a few rows also run through the real console entry point (``python -m
elastocap``) to check the exit status and the absence of a traceback end to end.
"""

from __future__ import annotations

import json
import os
import re
import select
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

import elastocap
from elastocap import ElastocapError
from elastocap.synth.capture import write_synthetic_capture

# Seconds a row may take before it counts as a hang: every row fails fast (its input is bad
# from the start) on a tiny capture; the slowest (a fit that must carve first) takes ~5 s.
ROW_TIMEOUT = 60.0
SIZE = (64, 48)
CAMERAS = ("cam00", "cam01", "cam02")
SMALL = ["--resolution", "24", "--quiet"]

# The server: runs ``main(argv)`` per request line, answers one JSON line marked with
# _MARK on its real stdout (what the command prints is captured apart).
_MARK = "@@elastocap-row@@"
_SERVER = f"""
import contextlib, io, json, os, sys, traceback
from elastocap.pipeline.cli import main
protocol = sys.stdout
for line in sys.stdin:
    request = json.loads(line)
    os.chdir(request["cwd"])
    out, err = io.StringIO(), io.StringIO()
    crash = None
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(request["argv"])
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else 1
        except BaseException:
            code, crash = None, traceback.format_exc()
    answer = {{"code": code, "stdout": out.getvalue(), "stderr": err.getvalue(), "crash": crash}}
    protocol.write({_MARK!r} + json.dumps(answer) + "\\n")
    protocol.flush()
"""


class _Server:
    """One Python process running rows of the command line, one at a time."""

    def __init__(self) -> None:
        self.process: subprocess.Popen[str] | None = None

    def _start(self) -> subprocess.Popen[str]:
        if self.process is None or self.process.poll() is not None:
            env = {**os.environ, "RAYON_NUM_THREADS": "2"}
            self.process = subprocess.Popen(
                [sys.executable, "-c", _SERVER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL, text=True, env=env,
            )
        return self.process

    def run(self, argv: list[str], cwd: Path, timeout: float = ROW_TIMEOUT) -> dict:
        process = self._start()
        assert process.stdin is not None and process.stdout is not None
        process.stdin.write(json.dumps({"argv": argv, "cwd": str(cwd)}) + "\n")
        process.stdin.flush()
        while True:
            ready, _, _ = select.select([process.stdout], [], [], timeout)
            if not ready:
                self.stop()
                return {"code": None, "hang": True, "stdout": "", "stderr": "", "crash": None}
            line = process.stdout.readline()
            if not line:  # died: a segfault or an abort
                status = process.wait()
                self.process = None
                return {"code": None, "died": status, "stdout": "", "stderr": "", "crash": f"exit status {status}"}
            if line.startswith(_MARK):
                return json.loads(line[len(_MARK):])

    def stop(self) -> None:
        if self.process is not None:
            self.process.kill()
            self.process.wait()
            self.process = None


@pytest.fixture(scope="module")
def server():
    running = _Server()
    yield running
    running.stop()


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small valid capture: 3 cameras, 3 frames, 64x48 images, masks, backgrounds."""
    root = tmp_path_factory.mktemp("matrix") / "base"
    return write_synthetic_capture(root, frames=3, cameras=len(CAMERAS), image_size=SIZE, spacing=0.04, progress=False)


# -- defects of a capture folder -----------------------------------------------------------
# Each takes the copied capture folder and returns (the path to pass as CAPTURE, the
# regular expression the error must match: the file or argument it names).


def _mask(cap: Path, camera: str = "cam01", frame: int = 0) -> Path:
    return cap / "masks" / camera / f"{frame:06d}.png"


def _edit_yaml(file: Path, old: str, new: str) -> None:
    text = file.read_text()
    assert old in text, (old, file)
    file.write_text(text.replace(old, new, 1))


def _nan_in_intrinsics(cap: Path) -> tuple[Path, str]:
    text = (cap / "intri.yml").read_text()
    start = text.index("K_cam01")
    data = text.index("data: [", start) + len("data: [")
    end = text.index(",", data)
    (cap / "intri.yml").write_text(text[:data] + " .Nan" + text[end:])
    return cap, r"intri\.yml.*cam01|cam01.*K"


def _rewrite_extrinsics(cap: Path, change: Callable[[list[str], dict[str, np.ndarray]], list[str]]) -> None:
    """extri.yml read, ``change(names, fields)`` applied, written back."""
    fs = cv2.FileStorage(str(cap / "extri.yml"), cv2.FILE_STORAGE_READ)
    names = [fs.getNode("names").at(i).string() for i in range(fs.getNode("names").size())]
    fields = {}
    for name in names:
        for key in ("R", "Rot", "T"):
            node = fs.getNode(f"{key}_{name}")
            if not node.empty():
                fields[f"{key}_{name}"] = node.mat()
    fs.release()
    names = change(names, fields)
    out = cv2.FileStorage(str(cap / "extri.yml"), cv2.FILE_STORAGE_WRITE)
    out.write("names", names)
    for key, value in fields.items():
        out.write(key, value)
    out.release()


def _reflection_in_extrinsics(cap: Path) -> tuple[Path, str]:
    def reflect(names: list[str], fields: dict[str, np.ndarray]) -> list[str]:
        fields["Rot_cam02"] = fields["Rot_cam02"] @ np.diag([1.0, 1.0, -1.0])
        fields.pop("R_cam02", None)
        return names

    _rewrite_extrinsics(cap, reflect)
    return cap, r"cam02.*(reflection|rotation)"


def _camera_missing_from_calibration(cap: Path) -> tuple[Path, str]:
    """intri.yml names cam02, extri.yml lacks it."""

    def drop(names: list[str], fields: dict[str, np.ndarray]) -> list[str]:
        for key in ("R_cam02", "Rot_cam02", "T_cam02"):
            fields.pop(key, None)
        return [n for n in names if n != "cam02"]

    _rewrite_extrinsics(cap, drop)
    return cap, r"extri\.yml.*cam02|cam02.*extri"


def _missing_capture(cap: Path) -> tuple[Path, str]:
    return cap.parent / "no_such_capture", r"no_such_capture"


def _capture_is_a_file(cap: Path) -> tuple[Path, str]:
    file = cap.parent / "capture.txt"
    file.write_text("not a folder")
    return file, r"capture\.txt"


def _no_calibration(cap: Path) -> tuple[Path, str]:
    (cap / "intri.yml").unlink()
    (cap / "extri.yml").unlink()
    return cap, r"calibration"


def _camera_missing_from_masks(cap: Path) -> tuple[Path, str]:
    shutil.rmtree(cap / "masks" / "cam01")
    return cap, r"masks/cam01"


def _mask_size_differs(cap: Path) -> tuple[Path, str]:
    cv2.imwrite(str(_mask(cap)), np.zeros((SIZE[1] + 2, SIZE[0]), np.uint8))
    return cap, r"masks/cam01/000000\.png is 64x50"


def _image_size_differs(cap: Path) -> tuple[Path, str]:
    for file in sorted((cap / "images" / "cam02").iterdir()):
        cv2.imwrite(str(file), np.zeros((SIZE[1], SIZE[0] // 2, 3), np.uint8))
    return cap, r"images/cam02/.* is 32x48"


def _empty_mask(cap: Path) -> tuple[Path, str]:
    cv2.imwrite(str(_mask(cap)), np.zeros((SIZE[1], SIZE[0]), np.uint8))
    return cap, r"cam01.*(all background|empty)|(all background|empty).*cam01"


def _truncated_mask(cap: Path) -> tuple[Path, str]:
    data = _mask(cap).read_bytes()
    _mask(cap).write_bytes(data[: len(data) // 2])
    return cap, r"masks/cam01/000000\.png"


def _garbage_mask(cap: Path) -> tuple[Path, str]:
    _mask(cap).write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    return cap, r"masks/cam01/000000\.png"


def _truncated_image(cap: Path) -> tuple[Path, str]:
    file = cap / "images" / "cam00" / "000000.jpg"
    file.write_bytes(file.read_bytes()[:100])
    return cap, r"images/cam00/000000\.jpg"


def _truncated_video(cap: Path) -> tuple[Path, str]:
    """The colour frames of cam00 as a video cut in the middle (and no images/ folder)."""
    (cap / "videos").mkdir()
    for camera in CAMERAS:
        video = cap / "videos" / f"{camera}.mp4"
        writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, SIZE)
        for image in sorted((cap / "images" / camera).iterdir()):
            writer.write(cv2.imread(str(image)))
        writer.release()
    shutil.rmtree(cap / "images")
    video = cap / "videos" / "cam00.mp4"
    video.write_bytes(video.read_bytes()[: video.stat().st_size // 3])
    return cap, r"videos/cam00\.mp4"


def _garbage_video(cap: Path) -> tuple[Path, str]:
    shutil.rmtree(cap / "images")
    (cap / "videos").mkdir()
    for camera in CAMERAS:
        (cap / "videos" / f"{camera}.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + os.urandom(2000))
    return cap, r"videos/cam0\d\.mp4"


def _mask_video_missing_frames(cap: Path) -> tuple[Path, str]:
    shutil.rmtree(_mask(cap).parent)
    (cap / "masks" / "cam01.mp4").write_bytes(b"")
    return cap, r"masks/cam01\.mp4"


def _config_unknown_key(cap: Path) -> tuple[Path, str]:
    (cap / "capture.toml").write_text('units = "mm"\noffset = { cam01 = 2 }\n')
    return cap, r"capture\.toml.*unknown key.*offset"


def _config_malformed(cap: Path) -> tuple[Path, str]:
    (cap / "capture.toml").write_text('units = "mm\nmissing = [skip\n')
    return cap, r"capture\.toml.*TOML"


def _config_wrong_types(cap: Path) -> tuple[Path, str]:
    (cap / "capture.toml").write_text('missing = "sometimes"\n[offsets]\ncam01 = 1.5\n')
    return cap, r"capture\.toml.*(offsets\.cam01|missing)"


def _config_offset_of_unknown_camera(cap: Path) -> tuple[Path, str]:
    (cap / "capture.toml").write_text("[offsets]\ncam09 = 1\n")
    return cap, r"capture\.toml.*cam09"


def _config_binary(cap: Path) -> tuple[Path, str]:
    (cap / "capture.toml").write_bytes(b"\xff\xfe\x00units = 1\x00" + os.urandom(64))
    return cap, r"capture\.toml"


def _malformed_yaml(cap: Path) -> tuple[Path, str]:
    (cap / "extri.yml").write_text("%YAML:1.0\n---\nnames: [ \"cam00\", \nR_cam00: !!opencv-matrix {{{\n")
    return cap, r"extri\.yml"


def _yaml_garbage_bytes(cap: Path) -> tuple[Path, str]:
    (cap / "intri.yml").write_bytes(os.urandom(512))
    return cap, r"intri\.yml"


def _frame_missing_in_one_camera(cap: Path) -> tuple[Path, str]:
    _mask(cap, "cam02", 1).unlink()  # a frame in the middle
    return cap, r"masks/cam02.*lacks frame.*1"


def _two_files_for_one_frame(cap: Path) -> tuple[Path, str]:
    shutil.copy(_mask(cap), _mask(cap).with_suffix(".jpg"))
    return cap, r"two files for frame 0"


def _no_frames(cap: Path) -> tuple[Path, str]:
    for folder in ("images", "masks"):
        for camera in CAMERAS:
            for file in (cap / folder / camera).iterdir():
                file.unlink()
    return cap, r"no frame|frames|masks"


def _camera_name_escapes(cap: Path) -> tuple[Path, str]:
    for file in ("intri.yml", "extri.yml"):
        text = (cap / file).read_text()
        (cap / file).write_text(text.replace("cam02", "../../escaped"))
    return cap, r"\.\./\.\./escaped"


def _all_cameras_at_one_centre(cap: Path) -> tuple[Path, str]:
    """Degenerate geometry: every camera at the same centre, looking the same way."""
    from elastocap import Rig

    rig = Rig.load(cap)
    first = rig.cameras[0]
    same = [camera.replace(R=first.R, t=first.t) for camera in rig.cameras]
    (cap / "intri.yml").unlink()
    (cap / "extri.yml").unlink()
    Rig(same).save(cap)
    return cap, r"cameras are at one centre"


DEFECTS: dict[str, Callable[[Path], tuple[Path, str]]] = {
    "capture folder missing": _missing_capture,
    "capture is a file": _capture_is_a_file,
    "no calibration": _no_calibration,
    "camera missing from masks/": _camera_missing_from_masks,
    "camera missing from the calibration": _camera_missing_from_calibration,
    "mask size differs from the calibration": _mask_size_differs,
    "image size differs from the calibration": _image_size_differs,
    "empty mask": _empty_mask,
    "truncated mask PNG": _truncated_mask,
    "garbage mask PNG": _garbage_mask,
    "truncated JPEG image": _truncated_image,
    "truncated MP4 video": _truncated_video,
    "garbage MP4 videos": _garbage_video,
    "empty mask video": _mask_video_missing_frames,
    "NaN in the calibration": _nan_in_intrinsics,
    "reflection in the calibration": _reflection_in_extrinsics,
    "malformed extri.yml": _malformed_yaml,
    "random bytes as intri.yml": _yaml_garbage_bytes,
    "capture.toml unknown key": _config_unknown_key,
    "capture.toml malformed": _config_malformed,
    "capture.toml wrong types": _config_wrong_types,
    "capture.toml offset of an unknown camera": _config_offset_of_unknown_camera,
    "capture.toml binary": _config_binary,
    "frame missing in one camera": _frame_missing_in_one_camera,
    "two files for one frame": _two_files_for_one_frame,
    "no frames": _no_frames,
    "camera name with ../": _camera_name_escapes,
    "all cameras at one centre": _all_cameras_at_one_centre,
}

# The commands that read a capture folder, as argv given CAPTURE and OUT.
CAPTURE_COMMANDS: dict[str, Callable[[Path, Path], list[str]]] = {
    "hull": lambda cap, out: ["hull", str(cap), "--out", str(out), *SMALL],
    "fit": lambda cap, out: ["fit", str(cap), "--out", str(out), "--nodes", "100", *SMALL],
    # One frame: the body fits a frame in seconds, and every defect is met in frame 0.
    "body": lambda cap, out: ["body", str(cap), "--out", str(out), "--frames", "0", "--quiet"],
    "capture": lambda cap, out: ["capture", str(cap), "--out", str(out), "--nodes", "100", "--silhouettes", "masks", *SMALL],
    "silhouettes": lambda cap, out: ["silhouettes", str(cap), "--out", str(out), "--quiet"],
}

# Defects a command does not meet: silhouettes makes the masks (it does not read them);
# hull and fit read masks, not colour frames.
_COLOUR = ("image size differs from the calibration", "truncated JPEG image", "truncated MP4 video", "garbage MP4 videos")
_NOT_READ = {
    ("silhouettes", name) for name in DEFECTS
    if "mask" in name or name in ("frame missing in one camera", "two files for one frame", "all cameras at one centre")
} | {(command, name) for command in ("hull", "fit") for name in _COLOUR}
# An all-background mask is valid but unhelpful input for the body (SPEC 2): it fits the
# subject to the other views; the carving refuses it (it would carve everything away).
_NOT_READ.add(("body", "empty mask"))


def _capture_row(command: str, defect: str, folder: Path, base: Path) -> tuple[list[str], str]:
    """A copy of the base capture with ``defect``, and ``command`` run on it."""
    cap = folder / "capture"
    shutil.copytree(base, cap, ignore=shutil.ignore_patterns("ground_truth"))
    path, expected = DEFECTS[defect](cap)
    return CAPTURE_COMMANDS[command](path, folder / "out"), expected


# -- options and outputs of the capture commands -------------------------------------------


def _readonly_out(folder: Path) -> Path:
    """An output folder that cannot be written: under /proc when running as root (which
    ignores permissions), else a folder without write permission."""
    if os.geteuid() == 0:
        return Path("/proc/elastocap-read-only/out")
    out = folder / "read-only"
    out.mkdir()
    out.chmod(0o555)
    return out / "out"


OPTION_ROWS: dict[str, Callable[[Path, Path], tuple[list[str], str]]] = {}
# silhouettes reads the stereo stage's OUT/disparity before it writes anything: without it,
# that is the error, whatever is wrong with OUT.
_FIRST = {"hull": "", "fit": "", "body": "", "capture": "", "silhouettes": "|OUT.*disparity|disparity mask"}
for _command in ("hull", "body", "silhouettes"):
    OPTION_ROWS[f"{_command}: frames out of range"] = (
        lambda c: lambda folder, base: ([c, str(base), "--out", str(folder / "out"), "--frames", "50:60", "--quiet"], r"--frames 50:60 selects no frame")
    )(_command)
    OPTION_ROWS[f"{_command}: frames not a range"] = (
        lambda c: lambda folder, base: ([c, str(base), "--out", str(folder / "out"), "--frames", "one:two", "--quiet"], r"--frames.*'one:two'")
    )(_command)
    OPTION_ROWS[f"{_command}: single frame out of range"] = (
        lambda c: lambda folder, base: ([c, str(base), "--out", str(folder / "out"), "--frames", "7", "--quiet"], r"frame.*7")
    )(_command)
for _command in ("hull", "fit", "body", "capture", "silhouettes"):
    OPTION_ROWS[f"{_command}: read-only output folder"] = (
        lambda c: lambda folder, base: (CAPTURE_COMMANDS[c](base, _readonly_out(folder)), r"elastocap-read-only|Permission" + _FIRST[c])
    )(_command)
    OPTION_ROWS[f"{_command}: output is a file"] = (
        lambda c: lambda folder, base: ((folder / "out.txt").write_text("x"), CAPTURE_COMMANDS[c](base, folder / "out.txt"))[1:] + ("out\\.txt" + _FIRST[c],)
    )(_command)
OPTION_ROWS.update({
    "hull: resolution 0": lambda folder, base: (["hull", str(base), "--out", str(folder / "o"), "--resolution", "0", "--quiet"], r"resolution"),
    "hull: resolution -5": lambda folder, base: (["hull", str(base), "--out", str(folder / "o"), "--resolution", "-5", "--quiet"], r"resolution"),
    "hull: tolerance -1": lambda folder, base: (["hull", str(base), "--out", str(folder / "o"), "--tolerance", "-1", *SMALL], r"tolerance"),
    "hull: tolerance = cameras": lambda folder, base: (["hull", str(base), "--out", str(folder / "o"), "--tolerance", "3", *SMALL], r"tolerance"),
    "fit: rest frame out of range": lambda folder, base: (["fit", str(base), "--out", str(folder / "o"), "--rest-frame", "99", "--nodes", "100", *SMALL], r"rest frame 99"),
    "fit: 0 nodes": lambda folder, base: (["fit", str(base), "--out", str(folder / "o"), "--nodes", "0", *SMALL], r"n_nodes|nodes"),
    "fit: stiffness nan": lambda folder, base: (["fit", str(base), "--out", str(folder / "o"), "--stiffness", "nan", "--nodes", "100", *SMALL], r"stiffness"),
    "fit: stiffness -1": lambda folder, base: (["fit", str(base), "--out", str(folder / "o"), "--stiffness", "-1", "--nodes", "100", *SMALL], r"stiffness"),
    "capture: config file missing": lambda folder, base: (["capture", str(base), "--out", str(folder / "o"), "--config", str(folder / "none.toml")], r"none\.toml"),
    "capture: config malformed": lambda folder, base: ((folder / "c.toml").write_text("nodes = = 3"), ["capture", str(base), "--out", str(folder / "o"), "--config", str(folder / "c.toml")])[1:] + (r"c\.toml",),
    "capture: config unknown key": lambda folder, base: ((folder / "c.toml").write_text("nodez = 3\n"), ["capture", str(base), "--out", str(folder / "o"), "--config", str(folder / "c.toml")])[1:] + (r"nodez",),
    "capture: config wrong type": lambda folder, base: ((folder / "c.toml").write_text('resolution = "high"\n'), ["capture", str(base), "--out", str(folder / "o"), "--config", str(folder / "c.toml")])[1:] + (r"resolution",),
    "capture: config nan fps": lambda folder, base: ((folder / "c.toml").write_text("fps = nan\n"), ["capture", str(base), "--out", str(folder / "o"), "--config", str(folder / "c.toml")])[1:] + (r"fps",),
    "capture: silhouettes from a missing background": lambda folder, base: (_no_background(folder, base), r"background"),
    "capture: fps -3": lambda folder, base: (["capture", str(base), "--out", str(folder / "o"), "--fps", "-3", *SMALL], r"fps"),
    "capture: units furlongs": lambda folder, base: (["capture", str(base), "--out", str(folder / "o"), "--units", "furlongs", *SMALL], r"units"),
    "capture: threads 0": lambda folder, base: (["capture", str(base), "--out", str(folder / "o"), "--threads", "0", *SMALL], r"threads"),
})


def _no_background(folder: Path, base: Path) -> list[str]:
    cap = folder / "capture"
    shutil.copytree(base, cap, ignore=shutil.ignore_patterns("ground_truth", "background"))
    return ["capture", str(cap), "--out", str(folder / "o"), "--silhouettes", "background", "--fps", "30", "--nodes", "100", *SMALL]


# -- export: an output folder ---------------------------------------------------------------


@pytest.fixture(scope="module")
def fitted(base: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished output folder of ``elastocap fit`` on the base capture."""
    from elastocap.pipeline.cli import main

    out = tmp_path_factory.mktemp("matrix") / "fitted"
    assert main(["fit", str(base), "--out", str(out), "--nodes", "100", *SMALL]) == 0
    return out


def _copy_out(folder: Path, fitted: Path) -> Path:
    out = folder / "out"
    shutil.copytree(fitted, out)
    return out


def _export(out: Path, *extra: str) -> list[str]:
    return ["export", str(out), *extra]


def _pickled_fit_frame(out: Path) -> None:
    np.savez(out / "fit" / "000001.npz", positions=np.array([{"x": 1}], dtype=object))


def _truncated_npz(file: Path) -> None:
    file.write_bytes(file.read_bytes()[: file.stat().st_size // 2])


EXPORT_ROWS: dict[str, Callable[[Path, Path], tuple[list[str], str]]] = {
    "export: output folder missing": lambda folder, fitted: (_export(folder / "nothing", "--format", "glb"), r"nothing"),
    "export: no fit in the folder": lambda folder, fitted: ((folder / "empty").mkdir(), _export(folder / "empty", "--format", "glb"))[1:] + (r"empty.*fit|rest\.npz",),
    "export: bvh without a body fit": lambda folder, fitted: (_export(_copy_out(folder, fitted), "--format", "bvh"), r"body"),
    "export: fps nan": lambda folder, fitted: (_export(_copy_out(folder, fitted), "--format", "glb", "--fps", "nan"), r"fps"),
    "export: fps 0": lambda folder, fitted: (_export(_copy_out(folder, fitted), "--format", "pc2", "--fps", "0"), r"fps"),
    "export: units bogus": lambda folder, fitted: (_export(_copy_out(folder, fitted), "--format", "glb", "--units", "parsecs"), r"units"),
    "export: take with a path": lambda folder, fitted: (_export(_copy_out(folder, fitted), "--format", "glb", "--take", "../../escape"), r"take"),
}


def _truncated_model_row(folder: Path, fitted: Path) -> tuple[list[str], str]:
    out = _copy_out(folder, fitted)
    _truncated_npz(out / "model" / "rest.npz")
    return _export(out, "--format", "glb"), r"model/rest\.npz"


def _truncated_frame_row(folder: Path, fitted: Path) -> tuple[list[str], str]:
    out = _copy_out(folder, fitted)
    _truncated_npz(out / "fit" / "000001.npz")
    return _export(out, "--format", "pc2"), r"fit/000001\.npz"


def _pickled_frame_row(folder: Path, fitted: Path) -> tuple[list[str], str]:
    out = _copy_out(folder, fitted)
    _pickled_fit_frame(out)
    return _export(out, "--format", "glb"), r"fit/000001\.npz"


def _mismatched_frame_row(folder: Path, fitted: Path) -> tuple[list[str], str]:
    out = _copy_out(folder, fitted)
    np.savez(out / "fit" / "000002.npz", positions=np.zeros((7, 3)))
    return _export(out, "--format", "pc2"), r"000002|frame 2"


def _bad_out_config_row(folder: Path, fitted: Path) -> tuple[list[str], str]:
    out = _copy_out(folder, fitted)
    (out / "capture.toml").write_text("fps = [\n")
    return _export(out, "--format", "glb"), r"capture\.toml"


def _readonly_export_row(folder: Path, fitted: Path) -> tuple[list[str], str]:
    out = _copy_out(folder, fitted)
    if os.geteuid() == 0:
        (out / "export").write_text("a file where the export folder goes")
        return _export(out, "--format", "glb"), r"export"
    (out).chmod(0o555)
    return _export(out, "--format", "glb"), r"export|Permission"


EXPORT_ROWS.update({
    "export: truncated model npz": _truncated_model_row,
    "export: truncated fit frame npz": _truncated_frame_row,
    "export: object array (pickle) in a fit frame": _pickled_frame_row,
    "export: frames of another model": _mismatched_frame_row,
    "export: malformed OUT/capture.toml": _bad_out_config_row,
    "export: read-only output folder": _readonly_export_row,
})


# -- rig convert / rig show / calibrate ------------------------------------------------------


def _plain_rig(base: Path) -> "elastocap.Rig":
    """The base capture's rig without skew and distortion, which every format holds."""
    rig = elastocap.Rig.load(base)
    plain = []
    for camera in rig.cameras:
        K = camera.K.copy()
        K[0, 1] = 0.0
        plain.append(camera.replace(K=K, dist=np.zeros(5)))
    return elastocap.Rig(plain)


def _rig_file(folder: Path, base: Path, name: str, content: bytes | None = None) -> Path:
    path = folder / name
    if content is None:
        _plain_rig(base).save(path)
    else:
        path.write_bytes(content)
    return path


def _corrupt(path: Path, keep: float = 0.5) -> Path:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    return path


RIG_FILES: dict[str, Callable[[Path, Path], tuple[Path, str]]] = {
    "rig.json truncated": lambda folder, base: (_corrupt(_rig_file(folder, base, "rig.json")), r"rig\.json"),
    "rig.json not an object": lambda folder, base: (_rig_file(folder, base, "rig.json", b"[1, 2, 3]"), r"rig\.json"),
    "rig.json NaN in K": lambda folder, base: (_nan_json(_rig_file(folder, base, "rig.json")), r"rig\.json.*cam0"),
    "rig.json binary": lambda folder, base: (_rig_file(folder, base, "rig.json", b"\xff\xd8\xff" + bytes(range(256))), r"rig\.json"),
    "transforms.json truncated": lambda folder, base: (_corrupt(_rig_file(folder, base, "transforms.json")), r"transforms\.json"),
    "calib.toml truncated": lambda folder, base: (_corrupt(_rig_file(folder, base, "calib.toml"), 0.6), r"calib\.toml"),
    "calib.toml not TOML": lambda folder, base: (_rig_file(folder, base, "calib.toml", b"[cam_0\nname = "), r"calib\.toml"),
    "stereo.yml garbage": lambda folder, base: (_rig_file(folder, base, "stereo.yml", b"%YAML:1.0\nM1: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n  data: [ 1, 2 ]\n"), r"stereo\.yml"),
    "par.txt truncated": lambda folder, base: (_corrupt(_rig_file(folder, base, "rig_par.txt"), 0.7), r"rig_par\.txt"),
    "par.txt words": lambda folder, base: (_rig_file(folder, base, "rig_par.txt", b"3\nimg.png one two three\n"), r"rig_par\.txt"),
    "COLMAP cameras.txt truncated": lambda folder, base: (_colmap(folder, base, "cameras.txt"), r"cameras\.txt"),
    "COLMAP images.bin truncated": lambda folder, base: (_colmap(folder, base, "images.bin"), r"images\.bin"),
    "unknown extension": lambda folder, base: (_rig_file(folder, base, "rig.pdf", b"%PDF-1.4"), r"rig\.pdf"),
    "missing file": lambda folder, base: (folder / "absent.json", r"absent\.json"),
    "empty folder": lambda folder, base: ((folder / "empty").mkdir() or folder / "empty", r"no calibration in .*empty"),
}


def _nan_json(path: Path) -> Path:
    document = json.loads(path.read_text())
    document["cameras"][0]["K"][0][0] = float("nan")
    path.write_text(json.dumps(document))
    return path


def _colmap(folder: Path, base: Path, corrupt: str) -> Path:
    model = folder / "colmap"
    model.mkdir()
    _plain_rig(base).save(model / ("cameras.bin" if corrupt.endswith(".bin") else "cameras.txt"))
    _corrupt(model / corrupt, 0.6)
    return model


RIG_ROWS: dict[str, Callable[[Path, Path], tuple[list[str], str]]] = {}
for _name in RIG_FILES:
    RIG_ROWS[f"rig convert: {_name}"] = (
        lambda n: lambda folder, base: (lambda made: (["rig", "convert", str(made[0]), str(folder / "converted.json")], made[1]))(RIG_FILES[n](folder, base))
    )(_name)

# rig show reads through the same Rig.load: a few of the files suffice.
for _name in ("rig.json truncated", "stereo.yml garbage", "COLMAP images.bin truncated", "missing file"):
    RIG_ROWS[f"rig show: {_name}"] = (
        lambda n: lambda folder, base: (lambda made: (["rig", "show", str(made[0]), "--out", str(folder / "rig.png")], made[1]))(RIG_FILES[n](folder, base))
    )(_name)
RIG_ROWS.update({
    "rig convert: output format cannot hold distortion": lambda folder, base: (["rig", "convert", str(base), str(folder / "out_par.txt")], r"distortion|middlebury"),
    "rig convert: read-only output": lambda folder, base: (["rig", "convert", str(base), str(_readonly_out(folder) / "rig.json")], r"elastocap-read-only|Permission|No such file"),
    "rig convert: size that disagrees": lambda folder, base: (["rig", "convert", str(base), str(folder / "r.json"), "--size", "10", "10"], r"size|10"),
    "rig show: picture into a read-only folder": lambda folder, base: (["rig", "show", str(base), "--out", str(_readonly_out(folder) / "rig.png")], r"rig\.png|elastocap-read-only|Permission"),
    "calibrate: no images": lambda folder, base: ((folder / "boards").mkdir(), ["calibrate", str(folder / "boards"), "--board", "7x5", "--out", str(folder / "rig.json")])[1:] + (r"boards",),
    "calibrate: images folder missing": lambda folder, base: (["calibrate", str(folder / "none"), "--board", "7x5", "--out", str(folder / "rig.json")], r"none"),
    "calibrate: board not WxH": lambda folder, base: (["calibrate", str(base / "images"), "--board", "seven", "--out", str(folder / "rig.json")], r"board"),
    "calibrate: board 1x1": lambda folder, base: (["calibrate", str(base / "images"), "--board", "1x1", "--out", str(folder / "rig.json")], r"board|columns"),
    "calibrate: square size nan": lambda folder, base: (["calibrate", str(base / "images"), "--board", "7x5", "--square-size", "nan", "--out", str(folder / "rig.json")], r"square"),
    "calibrate: no board in the images": lambda folder, base: (["calibrate", str(base / "images"), "--board", "7x5", "--out", str(folder / "rig.json")], r"board|chessboard|corners"),
    "calibrate: truncated image": lambda folder, base: (_truncated_boards(folder, base), r"000000\.jpg|board|chessboard"),
})


def _truncated_boards(folder: Path, base: Path) -> list[str]:
    images = folder / "boards"
    shutil.copytree(base / "images", images)
    _corrupt(images / "cam00" / "000000.jpg", 0.1)
    return ["calibrate", str(images), "--board", "7x5", "--out", str(folder / "rig.json")]


def _cli_rows() -> dict[str, tuple[str, object]]:
    rows: dict[str, tuple[str, object]] = {}
    for command in CAPTURE_COMMANDS:
        for defect in DEFECTS:
            if (command, defect) in _NOT_READ:
                continue
            rows[f"{command}: {defect}"] = ("capture", (command, defect))
    for name, make in OPTION_ROWS.items():
        rows[name] = ("base", make)
    for name, make in EXPORT_ROWS.items():
        rows[name] = ("fitted", make)
    for name, make in RIG_ROWS.items():
        rows[name] = ("base", make)
    return rows


CLI_ROWS = _cli_rows()


def _check_answer(row: str, answer: dict, expected: str, argv: list[str]) -> str:
    """The one-line error, after checking the row ended as a clear error."""
    assert not answer.get("hang"), f"{row}: no answer in {ROW_TIMEOUT} s (hang): elastocap {' '.join(argv)}"
    assert answer["crash"] is None, f"{row}: crashed:\n{answer['crash']}"
    stderr = answer["stderr"]
    assert answer["code"] not in (0, None), f"{row}: exit status {answer['code']}; stdout {answer['stdout']!r}"
    assert "Traceback" not in stderr and "panicked" not in stderr, f"{row}: {stderr}"
    errors = [line for line in stderr.splitlines() if ": error: " in line]
    assert len(errors) == 1, f"{row}: expected one error line, got {stderr!r}"
    assert re.search(expected, errors[0]), f"{row}: the error does not name {expected!r}: {errors[0]}"
    return errors[0]


@pytest.mark.parametrize("row", list(CLI_ROWS))
def test_command_line_row(row: str, server: _Server, base: Path, tmp_path: Path, request: pytest.FixtureRequest) -> None:
    kind, spec = CLI_ROWS[row]
    folder = tmp_path / "row"
    folder.mkdir()
    if kind == "capture":
        command, defect = spec  # type: ignore[misc]
        argv, expected = _capture_row(command, defect, folder, base)
    elif kind == "fitted":
        argv, expected = spec(folder, request.getfixturevalue("fitted"))  # type: ignore[operator]
    else:
        argv, expected = spec(folder, base)  # type: ignore[operator]
    try:
        answer = server.run(argv, folder)
    finally:
        for path in folder.rglob("*"):
            if path.is_dir():
                path.chmod(0o755)
    line = _check_answer(row, answer, expected, argv)
    _MATRIX[row] = line


# What each row ended with, for the closing note: ELASTOCAP_MATRIX_OUT=file.tsv writes the
# matrix (row, error) there.
_MATRIX: dict[str, str] = {}


@pytest.fixture(scope="module", autouse=True)
def _write_matrix():
    yield
    target = os.environ.get("ELASTOCAP_MATRIX_OUT")
    if target:
        Path(target).write_text("".join(f"{row}\t{line}\n" for row, line in _MATRIX.items()))


# -- the Python entry points: every array argument x every way it can be wrong ------------------
# Generated: for each entry point, its valid arguments, and for each array argument the
# variants wrong shape, wrong dtype, NaN, inf, empty (those that apply to its kind). Each
# must raise ElastocapError (InvalidInputError) whose message names the argument.


def _valid_rig() -> elastocap.Rig:
    cameras = []
    for i, angle in enumerate((0.0, 2.1, 4.2)):
        c, s = np.cos(angle), np.sin(angle)
        R = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
        K = np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]])
        cameras.append(elastocap.Camera(f"cam{i}", K, np.zeros(5), R, np.array([0.0, 0.0, 3.0]), *SIZE))
    return elastocap.Rig(cameras)


def _disc_mask() -> np.ndarray:
    v, u = np.mgrid[: SIZE[1], : SIZE[0]]
    return (u - 32) ** 2 + (v - 24) ** 2 < 100


def _image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 255, (SIZE[1], SIZE[0], 3), dtype=np.uint8)


# entry -> (call(**kwargs), valid kwargs, {argument: (kind, name the message must hold)})
# kinds: "float" arrays (NaN / inf apply), "mask" / "image" arrays (integer-like).
ENTRIES: dict[str, tuple[Callable[..., object], Callable[[], dict[str, object]], dict[str, tuple[str, str]]]] = {
    "Camera": (
        lambda **a: elastocap.Camera(**a),
        lambda: {"name": "cam", "K": np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]]),
                 "dist": np.zeros(5), "R": np.eye(3), "t": np.array([0.0, 0.0, 3.0]), "width": 64, "height": 48},
        {"K": ("float", "K"), "dist": ("dist", "dist"), "R": ("float", "R"), "t": ("float", "t")},
    ),
    "Grid": (
        lambda **a: elastocap.Grid(**a),
        lambda: {"origin": np.zeros(3), "spacing": 0.1, "shape": (4, 4, 4)},
        {"origin": ("float", "origin"), "spacing": ("scalar", "spacing"), "shape": ("shape", "shape")},
    ),
    "signed_distance": (
        lambda **a: elastocap.signed_distance(**a),
        lambda: {"occupancy": np.pad(np.ones((3, 3, 3), bool), 2), "spacing": 0.1},
        {"occupancy": ("mask", "occupancy"), "spacing": ("scalar", "spacing")},
    ),
    "visual_hull": (
        lambda **a: elastocap.visual_hull({f"cam{i}": m for i, m in enumerate(a.pop("masks"))}, **a),
        lambda: {"masks": [_disc_mask()] * 3, "rig": _valid_rig(), "grid": elastocap.Grid(np.full(3, -0.5), 0.05, (20, 20, 20))},
        {"masks": ("mask-list", "mask of camera 'cam")},
    ),
    "subtract_background": (
        lambda **a: elastocap.subtract_background(**a),
        lambda: {"image": _image(0), "background": _image(1)},
        {"image": ("image", "image"), "background": ("image", "background")},
    ),
    "threshold_dark_background": (
        lambda **a: elastocap.threshold_dark_background(**a),
        lambda: {"image": _image(0)},
        {"image": ("image", "image")},
    ),
    "clean_mask": (
        lambda **a: elastocap.clean_mask(**a),
        lambda: {"mask": _disc_mask()},
        {"mask": ("mask", "mask")},
    ),
    "polar_rotation": (
        lambda **a: elastocap.polar_rotation(**a),
        lambda: {"matrices": np.tile(np.eye(3), (4, 1, 1))},
        {"matrices": ("float", "matrices")},
    ),
    "ElasticModel": (
        lambda **a: elastocap.ElasticModel(**a),
        lambda: {"nodes": np.random.default_rng(0).random((60, 3)), "volumes": np.full(60, 1.0 / 60)},
        {"nodes": ("float", "nodes"), "volumes": ("float", "volumes")},
    ),
}


def _variants(kind: str, good: object) -> dict[str, object]:
    """The wrong versions of a valid argument of ``kind``."""
    if kind == "scalar":
        return {"NaN": float("nan"), "inf": float("inf"), "zero": 0.0, "negative": -1.0, "wrong type": "0.1"}
    if kind == "shape":
        return {"wrong shape": (4, 4), "empty": (0, 4, 4), "negative": (4, -1, 4), "wrong dtype": (4.5, 4, 4)}
    if kind == "dist":  # fewer coefficients than 5 (or none) are allowed: zeros
        return {"wrong shape": np.zeros((3, 3)), "too long": np.zeros(15), "wrong dtype": np.zeros(5, complex),
                "NaN": np.array([np.nan, 0, 0, 0, 0]), "inf": np.array([0, np.inf, 0, 0, 0])}
    if kind == "mask-list":
        mask = np.asarray(good)[0]
        return {
            "wrong shape": [mask[:, :-1]] * 3,
            "wrong dtype": [mask.astype(complex)] * 3,
            "NaN": [np.where(mask, np.nan, 0.0)] * 3,
            "empty": [np.zeros((0, 0), bool)] * 3,
            "mismatched sizes": [mask, mask[:-2], mask],
        }
    array = np.asarray(good)
    variants: dict[str, object] = {
        "wrong shape": array.reshape(-1)[:-1] if array.size > 1 else np.zeros((2, 2)),
        "wrong dtype": array.astype(complex) if kind == "float" else array.astype(str),
        "empty": array[:0],
    }
    if kind == "float":
        for name, value in (("NaN", np.nan), ("inf", np.inf)):
            bad = array.astype(np.float64).copy()
            bad.flat[0] = value
            variants[name] = bad
    else:
        bad = array.astype(np.float64)
        bad.flat[0] = np.nan
        variants["NaN"] = bad
    return variants


def _api_rows() -> dict[str, tuple[str, str, str]]:
    rows = {}
    for entry, (_, valid, arguments) in ENTRIES.items():
        for argument, (kind, _) in arguments.items():
            for variant in _variants(kind, valid()[argument]):
                rows[f"{entry}({argument}): {variant}"] = (entry, argument, variant)
    return rows


API_ROWS = _api_rows()


def test_the_valid_arguments_are_accepted() -> None:
    """Else every API row would pass for the wrong reason."""
    for entry, (call, valid, _) in ENTRIES.items():
        call(**valid())


@pytest.mark.parametrize("row", list(API_ROWS))
def test_python_entry_point_row(row: str) -> None:
    entry, argument, variant = API_ROWS[row]
    call, valid, arguments = ENTRIES[entry]
    kwargs = valid()
    kind, named = arguments[argument]
    kwargs[argument] = _variants(kind, kwargs[argument])[variant]
    with pytest.raises(ElastocapError) as raised:
        call(**kwargs)
    assert named in str(raised.value), f"{row}: the message does not name {named!r}: {raised.value}"
    _MATRIX[row] = f"{type(raised.value).__name__}: {raised.value}"[:300]


@pytest.mark.parametrize("row", ["hull: NaN in the calibration", "export: object array (pickle) in a fit frame",
                                 "rig convert: COLMAP images.bin truncated"])
def test_the_console_entry_point_exits_2_with_one_line(row: str, base: Path, tmp_path: Path,
                                                       request: pytest.FixtureRequest) -> None:
    """A few rows end to end through ``python -m elastocap``: exit status 2, one line on
    stderr, no traceback."""
    kind, spec = CLI_ROWS[row]
    if kind == "capture":
        argv, expected = _capture_row(*spec, tmp_path, base)  # type: ignore[misc]
    elif kind == "fitted":
        argv, expected = spec(tmp_path, request.getfixturevalue("fitted"))  # type: ignore[operator]
    else:
        argv, expected = spec(tmp_path, base)  # type: ignore[operator]
    run = subprocess.run([sys.executable, "-m", "elastocap", *argv], capture_output=True, text=True,
                         timeout=ROW_TIMEOUT, check=False)
    assert run.returncode == 2, run.stderr
    lines = [line for line in run.stderr.splitlines() if line.strip() and "Warning" not in line and not line.startswith("  ")]
    assert len(lines) == 1 and "Traceback" not in run.stderr, run.stderr
    assert re.search(expected, lines[0]), lines[0]
