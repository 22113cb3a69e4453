"""Fitting a 2-D elastic model through a sequence of binary masks (issue 5: "2-D works the
same way on mask sequences"): contours tracked to a pixel, area following the masks,
outward normals whatever the contour orientation, bad input."""

from __future__ import annotations

import numpy as np
import pytest

import elastocap
from elastocap import ElasticModel, InvalidInputError, fit_sequence
from tolerances import FIT_2D_AREA_RTOL, FIT_2D_MEAN_PIXELS

H, W = 160, 200
_rows, _cols = np.mgrid[0:H, 0:W]


def ellipse(cx: float, cy: float, a: float, b: float, angle: float = 0.0) -> np.ndarray:
    """A filled ellipse mask (H, W): centre (cx, cy) in pixel coordinates (column, row)."""
    c, s = np.cos(angle), np.sin(angle)
    u = (_cols - cx) * c + (_rows - cy) * s
    v = -(_cols - cx) * s + (_rows - cy) * c
    return (u / a) ** 2 + (v / b) ** 2 <= 1


@pytest.mark.parametrize("stretch", [0.0, 2.0], ids=["rigid", "growing"])
def test_mask_sequence_is_tracked(stretch: float) -> None:
    """An ellipse moving, turning by 0.15 rad per frame and (in one case) growing: every
    frame's contour nodes end within a pixel of the mask's boundary on average, and the
    fitted area follows the masks' area."""
    masks = [ellipse(80 + 6 * t, 80 - 3 * t, 40 + stretch * t, 25, 0.15 * t) for t in range(6)]
    model = ElasticModel.from_mask(masks[0], n_nodes=600, rotation="warped")
    fit = fit_sequence(model, masks)
    assert fit.frames == list(range(6))
    rest_area = fit.fits[0].metrics["volume_ratio"]
    for frame in fit.frames:
        metrics = fit.fits[frame].metrics
        assert metrics["mean_distance"] < FIT_2D_MEAN_PIXELS, (frame, metrics)
        expected = masks[frame].sum() / masks[0].sum()
        assert metrics["volume_ratio"] / rest_area == pytest.approx(expected, rel=FIT_2D_AREA_RTOL), frame
        assert fit.fits[frame].positions.shape == (model.n_nodes, 2)


def test_contour_orientation_does_not_matter() -> None:
    """Reversed contour edges (inward normals) are reoriented: the same fit."""
    masks = [ellipse(90, 80, 40, 25), ellipse(96, 80, 40, 25)]
    model = ElasticModel.from_mask(masks[0], n_nodes=400)
    flipped = ElasticModel(
        model.nodes, model.volumes, k=model.k, rotation=model.rotation,
        surface_nodes=model.surface_nodes, surface_faces=model.surface_faces[:, ::-1],
    )
    a = fit_sequence(model, masks).fits[1].positions
    b = fit_sequence(flipped, masks).fits[1].positions
    np.testing.assert_allclose(a, b, atol=1e-9)
    # The fit moved the body towards the target (6 pixels to the right).
    assert 4 < float(np.mean(a[:, 0] - model.nodes[:, 0])) < 8


def test_bad_masks_are_clear_errors() -> None:
    model = ElasticModel.from_mask(ellipse(90, 80, 40, 25), n_nodes=300)
    with pytest.raises(InvalidInputError, match="empty or full"):
        fit_sequence(model, [ellipse(90, 80, 40, 25), np.zeros((H, W), bool)])
    with pytest.raises(InvalidInputError, match=r"\(H, W\)"):
        fit_sequence(model, [np.zeros((H, W, 3), bool)])
    with pytest.raises(InvalidInputError, match="surface"):
        fit_sequence(ElasticModel(model.nodes, model.volumes), [ellipse(90, 80, 40, 25)])
    core = elastocap._core.FitCore(model._core, model.surface_nodes, model.surface_faces)
    with pytest.raises(InvalidInputError, match="one voxel thick"):
        core.fit_frame(np.zeros((4, 4, 2)), (0.0, 0.0, 0.0), 1.0, model.nodes)
