"""Phantom components of a hull: dropped when they explain no silhouette pixel, the subject
and real separate pieces kept."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy import ndimage

from elastocap import Grid, InvalidInputError, visual_hull
from elastocap.hull import drop_phantoms
from test_hull import ellipsoid, render, ring

AXES = np.array([0.5, 0.35, 0.25])
CONNECTED = np.ones((3, 3, 3), dtype=bool)


def components(occupancy: np.ndarray) -> int:
    return ndimage.label(occupancy, structure=CONNECTED)[1]


@pytest.mark.parametrize("half", [1.5, 2.0, 2.5])
def test_space_few_cameras_see_is_dropped_and_the_subject_kept(half):
    # A grid reaching toward the cameras: space seen by one or two of them is carved by
    # no other and keeps blobs on their rays through the silhouette, some larger than the
    # subject (half 2.0 and 2.5).
    mesh, rig = ellipsoid(tuple(AXES)), ring(8)
    grid = Grid.around([-half] * 3, [half] * 3, 64)
    masks = [render(mesh, c) for c in rig.cameras]
    hull = visual_hull(masks, rig, grid)
    assert components(hull.occupancy) >= 4
    kept = drop_phantoms(hull, masks, rig)
    assert components(kept.occupancy) == 1
    inside = ((grid.centers() / AXES) ** 2).sum(axis=-1) <= 1
    assert kept.occupancy[inside].all(), "the subject's voxels are all kept"
    # What is left hugs the subject: every kept voxel within a few voxels of it.
    centres = grid.centers()[kept.occupancy]
    assert np.sqrt(((centres / AXES) ** 2).sum(axis=-1)).max() < 1 + 3 * grid.spacing / AXES.min()
    assert (kept.occupancy <= hull.occupancy).all()
    assert kept.grid is hull.grid


@pytest.mark.parametrize("half", [0.7, 2.0])
def test_two_real_pieces_are_both_kept(half):
    pieces = [(np.array([0.3, 0.2, 0.2]), np.array([-0.4, 0.0, 0.0])), (np.array([0.15, 0.15, 0.15]), np.array([0.45, 0.1, 0.1]))]
    meshes = []
    for axes, centre in pieces:
        meshes.append(ellipsoid(tuple(axes)))
        meshes[-1].apply_translation(centre)
    rig = ring(8)
    grid = Grid.around([-half] * 3, [half] * 3, 64)
    masks = [render(trimesh.util.concatenate(meshes), c) for c in rig.cameras]
    kept = drop_phantoms(visual_hull(masks, rig, grid), masks, rig)
    assert components(kept.occupancy) == 2
    for axes, centre in pieces:
        inside = (((grid.centers() - centre) / axes) ** 2).sum(axis=-1) <= 1
        assert kept.occupancy[inside].all(), "every voxel of each piece is kept"


def test_a_hull_of_one_component_is_returned_as_it_is():
    mesh, rig = ellipsoid(tuple(AXES)), ring(8)
    grid = Grid.around([-0.7] * 3, [0.7] * 3, 40)
    masks = [render(mesh, c) for c in rig.cameras]
    hull = visual_hull(masks, rig, grid)
    assert components(hull.occupancy) == 1
    assert drop_phantoms(hull, masks, rig) is hull


def test_bad_input():
    mesh, rig = ellipsoid(tuple(AXES)), ring(4)
    grid = Grid.around([-0.7] * 3, [0.7] * 3, 24)
    masks = [render(mesh, c) for c in rig.cameras]
    hull = visual_hull(masks, rig, grid)
    with pytest.raises(InvalidInputError, match="hull must be a Hull"):
        drop_phantoms(hull.occupancy, masks, rig)
    with pytest.raises(InvalidInputError, match="masks"):
        drop_phantoms(hull, masks[:3], rig)
    with pytest.raises(InvalidInputError, match="min_pixels"):
        drop_phantoms(hull, masks, rig, min_pixels=0)
