"""The temple set written in each calibration format and read back carves the same hull:
at most 0.01% of the voxels differ (issue 13's "Done when"). The OpenCV stereo format
holds a pair: the first two views, re-expressed in the first camera's frame."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import elastocap
from elastocap import Grid, Rig, visual_hull
from data_paths import TEMPLE

pytestmark = pytest.mark.skipif(not TEMPLE.exists(), reason="shared data not present")

# The bound: fraction of the grid's voxels whose occupancy may differ.
MAX_DIFFERING_FRACTION = 1e-4
OUTPUTS = ["easymocap", "rig.json", "rig_par.txt", "colmap/cameras.txt", "colmap-binary/cameras.bin",
           "calib.toml", "transforms.json"]


@pytest.fixture(scope="module")
def temple():
    """The rig, threshold silhouettes inside the data set's bounding box (as in
    tests/test_hull.py; the segmentation does not matter here, only that every format
    carves the same hull from the same masks) and test_hull's 250-voxel grid."""
    rig = Rig.load(TEMPLE / "templeSR_par.txt")
    lo = np.array([-0.073568, 0.021728, -0.012445]) - 0.005
    hi = np.array([0.028855, 0.181892, 0.062736]) + 0.005
    corners = np.array(np.meshgrid(*zip(lo, hi), indexing="ij")).reshape(3, -1).T
    masks = {}
    for name, camera in zip(rig.names, rig.cameras):
        image = cv2.imread(str(TEMPLE / f"{name}.png"))[:, :, ::-1]
        uv, _ = camera.project(corners)
        roi = np.zeros(image.shape[:2], np.uint8)
        cv2.fillConvexPoly(roi, cv2.convexHull(np.round(uv).astype(np.int32)), 1)
        masks[name] = elastocap.threshold_dark_background(image, 48, open_radius=1, close_radius=4, min_area=500) & roi.astype(bool)
    grid = Grid.around(lo, hi, 250)
    return rig, masks, grid, visual_hull(masks, rig, grid, footprint="center").occupancy


def differing_fraction(a: np.ndarray, b: np.ndarray) -> float:
    return float((a != b).sum()) / a.size


@pytest.mark.parametrize("output", OUTPUTS)
def test_temple_written_in_each_format_carves_the_same_hull(tmp_path, temple, output):
    rig, masks, grid, expected = temple
    target = rig.save(tmp_path / output)
    back = Rig.load(target, size=(640, 480) if output.endswith("_par.txt") else None)
    occupancy = visual_hull(masks, back, grid, footprint="center").occupancy
    fraction = differing_fraction(occupancy, expected)
    print(f"{output}: {fraction:.3g} of {expected.size} voxels differ ({(occupancy != expected).sum()})")
    assert fraction <= MAX_DIFFERING_FRACTION


def test_temple_pair_in_opencv_stereo_carves_the_same_hull(tmp_path, temple):
    rig, masks, grid, _ = temple
    names = rig.names[:2]
    pair = Rig([rig[name] for name in names]).relative_to(names[0])
    # The temple's box in the first camera's frame, on a grid of the same spacing.
    corners = np.array(np.meshgrid(*zip(grid.origin, grid.origin + grid.spacing * (np.array(grid.shape) - 1)),
                                   indexing="ij")).reshape(3, -1).T
    moved = corners @ rig[names[0]].R.T + rig[names[0]].t
    pair_grid = Grid.around(moved.min(axis=0), moved.max(axis=0), 160)
    pair_masks = {name: masks[name] for name in names}
    expected = visual_hull(pair_masks, pair, pair_grid, footprint="center").occupancy
    back = Rig.load(pair.save(tmp_path / "stereo.yml"))
    occupancy = visual_hull(pair_masks, back, pair_grid, footprint="center").occupancy
    fraction = differing_fraction(occupancy, expected)
    print(f"stereo.yml: {fraction:.3g} of {expected.size} voxels differ")
    assert expected.any() and fraction <= MAX_DIFFERING_FRACTION
