"""Visual hulls: conservative, converging with more cameras, right on real data."""

from __future__ import annotations


import cv2
import numpy as np
import pytest
import trimesh

import elastocap
from elastocap import Camera, Grid, Rig, visual_hull
from data_paths import TEMPLE
from tolerances import TEMPLE_IOU_MIN



def look_at(name: str, eye, target=(0.0, 0.0, 0.0), size=(320, 240), f=300.0) -> Camera:
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0]) if abs(z[2]) < 0.99 else np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    K = [[f, 0, (size[0] - 1) / 2], [0, f, (size[1] - 1) / 2], [0, 0, 1]]
    return Camera(name, K, np.zeros(5), R, -R @ eye, *size)


def ring(n: int, radius=3.0) -> Rig:
    """n cameras: alternately on a horizontal ring and above/below it, all looking at 0."""
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        elevation = [0.0, 0.6, -0.6][i % 3]
        eye = radius * np.array([np.cos(a) * np.cos(elevation), np.sin(a) * np.cos(elevation), np.sin(elevation)])
        cams.append(look_at(f"cam{i}", eye))
    return Rig(cams)


def render(mesh: trimesh.Trimesh, camera: Camera) -> np.ndarray:
    uv, depth = camera.project(mesh.vertices)
    assert np.all(depth > 0)
    mask = np.zeros((camera.height, camera.width), np.uint8)
    # One call per triangle: a single cv2.fillPoly over all of them fills by the even-odd
    # rule, and overlapping triangles (front and back of the surface) would cancel.
    for triangle in np.round(uv[mesh.faces] * 256).astype(np.int32):
        cv2.fillConvexPoly(mask, triangle, 1, shift=8)
    return mask.astype(bool)


def ellipsoid(axes=(0.5, 0.35, 0.25)) -> trimesh.Trimesh:
    mesh = trimesh.creation.icosphere(subdivisions=4)
    mesh.apply_scale(axes)
    return mesh


GRID = Grid.around([-0.7, -0.7, -0.7], [0.7, 0.7, 0.7], 56)


@pytest.mark.parametrize("n_cameras", [4, 8, 12])
def test_conservative_hull_keeps_every_voxel_the_object_touches(n_cameras):
    mesh, rig = ellipsoid(), ring(n_cameras)
    hull = visual_hull({n: render(mesh, c) for n, c in zip(rig.names, rig.cameras)}, rig, GRID)
    # Voxels whose centre is inside, and voxels holding a point of the surface, are touched.
    centres = GRID.centers()
    inside = ((centres / np.array([0.5, 0.35, 0.25])) ** 2).sum(axis=-1) <= 1
    assert hull.occupancy[inside].all()
    on_surface = np.round(GRID.to_index(mesh.sample(5000))).astype(int)
    assert hull.occupancy[tuple(on_surface.T)].all()


def test_volume_approaches_the_true_volume_as_cameras_are_added():
    mesh = ellipsoid()
    volumes = []
    for n in (4, 8, 12):
        rig = ring(n)
        masks = [render(mesh, c) for c in rig.cameras]
        volumes.append(visual_hull(masks, rig, GRID, footprint="center").volume)
    assert volumes[0] > volumes[1] > volumes[2]
    assert volumes[2] / mesh.volume < 1.25
    assert volumes[2] / mesh.volume > 0.95


def test_sdf_zero_level_is_within_a_voxel_of_the_hull_surface():
    mesh, rig = ellipsoid(), ring(12)
    hull = visual_hull([render(mesh, c) for c in rig.cameras], rig, GRID, footprint="center")
    surface = hull.mesh()
    assert surface.is_watertight
    assert surface.volume > 0, "outward-facing triangles"
    assert np.abs(hull.sdf().sample(surface.vertices)).max() <= GRID.spacing
    # The hull contains the object and, with 12 views of a convex shape, hugs it.
    d = hull.sdf().sample(mesh.sample(2000))
    assert d.max() <= GRID.spacing
    assert d.min() >= -4 * GRID.spacing


def test_tolerance_keeps_voxels_that_one_camera_wrongly_rejects():
    mesh, rig = ellipsoid(), ring(8)
    masks = [render(mesh, c) for c in rig.cameras]
    masks[0][:, : masks[0].shape[1] // 2 + 10] = False  # a camera with half its silhouette lost
    strict = visual_hull(masks, rig, GRID, footprint="center")
    tolerant = visual_hull(masks, rig, GRID, footprint="center", tolerance=1)
    assert tolerant.volume > 1.5 * strict.volume
    assert tolerant.volume / mesh.volume < 1.5


def temple_rig_and_masks():
    """templeSparseRing: the rig, the silhouettes the hull is carved from, the former
    threshold-only silhouettes (for comparison) and the carving grid.

    Silhouettes by :func:`elastocap.segment_dark_background`: grey > 30 after a 1-px blur
    proposes, the pixels above the view's Otsu level (eroded by 2 px) are sure temple, and
    GrabCut in Lab keeps what has the temple's colours. Parameters are the defaults but
    for the clean-up (opened by 1 px, parts under 500 px dropped), chosen on this data set:
    over threshold 20..48, band 15..30 and 5..10 iterations the worst view's IoU (rendered
    by pixel-centre coverage) stayed within 0.969..0.977. The threshold-only masks (grey >
    48, opened by 1 px, closed by 4 px, specks under 500 px dropped) kept a fold of the dark
    cloth touching the temple (view 2) and cut into the temple's shadowed undersides
    (views 12, 9 and 7 most), which then carved the hull seen from the other views.
    """
    rig = Rig.load(TEMPLE / "templeSR_par.txt")
    lo = np.array([-0.073568, 0.021728, -0.012445]) - 0.005
    hi = np.array([0.028855, 0.181892, 0.062736]) + 0.005
    corners = np.array(np.meshgrid(*zip(lo, hi), indexing="ij")).reshape(3, -1).T
    masks, thresholded = {}, {}
    for name, camera in zip(rig.names, rig.cameras):
        image = cv2.imread(str(TEMPLE / f"{name}.png"))[:, :, ::-1]
        # The black cloth around the temple shows through any threshold at the image
        # edges; the data set's bounding box (its README) says where the temple is.
        uv, _ = camera.project(corners)
        roi = np.zeros(image.shape[:2], np.uint8)
        cv2.fillConvexPoly(roi, cv2.convexHull(np.round(uv).astype(np.int32)), 1)
        roi = roi.astype(bool)
        masks[name] = elastocap.segment_dark_background(image, 30, region=roi, open_radius=1, min_area=500)
        threshold = elastocap.threshold_dark_background(image, 48, open_radius=1, close_radius=4, min_area=500)
        thresholded[name] = threshold & roi
    return rig, masks, thresholded, Grid.around(lo, hi, 250)


@pytest.mark.skipif(not TEMPLE.exists(), reason="shared data not present")
def test_temple_hull_reprojects_onto_its_silhouettes():
    rig, masks, thresholded, grid = temple_rig_and_masks()
    surface = visual_hull(masks, rig, grid, footprint="center").mesh()
    ious, threshold_ious = [], []
    for name, camera in zip(rig.names, rig.cameras):
        projected = render(surface, camera)
        ious.append((projected & masks[name]).sum() / (projected | masks[name]).sum())
        reference = thresholded[name]
        threshold_ious.append((projected & reference).sum() / (projected | reference).sum())
    # Shown with pytest -s. The second line compares the same hull with the threshold-only
    # masks, which still hold the cloth fold: for information, not asserted.
    print("temple reprojection IoU per view:", np.round(ious, 3))
    print("  same hull vs threshold-only masks:", np.round(threshold_ious, 3))
    # Measured 0.975 to 0.983 per view (threshold-only pipeline: 0.945 to 0.974). What is
    # left is mostly a rim of about one pixel where the rendered hull exceeds the mask:
    # this render fills every pixel a projected triangle's edge touches (pixel-centre
    # coverage gives 0.973 to 0.986), and voxels are 1.8 px wide in these views.
    assert min(ious) >= TEMPLE_IOU_MIN, np.round(ious, 3)


def test_bad_input_is_a_clear_error():
    mesh, rig = ellipsoid(), ring(4)
    masks = [render(mesh, c) for c in rig.cameras]
    with pytest.raises(elastocap.InvalidInputError, match="cam0"):
        visual_hull([m[:-1] for m in masks], rig, GRID)
    with pytest.raises(elastocap.InvalidInputError, match="3 masks for 4 cameras"):
        visual_hull(masks[:3], rig, GRID)
    with pytest.raises(elastocap.InvalidInputError, match="cam2"):
        visual_hull({n: m for n, m in zip(rig.names, masks) if n != "cam2"}, rig, GRID)
    with pytest.raises(elastocap.InvalidInputError, match="footprint"):
        visual_hull(masks, rig, GRID, footprint="exact")
    with pytest.raises(elastocap.InvalidInputError, match="tolerance"):
        visual_hull(masks, rig, GRID, tolerance=-1)
    behind = Grid([10.0, 0.0, 0.0], 0.1, (4, 4, 4))  # behind cam0, which sits at x = 3 looking at -x
    with pytest.raises(elastocap.InvalidInputError, match="behind"):
        visual_hull(masks, rig, behind)
    empty = visual_hull([np.zeros_like(m) for m in masks], rig, GRID)
    assert not empty.occupancy.any()
    with pytest.raises(elastocap.InvalidInputError, match="empty"):
        empty.mesh()


def test_the_hull_mesh_is_computed_once_and_handed_out_as_copies():
    mesh, rig = ellipsoid(), ring(4)
    hull = visual_hull([render(mesh, c) for c in rig.cameras], rig, GRID)
    first, second = hull.mesh(), hull.mesh()
    assert first is not second
    np.testing.assert_array_equal(first.vertices, second.vertices)
    first.vertices[:] = 0.0  # the caller's copy; the hull's mesh is unchanged
    assert np.abs(hull.mesh().vertices).max() > 0
    assert hull._mesh is hull._mesh
