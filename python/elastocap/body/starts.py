"""Starts of the body's pose search read from the data (issue 16): :func:`body_volume`,
:func:`data_starts`.

The global search's fixed starts (a few headings, a few arm and leg swings) leave poses
they do not reach: the capsule figure's seed 14 heading 39 degrees off, seed 13's left arm
17-19 cm off while the true pose scored better than the search's winner (masks alone,
``benches/README.md``, branch body9). The body's volume says more than that: its thickest
part is the trunk, whose cross-section is wider from shoulder to shoulder than from front
to back (the heading, up to a half turn), and the points of the volume farthest from the
trunk along the inside of the volume (geodesically) are the hands, the feet and the head
(the geodesic extrema of Plagemann et al., "Real-time identification and localization of
body parts from depth images", ICRA 2010). Each limb's path from its far point back to the
trunk passes through its wrist and elbow, ankle and knee at the model's segment lengths,
and the limb's angles are solved from them (inverse kinematics). Which far point is which
limb is tried both ways (left and right, front and back).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage, optimize, sparse
from scipy.sparse import csgraph

from elastocap._core import InvalidInputError
from elastocap.body.human import SKIN_FRACTION
from elastocap.body.model import SKIN_LEVEL, BodyModel, BodyState
from elastocap.cameras.camera import Camera
from elastocap.cameras.rig import Rig
from elastocap.hull.carve import visual_hull
from elastocap.hull.grid import Grid

__all__ = ["BodyVolume", "body_volume", "data_starts"]

#: Voxel edge of the volume (metres): limbs 8-12 cm thick stay several voxels wide.
VOXEL = 0.025
#: Half extent of the carved box about the data's centre (metres, x, y, z in the body's
#: z-up frame): a person with the arms raised, the centre near the pelvis.
HALF_BOX = (1.2, 1.2, 1.3)
#: The trunk is the volume farther than this share of the volume's largest depth from its
#: surface (the depth of a voxel: its distance to the nearest empty voxel).
CORE_DEPTH = 0.6
#: A far point must lie at least this far (metres, geodesically) from the trunk and from
#: every far point found before it: less is a shoulder or a hip.
MIN_REACH = 0.25
#: At most this many far points (two hands, two feet, the head, one spare).
MAX_FAR_POINTS = 6
#: A far point within this height (metres) of the volume's lowest voxel is a foot.
FOOT_HEIGHT = 0.4
#: A voxel holding stereo points counts when more than this many of its 26 neighbours hold
#: points too (the skin is a sheet; outliers in the air are alone).
MIN_NEIGHBOURS = 3

_ARM = ("upperarm", "forearm", "hand")
_LEG = ("thigh", "shin", "foot")


@dataclass(frozen=True)
class BodyVolume:
    """Where the body is: occupied voxels of a grid (body frame, z up).

    Attributes
    ----------
    occupancy : (nx, ny, nz) bool
    origin : (3,) float64
        Centre of voxel ``[0, 0, 0]``, metres.
    spacing : float
        Voxel edge, metres.
    """

    occupancy: NDArray[np.bool_]
    origin: NDArray[np.float64]
    spacing: float


def body_volume(
    centre: Any,
    *,
    points: Any = None,
    masks: Sequence[Any] | None = None,
    cameras: Sequence[Camera] | None = None,
    spacing: float = VOXEL,
) -> BodyVolume | None:
    """The body's volume about ``centre`` (metres, the body's z-up frame): the visual hull
    of ``masks`` seen by ``cameras`` when given (a camera whose mask is None carves
    nothing), else the voxels holding ``points`` (N, 3) among neighbours that do
    (:data:`MIN_NEIGHBOURS`), closed and filled (points lie on the skin only). Only the connected piece nearest
    ``centre`` is kept. None when nothing is left.

    Raises
    ------
    InvalidInputError
        ``masks`` without one camera per mask.
    """
    centre = np.asarray(centre, dtype=np.float64).reshape(3)
    half = np.asarray(HALF_BOX)
    shape = tuple(int(v) for v in np.ceil(2 * half / spacing).astype(int))
    origin = centre - half + spacing / 2
    if masks is not None and any(m is not None for m in masks):
        if cameras is None or len(cameras) != len(masks):
            raise InvalidInputError("body_volume: masks need one camera per mask")
        kept = [(m, c) for m, c in zip(masks, cameras) if m is not None]
        occupancy = np.asarray(visual_hull([m for m, _ in kept], Rig([c for _, c in kept]), Grid(origin, spacing, shape)).occupancy).copy()
    elif points is not None and len(points) > 0:
        cells = np.floor((np.asarray(points, dtype=np.float64).reshape(-1, 3) - (origin - spacing / 2)) / spacing).astype(np.int64)
        inside = ((cells >= 0) & (cells < shape)).all(axis=1)
        hit = np.zeros(shape, dtype=bool)
        hit[tuple(cells[inside].T)] = True
        # a voxel of the skin has hit neighbours; an outlier in the air has none
        neighbours = ndimage.convolve(hit.astype(np.int16), np.ones((3, 3, 3), dtype=np.int16), mode="constant")
        skin = hit & (neighbours > MIN_NEIGHBOURS)
        # The skin's voxels grown until the sheet has no gaps (3000 points on a person are
        # ~2.5 cm apart), the inside filled, then shrunk back. Closing before filling left
        # the trunk hollow: a gap its erosion reopens lets the filling leak out.
        cube = np.ones((3, 3, 3))
        grown = ndimage.binary_fill_holes(ndimage.binary_dilation(skin, structure=cube, iterations=2))
        occupancy = ndimage.binary_erosion(grown, structure=cube, iterations=2, border_value=1)
    else:
        return None
    labels, count = ndimage.label(occupancy, structure=np.ones((3, 3, 3)))
    if count == 0:
        return None
    # the piece nearest the centre: clutter and ghosts apart from the body are dropped
    where = np.argwhere(labels > 0)
    nearest = where[np.argmin(np.linalg.norm(where - (centre - origin) / spacing, axis=1))]
    return BodyVolume(labels == labels[tuple(nearest)], origin, float(spacing))


@dataclass(frozen=True)
class _Reading:
    """What the volume says: the trunk's centroid and left-right axis angle (radians, about
    z), the lowest height, and each far point's path to the trunk (far point first)."""

    centroid: NDArray[np.float64]
    axis_angle: float
    floor: float
    paths: list[NDArray[np.float64]]


def _read(volume: BodyVolume) -> _Reading | None:
    occupancy, h = volume.occupancy, volume.spacing
    if occupancy.sum() < 20:
        return None
    depth = ndimage.distance_transform_edt(np.pad(occupancy, 1), sampling=h)[1:-1, 1:-1, 1:-1]
    core = depth >= CORE_DEPTH * depth.max()
    labels, count = ndimage.label(core, structure=np.ones((3, 3, 3)))
    if count == 0:
        return None
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    core = labels == int(np.argmax(sizes))
    voxels = np.argwhere(occupancy)
    positions = volume.origin + h * voxels
    in_core = core[tuple(voxels.T)]
    trunk = positions[in_core]
    centroid = trunk.mean(axis=0)
    flat = trunk[:, :2] - centroid[:2]
    values, vectors = np.linalg.eigh(flat.T @ flat)
    major = vectors[:, int(np.argmax(values))]
    graph = _graph(occupancy, voxels, h)
    sources = np.flatnonzero(in_core)
    reach, predecessors, _ = csgraph.dijkstra(graph, directed=False, indices=sources, min_only=True, return_predecessors=True)
    remaining = reach.copy()
    paths = []
    for _ in range(MAX_FAR_POINTS):
        far = int(np.argmax(np.where(np.isfinite(remaining), remaining, -1.0)))
        if not np.isfinite(remaining[far]) or remaining[far] < MIN_REACH:
            break
        path = [far]
        while predecessors[path[-1]] >= 0:
            path.append(int(predecessors[path[-1]]))
        paths.append(positions[path])
        remaining = np.minimum(remaining, csgraph.dijkstra(graph, directed=False, indices=far))
    return _Reading(centroid, float(np.arctan2(major[1], major[0])), float(positions[:, 2].min()), paths)


def _graph(occupancy: NDArray[np.bool_], voxels: NDArray[np.int64], h: float) -> sparse.csr_matrix:
    """The 26-neighbour graph of the occupied voxels, edges weighted by their length."""
    index = np.full(np.asarray(occupancy.shape) + 2, -1, dtype=np.int64)
    index[tuple((voxels + 1).T)] = np.arange(len(voxels))
    rows, cols, weights = [], [], []
    for offset in np.argwhere(np.ones((3, 3, 3))) - 1:
        # half the neighbourhood: the graph is undirected
        if tuple(offset) <= (0, 0, 0):
            continue
        other = index[tuple((voxels + 1 + offset).T)]
        ok = other >= 0
        rows.append(np.flatnonzero(ok))
        cols.append(other[ok])
        weights.append(np.full(int(ok.sum()), h * float(np.linalg.norm(offset))))
    n = len(voxels)
    return sparse.csr_matrix((np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


@lru_cache(maxsize=4)
def _model_reading(model: BodyModel, spacing: float) -> tuple[NDArray[np.float64], float, dict[str, float]]:
    """The model's own trunk at rest (heading 0, root at the origin), read as the data are:
    its centroid, its left-right axis angle, and the reach of each hand and foot (metres
    from the part's origin to its farthest skin, along the path a far point ends)."""
    state = model.rest_state()
    lower, upper = model.bounds(state)
    counts = np.ceil((upper - lower) / spacing).astype(int) + 1
    axes = [lower[a] + spacing * np.arange(counts[a]) for a in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    values, _, _ = model.field(grid, state)
    reading = _read(BodyVolume(values.reshape(counts) >= SKIN_LEVEL, lower, spacing))
    if reading is None:
        raise InvalidInputError("the body model's rest volume is empty at this voxel size")
    description = {p["name"]: p for p in model.to_dict()["parts"]}
    reach = {}
    for name in ("l_hand", "r_hand", "l_foot", "r_foot"):
        balls = description[name]["balls"]
        reach[name] = max(float(np.linalg.norm(b["center"])) + SKIN_FRACTION * max(b["radii"]) for b in balls)
    return reading.centroid, reading.axis_angle, reach


def _limb_names(model: BodyModel, side: str, chain: tuple[str, str, str]) -> list[str] | None:
    names = [f"{side}_{chain[0]}.{k}" for k in range(3)] + [f"{side}_{chain[1]}.0"]
    parts = [f"{side}_{p}" for p in chain]
    if all(n in model.motion_names for n in names) and all(p in model.part_names for p in parts):
        return names
    return None


def _solve_limb(model: BodyModel, state: BodyState, side: str, chain: tuple[str, str, str], targets: NDArray[np.float64]) -> BodyState:
    """``state`` with one limb's four angles (three at its root joint, one at its middle
    joint) set so that its middle and end joints (the elbow and wrist, or the knee and
    ankle: the origins of ``chain[1]`` and ``chain[2]``) come nearest ``targets`` (2, 3),
    within the joint limits; a light pull towards the starting angles picks the twist the
    two points leave free."""
    names = _limb_names(model, side, chain)
    assert names is not None
    columns = [model.motion_names.index(n) for n in names]
    parts = [model.part_names.index(f"{side}_{chain[1]}"), model.part_names.index(f"{side}_{chain[2]}")]
    lower, upper = model.lower[columns], model.upper[columns]
    start = np.clip(state.motion[columns], lower, upper)

    def residual(angles: NDArray[np.float64]) -> NDArray[np.float64]:
        motion = state.motion.copy()
        motion[columns] = angles
        _, origins = model.pose(state.replace(motion=motion))
        return np.concatenate([(origins[parts] - targets).ravel(), 0.02 * (angles - start)])

    # from the rest angles and from the middle joint half bent (a two-bone chain has two
    # solutions for a reachable end; the limits keep one, the start decides between near
    # ties)
    found = []
    for bend in (0.0, 0.5):
        x0 = start.copy()
        x0[3] = np.clip((1 - bend) * x0[3] + bend * (lower[3] if abs(lower[3]) > abs(upper[3]) else upper[3]), lower[3], upper[3])
        found.append(optimize.least_squares(residual, x0, bounds=(lower, upper + 1e-12), max_nfev=60, x_scale=1.0))
    motion = state.motion.copy()
    motion[columns] = min(found, key=lambda f: float(f.cost)).x
    return state.replace(motion=motion)


def _targets(path: NDArray[np.float64], reach: float, segment: float) -> NDArray[np.float64]:
    """The end joint and the middle joint on a far point's path (far point first): at arc
    lengths ``reach`` and ``reach + segment`` from the far point (the path's last point when
    it is shorter)."""
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    out = []
    for length in (reach + segment, reach):
        out.append([np.interp(min(length, arc[-1]), arc, path[:, a]) for a in range(3)])
    return np.asarray(out)


def data_starts(model: BodyModel, shape: Any, volume: BodyVolume | None) -> list[BodyState]:
    """Starts of the pose search read from the body's ``volume`` (:func:`body_volume`).

    The trunk (the deepest part of the volume) gives the root's place and the heading up to
    a half turn (its cross-section's long axis runs from shoulder to shoulder); the far
    points the hands and feet: the first two near the floor are feet (:data:`FOOT_HEIGHT`),
    the highest one left above the trunk near its axis is the head, those whose paths
    reach the trunk from above its centroid are hands.
    For both headings, the hands and the feet each assigned left and right by their side of
    the trunk and swapped: 8 starts, the limbs' angles solved from the joints on their
    paths, the trunk upright. Empty when the volume says nothing (no volume, no trunk, a
    model without the default human's limbs).

    Parameters
    ----------
    model : BodyModel
    shape : (4 P,) array_like
        The shape the starts carry (the search's held shape).
    volume : BodyVolume or None
    """
    if volume is None or any(_limb_names(model, s, c) is None for s in "lr" for c in (_ARM, _LEG)):
        return []
    shape = model.as_shape(shape)
    reading = _read(volume)
    if reading is None:
        return []
    model_centroid, model_axis, reach = _model_reading(model, volume.spacing)
    lengths = _segment_lengths(model, shape)
    paths = reading.paths
    # in the far points' order (the farthest first): a foot's heel, found after its toe,
    # is left over
    feet = [p for p in paths if p[0, 2] < reading.floor + FOOT_HEIGHT][:2]
    rest = [p for p in paths if not any(p is f for f in feet)]
    heads = [p for p in rest if p[0, 2] > reading.centroid[2] + MIN_REACH and np.linalg.norm(p[0, :2] - reading.centroid[:2]) < 0.2]
    head = max(heads, key=lambda p: p[0, 2]) if heads else None
    # A hand's path reaches the trunk from above its centroid (at the shoulder); a far
    # point left on a leg (a bent knee, a heel) reaches it from below, at the hips. A hand
    # hanging against the hip is no far point at all: its arm stays at rest.
    hands = [p for p in rest if p is not head and p[-1, 2] > reading.centroid[2]][:2]
    starts = []
    for heading in (reading.axis_angle - model_axis, reading.axis_angle - model_axis + np.pi):
        turn = np.array([[np.cos(heading), -np.sin(heading), 0.0], [np.sin(heading), np.cos(heading), 0.0], [0.0, 0.0, 1.0]])
        base = model.rest_state(position=reading.centroid - turn @ model_centroid).replace(shape=shape)
        motion = base.motion.copy()
        motion[3] = _wrap(heading)
        base = base.replace(motion=motion)
        left = turn[:, 0]
        solved: dict[tuple[str, str, int], BodyState] = {}

        def limb(state: BodyState, side: str, chain: tuple[str, str, str], which: int, found: list[NDArray[np.float64]]) -> BodyState:
            key = (side, chain[0], which)
            if key not in solved:
                end = f"{side}_{chain[2]}"
                targets = _targets(found[which], reach[end], lengths[f"{side}_{chain[1]}"])
                solved[key] = _solve_limb(model, base, side, chain, targets)
            columns = [model.motion_names.index(n) for n in _limb_names(model, side, chain) or []]
            motion = state.motion.copy()
            motion[columns] = solved[key].motion[columns]
            return state.replace(motion=motion)

        for arms_swapped in (False, True):
            for legs_swapped in (False, True):
                state = base
                for chain, found, swapped in ((_ARM, hands, arms_swapped), (_LEG, feet, legs_swapped)):
                    sides = _sides(found, reading.centroid, left)
                    for which, side in enumerate(sides):
                        state = limb(state, {"l": "r", "r": "l"}[side] if swapped else side, chain, which, found)
                starts.append(state)
    return starts


def _sides(found: list[NDArray[np.float64]], centroid: NDArray[np.float64], left: NDArray[np.float64]) -> list[str]:
    """Left or right for each of one or two limbs' paths, by the mean side of the trunk
    their points lie on (two: the one further left is the left)."""
    offsets = [float(np.mean((p - centroid) @ left)) for p in found]
    if len(offsets) == 2:
        return ["l", "r"] if offsets[0] >= offsets[1] else ["r", "l"]
    return ["l" if o >= 0 else "r" for o in offsets]


def _segment_lengths(model: BodyModel, shape: NDArray[np.float64]) -> dict[str, float]:
    """Length (metres) of each forearm and shin under ``shape``: its child's offset."""
    description = {p["name"]: p for p in model.to_dict()["parts"]}
    table = model.shape_table(shape)
    out = {}
    for side in "lr":
        for middle, end in (("forearm", "hand"), ("shin", "foot")):
            out[f"{side}_{middle}"] = float(np.linalg.norm(description[f"{side}_{end}"]["offset"])) * table[f"{side}_{middle}"]["length"]
    return out


def _wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)
