"""Exports of a fitted sequence and of a body fit, read back by the readers users have:
GLB by pygltflib (every frame's vertices through the morph weights animation), PC2 byte for
byte against a file written here from the format's description, USD by usd-core, BVH by
bvhio, .c3d by ezc3d, .trc by numpy."""

from __future__ import annotations

import json
import struct
import warnings
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import trimesh

from elastocap import InvalidInputError
from elastocap.body.model import Z_UP_TO_WORLD, BodyModel, BodyState
from elastocap.pipeline.cli import main
from elastocap.pipeline.export import (
    ExportSettings,
    ExportSpace,
    FrameRateWarning,
    MeshSequence,
    export_settings,
    export_take,
    load_body_take,
    load_fitted_sequence,
)
from elastocap.pipeline.export.pc2 import write_obj, write_pc2
from elastocap.pipeline.fit import run_fit_stage
from elastocap.synth.capture import write_synthetic_capture

from tolerances import EXPORT_BVH_ATOL, EXPORT_C3D_ATOL, EXPORT_DIAGONAL_RTOL, EXPORT_TRC_ATOL

Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x, y, z) -> (x, z, -y)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory) -> Path:
    """A small capture fitted by the fit stage: 4 frames, 4 cameras, 160 x 120."""
    root = tmp_path_factory.mktemp("export")
    capture = write_synthetic_capture(root / "capture", frames=4, cameras=4, image_size=(160, 120), progress=False)
    out = root / "out"
    run_fit_stage(capture, out, n_nodes=200, resolution=32, progress=False)
    return out


def _truth(out: Path, frame: int) -> np.ndarray:
    """A frame's surface vertices from the fit stage's own files (world units)."""
    with np.load(out / "model" / "rest.npz") as model, np.load(out / "fit" / f"{frame:06d}.npz") as fit:
        return fit["positions"][model["surface_nodes"]]


def _accessor(document: pygltflib.GLTF2, blob: bytes, index: int) -> np.ndarray:
    accessor = document.accessors[index]
    view = document.bufferViews[accessor.bufferView]
    dtype = {pygltflib.FLOAT: "<f4", pygltflib.UNSIGNED_INT: "<u4"}[accessor.componentType]
    width = {"SCALAR": 1, "VEC3": 3}[accessor.type]
    start = view.byteOffset + accessor.byteOffset
    values = np.frombuffer(blob, dtype=dtype, count=accessor.count * width, offset=start)
    return values.reshape(accessor.count, width) if width > 1 else values


def _glb_frames(path: Path) -> tuple[dict[float, np.ndarray], np.ndarray, np.ndarray, pygltflib.GLTF2]:
    """Vertices at every key time of the weights animation, normals at those times, faces."""
    document = pygltflib.GLTF2().load(str(path))
    blob = document.binary_blob()
    primitive = document.meshes[0].primitives[0]
    base = _accessor(document, blob, primitive.attributes.POSITION).astype(np.float64)
    base_normals = _accessor(document, blob, primitive.attributes.NORMAL).astype(np.float64)
    deltas = np.stack([_accessor(document, blob, t["POSITION"]) for t in primitive.targets]).astype(np.float64)
    normal_deltas = np.stack([_accessor(document, blob, t["NORMAL"]) for t in primitive.targets]).astype(np.float64)
    sampler = document.animations[0].samplers[0]
    assert sampler.interpolation == "STEP"
    assert document.animations[0].channels[0].target.path == "weights"
    times = _accessor(document, blob, sampler.input)
    weights = _accessor(document, blob, sampler.output).reshape(len(times), len(primitive.targets))
    frames = {float(t): base + np.einsum("k,kvd->vd", w, deltas) for t, w in zip(times, weights)}
    normals = np.stack([base_normals + np.einsum("k,kvd->vd", w, normal_deltas) for w in weights])
    faces = _accessor(document, blob, primitive.indices).reshape(-1, 3)
    return frames, normals, faces, document


def test_glb_reproduces_every_fitted_frame_at_its_time(fitted, tmp_path):
    sequence = load_fitted_sequence(fitted)
    settings = ExportSettings(take="walk", fps=25.0, space=ExportSpace())
    (path,) = export_take(fitted, ["glb"], settings)
    assert path == fitted / "export" / "walk.glb"
    frames, normals, faces, document = _glb_frames(path)
    assert sorted(frames) == pytest.approx([f / 25.0 for f in sequence.frames])
    np.testing.assert_array_equal(faces, sequence.faces)
    for frame, time in zip(sequence.frames, sorted(frames)):
        truth = _truth(fitted, frame)
        diagonal = np.linalg.norm(np.ptp(truth, axis=0))
        assert np.abs(frames[time] - truth).max() <= EXPORT_DIAGONAL_RTOL * diagonal
    # Normals per target: the frame's own area-weighted vertex normals, from trimesh's faces.
    for k, frame in enumerate(sequence.frames):
        mesh = trimesh.Trimesh(_truth(fitted, frame), sequence.faces, process=False)
        summed = mesh.faces_sparse @ (mesh.face_normals * mesh.area_faces[:, None])
        length = np.linalg.norm(summed, axis=1)
        # A vertex whose faces' normals cancel (two faces back to back: a fin the remeshed
        # surface can have at 200 nodes) has no normal; rounding gives trimesh a direction.
        defined = length > 1e-9 * mesh.area_faces.max()
        assert defined.mean() > 0.97
        np.testing.assert_allclose(normals[k][defined], summed[defined] / length[defined, None], atol=1e-6)
    assert document.meshes[0].extras["targetNames"] == [f"frame_{f:06d}" for f in sequence.frames]


def test_glb_converts_millimetres_and_z_up_to_metres_and_y_up(tmp_path):
    rng = np.random.default_rng(3)
    rest = rng.normal(size=(5, 3)) * 1000
    shapes = {f: rest + rng.normal(size=(5, 3)) * 50 for f in (10, 12, 14)}
    sequence = MeshSequence(frames=[10, 12, 14], faces=np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2]]), rest=rest, read=shapes.__getitem__)
    settings = ExportSettings(take="mm", fps=50.0, space=ExportSpace(scale=0.001, up="z"))
    from elastocap.pipeline.export.gltf import write_glb

    frames, _, _, _ = _glb_frames(write_glb(tmp_path / "mm.glb", sequence, settings))
    # Gaps in the frame numbers are kept as gaps in time.
    assert sorted(frames) == pytest.approx([0.0, 0.04, 0.08])
    for frame, time in zip((10, 12, 14), sorted(frames)):
        np.testing.assert_allclose(frames[time], 0.001 * shapes[frame] @ Z_UP.T, atol=1e-6)


def _hand_written_pc2(points: list[np.ndarray], start: float, rate: float) -> bytes:
    """A PC2 file from the format's description: a 12-byte signature "POINTCACHE2" and a NUL,
    int32 version 1, int32 number of points, float32 start frame, float32 sample rate, int32
    number of samples, then every sample's points as float32 x, y, z; all little-endian."""
    data = b"POINTCACHE2\x00"
    data += struct.pack("<i", 1) + struct.pack("<i", len(points[0]))
    data += struct.pack("<f", start) + struct.pack("<f", rate) + struct.pack("<i", len(points))
    for sample in points:
        for x, y, z in sample:
            data += struct.pack("<fff", x, y, z)
    return data


def test_pc2_matches_a_hand_written_file_byte_for_byte(tmp_path):
    rest = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    shapes = {f: rest * (1 + 0.1 * f) + [0.25 * f, -0.5, 3.0] for f in (4, 6, 8)}
    sequence = MeshSequence(frames=[4, 6, 8], faces=faces, rest=rest, read=shapes.__getitem__)
    settings = ExportSettings(take="tet", fps=24.0, space=ExportSpace())
    written = write_pc2(tmp_path / "tet.pc2", sequence, settings).read_bytes()
    assert written == _hand_written_pc2([shapes[f] for f in (4, 6, 8)], start=4.0, rate=2.0)
    # The rest OBJ lists the vertices in the cache's order.
    obj = trimesh.load(write_obj(tmp_path / "tet.obj", sequence, settings), process=False)
    np.testing.assert_allclose(obj.vertices, rest)
    np.testing.assert_array_equal(obj.faces, faces)


def test_pc2_of_the_fit_holds_every_frame_and_refuses_uneven_frames(fitted, tmp_path):
    sequence = load_fitted_sequence(fitted)
    settings = ExportSettings(take="walk", fps=30.0, space=ExportSpace())
    data = write_pc2(tmp_path / "walk.pc2", sequence, settings).read_bytes()
    version, count, start, rate, samples = struct.unpack("<iiffi", data[12:32])
    assert data[:12] == b"POINTCACHE2\x00" and version == 1
    assert (count, start, rate, samples) == (sequence.n_vertices, 0.0, 1.0, len(sequence.frames))
    points = np.frombuffer(data[32:], dtype="<f4").reshape(samples, count, 3)
    for k, frame in enumerate(sequence.frames):
        np.testing.assert_allclose(points[k], _truth(fitted, frame), atol=1e-6)
    uneven = MeshSequence(frames=[0, 1, 3], faces=sequence.faces, rest=sequence.rest, read=sequence.read)
    with pytest.raises(InvalidInputError, match="evenly spaced"):
        write_pc2(tmp_path / "uneven.pc2", uneven, settings)


def test_usd_time_samples_read_back_by_usd_core(fitted, tmp_path, monkeypatch):
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom

    from elastocap.pipeline.export import usd

    monkeypatch.setattr(usd, "CLIP_FRAMES", 3)  # 4 frames: two clip layers
    sequence = load_fitted_sequence(fitted)
    settings = ExportSettings(take="walk", fps=24.0, space=ExportSpace(scale=0.5, up="z"))
    path = usd.write_usd(tmp_path / "walk.usd", sequence, settings)
    assert sorted(p.name for p in (tmp_path / "walk_clips").iterdir()) == ["000000.usdc", "000003.usdc", "manifest.usda"]
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == 24.0 and UsdGeom.GetStageUpAxis(stage) == "Y"
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    mesh = UsdGeom.Mesh(stage.GetDefaultPrim().GetChild("surface"))
    np.testing.assert_array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()), sequence.faces.reshape(-1))
    assert mesh.GetPointsAttr().GetTimeSamples() == [float(f) for f in sequence.frames]
    for frame in sequence.frames:
        points = np.array(mesh.GetPointsAttr().Get(Usd.TimeCode(frame)))
        np.testing.assert_allclose(points, 0.5 * _truth(fitted, frame) @ Z_UP.T, atol=1e-6)


def _body_fit(out: Path, frames: list[int], seed: int = 0) -> tuple[BodyModel, np.ndarray, np.ndarray]:
    """A body fit record of the default human with random shape and motion within limits."""
    model = BodyModel.default_human()
    rng = np.random.default_rng(seed)
    motion = rng.uniform(model.lower, model.upper, (len(frames), model.n_motion)) * 0.7
    motion[:, :3] = rng.normal(size=(len(frames), 3))
    motion[:, 3:6] = rng.uniform(-3, 3, (len(frames), 3)) * [1, 0.4, 1]
    # A record as written before the depth and taper coefficients ((length, width) per
    # part): read back as depth = width, taper 1.
    pairs = rng.uniform(0.9, 1.1, 2 * len(model.part_names))
    shape = model.as_shape(pairs)
    record = {
        "frames": frames,
        "parts": model.part_names,
        "motion_names": model.motion_names,
        "shape": {p: {"length": pairs[2 * i], "width": pairs[2 * i + 1]} for i, p in enumerate(model.part_names)},
        "motion": motion.tolist(),
        "R_body_to_world": Z_UP_TO_WORLD.tolist(),
    }
    (out / "body").mkdir(parents=True, exist_ok=True)
    (out / "body" / "fit.json").write_text(json.dumps(record))
    return model, shape, motion


def _joints(model: BodyModel, shape: np.ndarray, motion: np.ndarray, space: ExportSpace) -> np.ndarray:
    """Joint positions (part origins) of one frame in export space."""
    _, origins = model.pose(BodyState(shape, motion))
    return space.scale * origins @ (space.rotation @ Z_UP_TO_WORLD).T


@pytest.mark.parametrize("up", ["y", "z"])
def test_bvh_read_by_bvhio_puts_every_joint_where_the_model_does(tmp_path, up):
    bvhio = pytest.importorskip("bvhio")
    model, shape, motion = _body_fit(tmp_path, [3, 4, 5, 6])
    settings = ExportSettings(take="body", fps=30.0, space=ExportSpace(up=up))
    (path,) = export_take(tmp_path, ["bvh"], settings)
    root = bvhio.readAsHierarchy(str(path))
    joints = {joint.Name: joint for joint, _, _ in root.layout()}
    assert set(model.part_names) <= set(joints)
    assert len(root.getKeyframeRange()) and root.getKeyframeRange()[1] == 3
    for k in range(4):
        root.loadPose(k)
        found = np.array([list(joints[name].PositionWorld) for name in model.part_names])
        np.testing.assert_allclose(found, _joints(model, shape, motion[k], settings.space), atol=EXPORT_BVH_ATOL)
    assert "Frame Time: 0.03333333" in path.read_text()


def test_trc_and_c3d_hold_the_joint_trajectories(tmp_path):
    ezc3d = pytest.importorskip("ezc3d")
    model, shape, motion = _body_fit(tmp_path, [0, 1, 2], seed=1)
    settings = ExportSettings(take="body", fps=60.0, space=ExportSpace(scale=0.001, up="z"))
    trc, c3d_path = export_take(tmp_path, ["trc", "c3d"], settings)
    expected = np.stack([_joints(model, shape, m, settings.space) for m in motion])
    lines = trc.read_text().splitlines()
    assert lines[2].split("\t")[:5] == ["60", "60", "3", str(len(model.part_names)), "m"]
    assert lines[3].split("\t")[2] == model.part_names[0]
    table = np.loadtxt(trc, skiprows=6, delimiter="\t")
    np.testing.assert_allclose(table[:, 0], [1, 2, 3])
    np.testing.assert_allclose(table[:, 1], [0, 1 / 60, 2 / 60], atol=1e-6)
    np.testing.assert_allclose(table[:, 2:].reshape(3, -1, 3), expected, atol=EXPORT_TRC_ATOL)
    c3d = ezc3d.c3d(str(c3d_path))
    assert c3d["parameters"]["POINT"]["LABELS"]["value"] == model.part_names
    assert c3d["parameters"]["POINT"]["RATE"]["value"][0] == 60.0
    assert c3d["parameters"]["POINT"]["UNITS"]["value"] == ["m"]
    np.testing.assert_allclose(np.moveaxis(c3d["data"]["points"][:3], 2, 0), np.swapaxes(expected, 1, 2), atol=EXPORT_C3D_ATOL)


def test_settings_come_from_the_capture_config_or_default_with_a_warning(tmp_path):
    out = tmp_path / "take7"
    out.mkdir()
    with pytest.warns(FrameRateWarning, match="30 frames per second"):
        settings = export_settings(out)
    assert (settings.take, settings.fps, settings.space) == ("take7", 30.0, ExportSpace(1.0, "y"))
    (out / "capture.toml").write_text('capture = "/data/dance"\nfps = 59.94\nunits = "mm"\nup = "z"\n')
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        settings = export_settings(out)
    assert (settings.take, settings.fps, settings.space) == ("dance", 59.94, ExportSpace(0.001, "z"))
    assert export_settings(out, fps=25, units="0.01", up="y").space == ExportSpace(0.01, "y")
    with pytest.raises(InvalidInputError, match="units"):
        export_settings(out, units="furlongs")
    with pytest.raises(InvalidInputError, match="fps"):
        export_settings(out, fps=-1)
    (out / "capture.toml").write_text("fps = = 3\n")
    with pytest.raises(InvalidInputError, match="capture.toml"):
        export_settings(out)


def test_export_command_writes_the_files_and_names_what_is_missing(fitted, tmp_path, capsys):
    assert main(["export", str(fitted), "--format", "glb", "pc2", "--fps", "25", "--take", "cli"]) == 0
    for name in ("cli.glb", "cli.pc2", "cli.obj"):
        assert (fitted / "export" / name).stat().st_size > 0
    assert not list((fitted / "export").glob(".*")), "temporary files left behind"
    assert main(["export", str(fitted), "--format", "bvh", "--fps", "25"]) == 2
    assert "body/fit.json" in capsys.readouterr().err
    assert main(["export", str(tmp_path), "--format", "glb", "--fps", "25"]) == 2
    assert "run the fit stage first" in capsys.readouterr().err
