"""The rest frame chosen without ground truth (issue 17): the model is its rest frame's hull
and keeps that hull's phantom volume for the whole sequence, so the rest frame is the one
whose target encloses the least volume (a carved hull only errs outwards)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import elastocap
from elastocap import ElasticModel, InvalidInputError, fit_sequence
from elastocap.elastic.measures import surface_error
from elastocap.elastic.rest import least_volume_frame, target_volume
from elastocap.hull.carve import Hull

H = 0.02


def _u_shape(shift: float, filled: bool) -> Hull:
    """A U of 0.6 x 0.45 x 0.3 m (a 0.3 x 0.3 m notch open at the top) moved ``shift`` along
    x, on a grid of 2 cm voxels; ``filled``: the notch full, as a hull whose cameras could
    not see into it holds it (phantom volume)."""
    grid = elastocap.Grid(np.array([-0.5, -0.2, -0.3]), H, (60, 40, 30))
    c = grid.centers()
    x, y, z = c[..., 0] - shift, c[..., 1], c[..., 2]
    body = (np.abs(x) < 0.3) & (y > 0.0) & (y < 0.45) & (np.abs(z) < 0.15)
    notch = (np.abs(x) < 0.15) & (y > 0.15)
    return Hull(body if filled else body & ~notch, grid)


@pytest.fixture(scope="module")
def sequence() -> tuple[list[Hull], list[trimesh.Trimesh]]:
    # Frame 0 has the phantom; the truths are the U itself.
    hulls = [_u_shape(0.0, True)] + [_u_shape(0.04 * f, False) for f in range(1, 4)]
    truths = [_u_shape(0.04 * f, False).mesh() for f in range(4)]
    return hulls, truths


def test_the_least_volume_frame_is_the_one_without_phantom_volume(sequence: tuple) -> None:
    hulls, _ = sequence
    assert target_volume(hulls[0]) > 1.2 * target_volume(hulls[1])
    assert least_volume_frame(hulls) == 1
    # Keyed by capture frame numbers, the answer is a frame number.
    assert least_volume_frame({10: hulls[0], 12: hulls[2], 11: hulls[1]}) == 11
    # The three kinds of 3-D target agree on the volume.
    mesh = hulls[1].mesh()
    assert target_volume(mesh) == pytest.approx(target_volume(hulls[1]), rel=0.05)
    assert target_volume(hulls[1].sdf()) == pytest.approx(target_volume(hulls[1]), rel=1e-9)


def test_a_fit_from_the_least_volume_frame_ends_closer_to_the_truth(sequence: tuple) -> None:
    hulls, truths = sequence
    errors = {}
    for rest in (0, least_volume_frame(hulls)):
        model = ElasticModel.from_mesh(hulls[rest].mesh(), n_nodes=400)
        fit = fit_sequence(model, hulls, rest_frame=rest)
        errors[rest] = np.array([surface_error(fit.surface(f), truths[f]).mean for f in range(1, 4)])
    print("mean distance to the truth, frames 1-3, mm:", {k: np.round(1000 * v, 1) for k, v in errors.items()})
    # The model built on the filled U keeps most of the notch's material (its volume term
    # holds the rest volume); built on the U it has none to keep.
    assert np.all(errors[1] < 0.5 * errors[0])


def test_least_volume_frame_rejects_bad_targets() -> None:
    with pytest.raises(InvalidInputError, match="empty"):
        least_volume_frame([])
    with pytest.raises(InvalidInputError, match="Hull or a trimesh"):
        least_volume_frame([np.zeros((4, 4), dtype=bool)])


def test_the_fit_stage_builds_the_model_on_the_least_volume_hull(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import json

    from elastocap.pipeline.fit import load_model, run_fit_stage
    from elastocap.pipeline.hull import load_hull
    from elastocap.synth.capture import write_synthetic_capture

    # Seed 3: the second frame's hull is the least (0.46 against 0.48-0.52), not the first.
    capture = write_synthetic_capture(tmp_path / "capture", frames=4, cameras=4, image_size=(96, 72), spacing=0.04,
                                      seed=3, progress=False)
    out = tmp_path / "out"
    fit = run_fit_stage(capture, out, resolution=32, n_nodes=150, reprojection=False, progress=False)
    hulls = {f: load_hull(out, f) for f in range(4)}
    expected = least_volume_frame(hulls)
    assert expected != 0
    assert fit.rest_frame == expected == load_model(out)[1]
    assert json.loads((out / "metrics.json").read_text())["summary"]["rest_frame"] == expected
    volumes = [target_volume(hulls[f]) for f in range(4)]
    assert volumes[expected] == min(volumes)
    # A given rest frame is kept.
    given = run_fit_stage(capture, tmp_path / "given", rest_frame=3, resolution=32, n_nodes=150, reprojection=False,
                          progress=False)
    assert given.rest_frame == 3 == load_model(tmp_path / "given")[1]
