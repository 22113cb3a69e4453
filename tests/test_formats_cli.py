"""``elastocap rig convert`` and ``elastocap rig show``: conversions by output name, refusals
as one-line errors, the rig table, sanity warnings and the picture."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest

from elastocap import Camera, Rig
from elastocap.cameras import CalibrationWarning
from elastocap.cameras.show import check_rig
from elastocap.pipeline.cli import main
from test_hull import look_at, ring


def test_convert_by_output_name_and_format_option(tmp_path, capsys):
    rig = ring(4)
    rig.save(tmp_path / "in" / "rig.json")
    assert main(["rig", "convert", str(tmp_path / "in"), str(tmp_path / "out" / "cameras.txt")]) == 0
    assert "wrote 4 cameras" in capsys.readouterr().out
    assert (tmp_path / "out" / "points3D.txt").exists()
    assert main(["rig", "convert", str(tmp_path / "out"), str(tmp_path / "nerf"), "--format", "nerf"]) == 0
    back = Rig.load(tmp_path / "nerf" / "transforms.json")
    for a, b in zip(rig.cameras, back.cameras):
        assert np.array_equal(a.K, b.K) and np.abs(a.R - b.R).max() < 1e-14
    assert main(["rig", "convert", str(tmp_path / "in" / "rig.json"), str(tmp_path / "mm.json"), "--units", "mm"]) == 0
    np.testing.assert_allclose(Rig.load(tmp_path / "mm.json").cameras[1].t, rig.cameras[1].t / 1000, rtol=1e-15)


def test_convert_refusal_is_a_one_line_error(tmp_path, capsys):
    skewed = ring(2).cameras[0]
    K = np.array(skewed.K)
    K[0, 1] = 0.3
    Rig([skewed.replace(K=K)]).save(tmp_path / "rig.json")
    assert main(["rig", "convert", str(tmp_path / "rig.json"), str(tmp_path / "cameras.bin")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("elastocap rig: error: camera 'cam0' has skew") and "\n" not in err


def test_show_prints_checks_and_draws(tmp_path, capsys):
    ring(6).save(tmp_path / "rig.json")
    picture = tmp_path / "rig.png"
    assert main(["rig", "show", str(tmp_path / "rig.json"), "--out", str(picture)]) == 0
    out = capsys.readouterr().out
    assert "6 cameras" in out and "cam5: 320x240 px" in out and "0 warning(s)" in out
    image = cv2.imread(str(picture))
    assert image is not None and image.shape[0] > 100 and (image < 200).any()


def test_a_camera_looking_away_and_a_millimetre_focal_length_are_warned(tmp_path, capsys):
    cameras = list(ring(6).cameras)
    turned, flip = cameras[2], np.diag([-1.0, 1.0, -1.0])
    cameras[2] = turned.replace(R=flip @ turned.R, t=flip @ turned.t)  # same centre, looking the other way
    cameras[4] = cameras[4].replace(K=np.diag([8.0, 8.0, 1.0]) + [[0, 0, 160], [0, 0, 120], [0, 0, 0]])
    rig = Rig(cameras)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        problems = check_rig(rig)
    assert all(issubclass(w.category, CalibrationWarning) for w in caught) and len(caught) == len(problems) == 2
    assert "camera 'cam2' looks away from the volume the other cameras all see" in problems[1]
    assert "is behind it" in problems[1]
    assert "camera 'cam4': fx = 8 px gives a horizontal field of view of 174 deg" in problems[0]
    rig.save(tmp_path / "rig.json")
    assert main(["rig", "show", str(tmp_path / "rig.json"), "--out", str(tmp_path / "r.png")]) == 0
    assert "2 warning(s)" in capsys.readouterr().out


def test_a_plausible_rig_has_no_warning():
    cameras = [look_at(f"c{i}", [3 * np.cos(a), 3 * np.sin(a), 1.0]) for i, a in enumerate(np.linspace(0, 5, 5))]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert check_rig(Rig(cameras)) == []


@pytest.mark.parametrize("name", ["rig.json", "intri.yml", "cameras.txt", "cameras.bin", "transforms.json",
                                  "calib.toml"])
def test_a_convert_killed_while_writing_leaves_the_old_rig(tmp_path, name):
    # The kill-and-resume hook of elastocap._io kills the process at its first atomic write,
    # with the temporary file half written: the rig written before must still read back.
    from resume_runs import command, visible_files

    ring(3).save(tmp_path / "in.json")
    out = tmp_path / "out" / name
    assert main(["rig", "convert", str(tmp_path / "in.json"), str(out)]) == 0
    before = {p: p.read_bytes() for p in visible_files(tmp_path / "out")}
    ring(4).save(tmp_path / "other.json")
    assert command(["rig", "convert", str(tmp_path / "other.json"), str(out)], kill_at_write=1) == -9
    assert {p: p.read_bytes() for p in visible_files(tmp_path / "out")} == before
    assert len(Rig.load(out)) == 3
