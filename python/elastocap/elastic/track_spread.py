"""The tracks' correction carried along the surface to the nodes around them (issue 15;
``TrackTerms(spread=)``).

The track term (``rust/fit/tracks.rs``) pins the material point of each track, and the
elastic term carries that pin only a node or two: between the tracks the surface slides
(along the surface the hull's distance term costs nothing), and on the textured fast
capture most of the drift is on surface that no track is near (benches/README.md,
trackfit2: 22-47% of the drifted points have a track within 2% of the diagonal).

Here each pulling track's correction, its tracked position minus where the frame's start
puts its material point, is carried to the surface nodes around it, and each such node is
pulled to its start moved by it. What a track is trusted with is limited three ways, each
against a way the plain median spread (trackfit2, reverted) went wrong:

- **Along the track's own surface**: the reach is a geodesic distance on the model's
  surface graph (edge lengths at the start), not a Euclidean radius, so a track on an arm
  does not move the torso beside it.
- **Young tracks**: the tracker's 3-D error grows with a track's age (track7), so a track
  ``a`` frames from its anchor is trusted ``exp(-a / age)``.
- **Its covariance**: ``sigma^2 tr(P) / 3`` with the track term's precision ``P = (Sigma +
  sigma^2 I)^-1`` (1 for a track known to better than ``sigma``).
- **Not a track gone astray**: a track's spread is weighed by Tukey's biweight ``(1 -
  |d|^2 / (G R)^2)^2`` of its correction ``d`` against ``G`` reaches ``R`` (none past
  them): the pairs' metrics are a share of a track's, so their own Cauchy loss hardly
  damps a track 1 m off (a sphere's test: such a track moved the surface 5 cm through the
  spread, under 2 cm through the track term alone). Damping moderate corrections, as the
  track term's own Cauchy weight of ``d`` does (half at 10 sigma_0, a quarter of the
  reach), also damped the fast limbs' good tracks: frames lost on the tuning seed 0 -> 2
  (benches/README.md, trackfit3).
- **Optionally, by how it was attached** (``trust``, a factor per track;
  ``TrackTerms(spread_relayed=)``, off): a track attached by the relay alone on a fast
  limb's drifted fit has a wrong material point, and its spread drags every node around it
  the same wrong way (seed 14's right hand, benches/README.md, trackfit9); on the trunk the
  same tracks' spread holds the surface (seed 19), so it stays on by default
  (``spread_relayed_dense`` keeps it for relayed tracks among many older ones).
- **Across the surface only**: a node is pulled along the surface (metric ``I - n n^T``,
  ``n`` its normal at the start); the hull says where the surface is, the tracks say which
  part of it is where.

Every (track, node) pair within reach is one pull under the track term's Cauchy loss (a
robust weighted mean of the tracks' corrections at the node), the node's pulls scaled
together to at most ``share`` of one track's weight.
"""

from __future__ import annotations

import numpy as np
import trimesh
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from elastocap._core import InvalidInputError
from elastocap.elastic.tracks import TrackAttachments

__all__ = ["frame_spread", "spread_pulls", "surface_geodesics"]

# A track whose correction is this many reaches or more does not spread (Tukey's biweight of
# the correction's length).
GUARD = 2.0

TrackArrays = tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]


def surface_geodesics(positions: NDArray[np.float64], surface_nodes: NDArray[np.int64], surface_faces: NDArray[np.int64],
                      sources: NDArray[np.int64], radius: float) -> NDArray[np.float64]:
    """(len(sources), S) shortest distances along the surface graph (the edges of
    ``surface_faces``, lengths at ``positions``) from surface vertices ``sources`` (indices
    into ``surface_nodes``) to every surface vertex; inf beyond ``radius``."""
    local = np.full(len(positions), -1, np.int64)
    local[surface_nodes] = np.arange(len(surface_nodes))
    faces = local[surface_faces]
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    x = positions[surface_nodes]
    length = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)
    s = len(surface_nodes)
    # Duplicate edges (each inner edge is in two faces) sum in a COO -> CSR conversion:
    # take each edge once, in both directions.
    ordered = np.sort(edges, axis=1)
    key = np.unique(ordered[:, 0] * s + ordered[:, 1], return_index=True)[1]
    edges, length = edges[key], length[key]
    graph = coo_matrix((np.concatenate([length, length]),
                        (np.concatenate([edges[:, 0], edges[:, 1]]), np.concatenate([edges[:, 1], edges[:, 0]]))),
                       shape=(s, s)).tocsr()
    return dijkstra(graph, directed=False, indices=sources, limit=radius)


def spread_pulls(arrays: TrackArrays, ages: NDArray[np.float64], start: NDArray[np.float64],
                 surface_nodes: NDArray[np.int64], surface_faces: NDArray[np.int64], *, share: float, age: float,
                 radius: float, sigma: float, trust: NDArray[np.float64] | None = None) -> TrackArrays:
    """The track term's arrays of a frame (:meth:`TrackAttachments.frame_arrays`) with the
    tracks' corrections spread over the surface (module docs) appended as one-node rows.

    Parameters
    ----------
    arrays : (nodes (T, k), phi (T, k), targets (T, 3), precisions (T, 3, 3))
        The frame's pulling tracks.
    ages : (T,) float
        Frames between each track's anchor and this frame.
    start : (N, 3) float
        The frame's start positions.
    surface_nodes, surface_faces
        The model's surface (:class:`ElasticModel`).
    share : float
        The most a node is pulled, relative to one track of full trust (> 0).
    age : float
        Frames over which a track's trust falls by e (> 0).
    radius : float
        Geodesic reach of a track, world units (> 0).
    sigma : float
        The track term's sigma_0, world units.
    trust : (T,) float, optional
        A factor on each track's trust in the spread (default 1; 0: the track pulls its
        own material point but does not spread).
    """
    for name, value in (("share", share), ("age", age), ("radius", radius), ("sigma", sigma)):
        if not (np.isfinite(value) and value > 0):
            raise InvalidInputError(f"track spread: {name} must be a finite positive number, got {value}")
    nodes, phi, targets, precisions = arrays
    if len(targets) == 0:
        return arrays
    if len(ages) != len(targets):
        raise InvalidInputError(f"track spread: {len(ages)} ages for {len(targets)} tracks")
    placed = np.einsum("tk,tkd->td", phi, start[nodes])
    correction = targets - placed
    trust_factor = np.ones(len(targets)) if trust is None else np.asarray(trust, np.float64)
    if trust_factor.shape != (len(targets),) or not (np.isfinite(trust_factor).all() and (trust_factor >= 0).all()):
        raise InvalidInputError(f"track spread: trust must be {len(targets)} finite numbers >= 0")
    trust = trust_factor * np.exp(-np.asarray(ages, np.float64) / age) * sigma**2 * np.einsum("tii->t", precisions) / 3
    trust *= np.clip(1 - np.einsum("ti,ti->t", correction, correction) / (GUARD * radius) ** 2, 0, None) ** 2
    # A track's source on the surface graph: the surface node among its own MLS nodes
    # nearest its material point (the globally nearest one may be on a limb touching it).
    local = np.full(len(start), -1, np.int64)
    local[surface_nodes] = np.arange(len(surface_nodes))
    candidates = local[nodes]
    gap = np.where(candidates >= 0, np.linalg.norm(start[nodes] - placed[:, None, :], axis=2), np.inf)
    best = gap.argmin(axis=1)
    source = candidates[np.arange(len(nodes)), best]
    none = source < 0
    if none.any():
        source[none] = cKDTree(start[surface_nodes]).query(placed[none])[1]
    distance = surface_geodesics(start, surface_nodes, surface_faces, source, radius)
    track, vertex = np.nonzero(np.isfinite(distance))
    kernel = (1 - (distance[track, vertex] / radius) ** 2) ** 2
    weight = trust[track] * kernel
    # Each node's pulls together at most `share` of one fully trusted track.
    total = np.bincount(vertex, weights=weight, minlength=len(surface_nodes))
    weight = share * weight / np.maximum(total[vertex], 1.0)
    keep = weight > 1e-6 * share
    track, vertex, weight = track[keep], vertex[keep], weight[keep]
    if len(track) == 0:
        return arrays
    normals = np.asarray(trimesh.Trimesh(start[surface_nodes], local[surface_faces], process=False).vertex_normals)
    n = normals[vertex]
    along = np.eye(3)[None] - n[:, :, None] * n[:, None, :]
    which = surface_nodes[vertex]
    k = nodes.shape[1]
    extra_nodes = np.zeros((len(which), k), np.int64)
    extra_nodes[:, 0] = which
    extra_phi = np.zeros((len(which), k))
    extra_phi[:, 0] = 1.0
    return (
        np.ascontiguousarray(np.concatenate([nodes, extra_nodes])),
        np.ascontiguousarray(np.concatenate([phi, extra_phi])),
        np.ascontiguousarray(np.concatenate([targets, start[which] + correction[track]])),
        np.ascontiguousarray(np.concatenate([precisions, weight[:, None, None] / sigma**2 * along])),
    )


def frame_spread(attachments: TrackAttachments, frame: int, arrays: TrackArrays | None, start: NDArray[np.float64],
                 surface_nodes: NDArray[np.int64], surface_faces: NDArray[np.int64]) -> TrackArrays | None:
    """:func:`spread_pulls` of ``frame``'s track arrays (``attachments.frame_arrays``) from
    its ``start`` (N, 3), as ``attachments.terms`` say: ``spread`` (0: the arrays as they
    are), ``spread_age``, ``spread_radius``, and ``spread_relayed`` on the tracks attached by
    the relay alone (those with fewer than ``spread_relayed_dense`` older tracks near them
    at their anchor frame, when it is set)."""
    terms, lengths = attachments.terms, attachments.lengths
    if arrays is None or terms.spread <= 0:
        return arrays
    trust = None
    if terms.spread_relayed != 1.0:
        dense = terms.spread_relayed_dense
        relayed = attachments.frame_relayed(frame) & ((dense == 0) | (attachments.frame_older_near(frame) < dense))
        trust = np.where(relayed, terms.spread_relayed, 1.0)
    return spread_pulls(arrays, attachments.frame_ages(frame), start, surface_nodes, surface_faces, share=terms.spread,
                        age=terms.spread_age, radius=lengths.spread_radius, sigma=lengths.sigma, trust=trust)
