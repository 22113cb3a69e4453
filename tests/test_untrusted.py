"""Untrusted files (issue 13, item 6): calibrations, configurations, NPZ and capture folders
from others. No pickle is ever loaded (``allow_pickle=False`` everywhere, no ``eval``), sizes
are bounded before anything is allocated, camera names cannot make elastocap read or write
outside the capture and output folders, and malformed YAML / JSON / TOML / binary files give
a clear error naming the file."""

from __future__ import annotations

import ast
import os
import pathlib
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

import elastocap
from elastocap import InvalidInputError, Rig
from elastocap._io import MAX_ARRAY_BYTES, load_npz
from elastocap.pipeline.cli import main
from elastocap.synth.capture import write_synthetic_capture

PACKAGE = Path(elastocap.__file__).parent


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("untrusted") / "capture"
    return write_synthetic_capture(root, frames=2, cameras=3, image_size=(64, 48), spacing=0.04, progress=False)


@pytest.fixture(scope="module")
def hulls(capture: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("untrusted") / "out"
    assert main(["hull", str(capture), "--out", str(out), "--resolution", "24", "--quiet"]) == 0
    return out


# -- the source itself ------------------------------------------------------------------------


def _sources() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def test_every_np_load_in_the_package_refuses_pickles() -> None:
    calls = []
    for source in _sources():
        for node in ast.walk(ast.parse(source.read_text(), str(source))):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "load"
                    and isinstance(node.func.value, ast.Name) and node.func.value.id in ("np", "numpy")):
                flags = {k.arg: k.value for k in node.keywords}
                safe = isinstance(flags.get("allow_pickle"), ast.Constant) and flags["allow_pickle"].value is False
                calls.append((f"{source.relative_to(PACKAGE)}:{node.lineno}", safe))
    assert calls, "the scan found no np.load at all: it is broken"
    assert [where for where, safe in calls if not safe] == []


def test_no_pickle_eval_or_unsafe_yaml_in_the_package() -> None:
    banned_modules = {"pickle", "cPickle", "dill", "marshal", "shelve", "joblib"}
    found = []
    for source in _sources():
        tree = ast.parse(source.read_text(), str(source))
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
                found += [f"{source.name}:{node.lineno} imports {n}" for n in names if n.split(".")[0] in banned_modules]
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("eval", "exec"):
                found.append(f"{source.name}:{node.lineno} calls {node.func.id}")
            elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                  and isinstance(node.func.value, ast.Name) and node.func.value.id == "yaml"
                  and node.func.attr in ("load", "unsafe_load", "full_load", "load_all")):
                found.append(f"{source.name}:{node.lineno} calls yaml.{node.func.attr}")
    assert found == []


# -- NPZ ------------------------------------------------------------------------------------------


class _Trap:
    """Unpickling this creates ``marker``: proof that a pickle was executed."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):  # type: ignore[no-untyped-def]
        return pathlib.Path.touch, (self.marker,)


def test_a_pickle_in_a_hull_file_is_refused_and_never_run(capture: Path, hulls: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    shutil.copytree(hulls, out)
    marker = tmp_path / "pickle-ran"
    np.savez(out / "hull" / "000001.npz", occupancy=np.array([_Trap(marker)], dtype=object),
             shape=np.array([1, 1, 1]), origin=np.zeros(3), spacing=np.float64(1))
    with pytest.raises(InvalidInputError, match=r"hull/000001\.npz.*occupancy.*pickle"):
        elastocap.load_hull(out, 1)
    assert not marker.exists()
    # The fit stage reads those hulls, and stops at that file.
    with pytest.raises(InvalidInputError, match=r"hull/000001\.npz"):
        elastocap.run_fit_stage(capture, out, n_nodes=100, resolution=24, progress=False)
    assert not marker.exists()


def test_a_pickle_in_a_fitted_frame_is_refused_by_export(tmp_path: Path) -> None:
    out = tmp_path / "out"
    (out / "model").mkdir(parents=True)
    (out / "fit").mkdir()
    marker = tmp_path / "pickle-ran"
    np.savez(out / "model" / "rest.npz", nodes=np.zeros((4, 3)), surface_nodes=np.arange(4),
             surface_faces=np.array([[0, 1, 2], [0, 2, 3]]))
    np.savez(out / "fit" / "000000.npz", positions=np.array([_Trap(marker)], dtype=object))
    (out / "fit" / "000000.ply").write_text("ply\n")
    assert main(["export", str(out), "--format", "pc2"]) == 2
    assert not marker.exists()


def _npz_with_header(path: Path, shape: tuple[int, ...], payload: bytes = b"\0" * 64) -> None:
    """An .npz whose array declares ``shape`` float64 but holds only ``payload``."""
    header = {"descr": "<f8", "fortran_order": False, "shape": shape}
    text = repr(header).encode("latin1")
    pad = 64 - (10 + len(text) + 1) % 64
    npy = b"\x93NUMPY\x01\x00" + (len(text) + pad + 1).to_bytes(2, "little") + text + b" " * pad + b"\n" + payload
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("positions.npy", npy)


def test_an_array_declaring_more_than_allowed_is_refused_before_allocation(tmp_path: Path) -> None:
    path = tmp_path / "big.npz"
    _npz_with_header(path, (MAX_ARRAY_BYTES // 8 + 1,))
    with pytest.raises(InvalidInputError, match=r"big\.npz.*'positions'.*bytes allowed"):
        load_npz(path)
    # Declaring more than the member holds (a zip bomb's lie) is refused too.
    _npz_with_header(path, (10**6, 3))
    with pytest.raises(InvalidInputError, match=r"big\.npz.*more than its stored data"):
        load_npz(path)


@pytest.mark.parametrize("damage", ["truncated", "not a zip", "empty", "missing array"])
def test_damaged_npz_files_name_the_file(damage: str, tmp_path: Path) -> None:
    path = tmp_path / "frame.npz"
    np.savez_compressed(path, positions=np.random.default_rng(0).random((500, 3)))
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif damage == "not a zip":
        path.write_bytes(b"PK\x03\x04" + os.urandom(300))
    elif damage == "empty":
        path.write_bytes(b"")
    with pytest.raises(InvalidInputError, match=r"frame\.npz"):
        load_npz(path, required=("positions", "faces") if damage == "missing array" else ("positions",))


# -- sizes --------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["rig.json", "calib.toml", "transforms.json", "rig_par.txt"])
def test_a_huge_calibration_file_is_refused_without_reading_it(name: str, tmp_path: Path) -> None:
    from elastocap.cameras.formats import MAX_CALIBRATION_BYTES

    path = tmp_path / name
    with open(path, "wb") as f:  # sparse: no disk used, and reading it whole would take long
        f.truncate(MAX_CALIBRATION_BYTES + 1)
    with pytest.raises(InvalidInputError, match=rf"{name.replace('.', '[.]')}.*too large"):
        Rig.load(path)


def test_a_huge_capture_toml_is_refused(capture: Path, tmp_path: Path) -> None:
    cap = tmp_path / "cap"
    shutil.copytree(capture, cap)
    with open(cap / "capture.toml", "wb") as f:
        f.truncate(1 << 30)
    with pytest.raises(InvalidInputError, match=r"capture\.toml.*too large"):
        elastocap.Capture.open(cap)


# -- paths ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["../outside", "a/b", "/tmp/abs", "..", ".", "a\\b", "nul\0byte"])
def test_camera_names_cannot_lead_outside_the_folders(name: str, capture: Path, tmp_path: Path) -> None:
    cap = tmp_path / "cap"
    shutil.copytree(capture, cap)
    rig = Rig.load(cap)
    renamed = Rig([rig.cameras[0].replace(name=name), *rig.cameras[1:]])
    (cap / "intri.yml").unlink()
    (cap / "extri.yml").unlink()
    renamed.save(cap / "rig.json")
    before = set(tmp_path.rglob("*"))
    out = tmp_path / "out"
    with pytest.raises(InvalidInputError, match="not a plain file name"):
        elastocap.Capture.open(cap)
    assert main(["hull", str(cap), "--out", str(out), "--resolution", "24", "--quiet"]) == 2
    assert set(tmp_path.rglob("*")) - before <= {out}, "something was written outside --out"


def test_symlinks_in_a_capture_do_not_lead_writes_outside_out(capture: Path, tmp_path: Path) -> None:
    """A capture whose camera folders are symlinks (to data elsewhere) is read through them,
    and an output folder holding a symlink where a frame's file goes gets the file itself:
    the link is replaced, its target is not written."""
    elsewhere = tmp_path / "elsewhere"
    shutil.copytree(capture / "masks", elsewhere)
    cap = tmp_path / "cap"
    shutil.copytree(capture, cap, ignore=shutil.ignore_patterns("masks"))
    (cap / "masks").mkdir()
    for camera in elsewhere.iterdir():
        (cap / "masks" / camera.name).symlink_to(camera, target_is_directory=True)
    victim = tmp_path / "victim.ply"
    victim.write_text("do not overwrite")
    out = tmp_path / "out"
    (out / "hull").mkdir(parents=True)
    (out / "hull" / "000000.ply").symlink_to(victim)
    snapshot = {p: p.read_bytes() for p in elsewhere.rglob("*") if p.is_file()}
    assert main(["hull", str(cap), "--out", str(out), "--resolution", "24", "--quiet"]) == 0
    assert victim.read_text() == "do not overwrite"
    assert not (out / "hull" / "000000.ply").is_symlink()
    assert {p: p.read_bytes() for p in elsewhere.rglob("*") if p.is_file()} == snapshot
