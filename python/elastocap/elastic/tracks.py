"""Tracks in the elastic fit (SPEC 5.1; issue 15, item 4): tracked 3-D surface points
attached to the model as material points and pulled, frame by frame, to their tracked
positions (the term itself is ``rust/fit/tracks.rs``).

A track is anchored at its frame nearest the rest frame (the rest frame itself when it is
tracked there). When that frame is fitted, the tracked point is attached to the model: its
MLS shape-function weights over the ``k`` nodes nearest to it in that frame's fitted
positions (SPEC 4.2's linear basis and cubic-spline weights), computed once. In a frame
fitted later where the track has a position, the material point ``sum_i phi_i x_i`` is
pulled to it. Fitting runs outward from the rest frame, so the anchor of a track is fitted
before its other frames, except for a track anchored before the rest frame that also has
positions after it with none in between: it is not used in those later frames (they are
fitted before its anchor).

A track seeded after the rest frame is anchored at a frame whose fit has already drifted
along the surface; attached where that fit puts it, it would hold the drift instead of
undoing it. With ``relay`` (:class:`~elastocap.elastic.track_terms.TrackTerms`; on by
default), the older tracks tracked at that frame say how far the fit is off there: each
one's material point sits at ``sum phi x`` in the fit but was tracked at ``X``, so the fit
is off by ``X - sum phi x`` around it. A new track is attached at its tracked position
moved back by the median of that offset over its nearest older tracks (within a radius),
that is at the material point the older tracks place there, not the one the drifted fit
places there.

With ``ahead`` (``TrackTerms(ahead=)``, on by default) a late track is
attached before its anchor frame is fitted, from the tracks alone: the older tracks tracked
at that frame near it (their material points known at the rest frame) give the local rigid
motion from that frame back to the rest frame (a least-squares rotation and translation,
Kabsch), which carries the new track's tracked position to its material point at rest.
Neither the drifted fit of the anchor frame nor its relay offsets enter, and the track
pulls its anchor frame too. Where its older neighbours are too few, too close to a line,
or not moving rigidly (a joint between them), the track is attached after the fit as
above.

Options of the carry and the relay (:class:`~elastocap.elastic.track_terms.TrackTerms`'
``ahead_check``, ``relay_memory``, ``ahead_memory``, ``ahead_chain``, ``ahead_age``,
``relayed_weight``; the check and the relay's memory on by default, the others off;
benches/README.md, trackfit8):

- **The check against the relay**: a carry whose material point lies far from the relay's
  (measured on the frame's start, before the fit) is dropped. On the textured capture the
  carries more than 4 node spacings from the relay's point are 20% of the diagonal off (a
  neighbourhood whose rigid motion passes the residual test but carries the track
  elsewhere); up to that the carry is the better of the two.
- **Memory**: tracks lost in the last frames relay (and optionally carry) with the offset
  from the fit they had when last tracked: a fast limb's tracks end together and are
  re-seeded together, so no track tracked in the new tracks' frame is older than they are.
- **Chains**: tracks just carried carry the others of their frame (worse on the textured
  capture: the hops extrapolate the rigid motion).
- **Age**: a carried track ages in the spread from its carriers' anchors.
- **Relayed weight**: the tracks only the relay placed weigh less.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from elastocap._core import InvalidInputError
from elastocap.elastic.track_terms import TrackLengths, TrackTerms
from elastocap.elastic.track_weights import material_weights, placeable_weights, rigid_carry
from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.tracks import Tracks

__all__ = ["TrackAttachments", "check_tracks", "material_weights", "placeable_weights", "rigid_carry", "select_frames"]

def check_tracks(tracks: Tracks | None, frames: Sequence[int]) -> Tracks | None:
    """``tracks`` checked against the targets' ``frames``: None for no tracks (None, no
    track or no frame), else the tracks.

    Raises
    ------
    InvalidInputError
        Not a :class:`Tracks`; a tracked position or covariance that is not finite, or a
        covariance that is not symmetric positive definite; frames of the tracks that are
        not frames of the targets.
    """
    if tracks is None:
        return None
    if not isinstance(tracks, Tracks):
        raise InvalidInputError(f"tracks must be elastocap.Tracks (elastocap.load_tracks), got {type(tracks).__name__}")
    if len(tracks.ids) == 0 or len(tracks.frames) == 0:
        return None
    tracked = tracks.flags == TrackFlag.TRACKED
    # Tracks' constructor checks this too, but a Tracks can be changed in place (its arrays
    # are not read-only).
    if not np.isfinite(tracks.positions[tracked]).all():
        f, n = np.argwhere(tracked & ~np.isfinite(tracks.positions).all(axis=2))[0]
        raise InvalidInputError(f"tracks: position of track {tracks.ids[n]} at frame {tracks.frames[f]} is not finite though flagged TRACKED")
    covariances = tracks.covariances[tracked]
    good = np.isfinite(covariances).all(axis=(1, 2))
    if good.all():
        symmetric = np.allclose(covariances, covariances.transpose(0, 2, 1), rtol=1e-6, atol=1e-12)
        good = np.linalg.eigvalsh(0.5 * (covariances + covariances.transpose(0, 2, 1))).min(axis=1) > 0
        good &= symmetric
    if not good.all():
        f, n = np.argwhere(tracked)[np.flatnonzero(~good)[0]]
        raise InvalidInputError(
            f"tracks: covariance of track {tracks.ids[n]} at frame {tracks.frames[f]} is not finite, symmetric and positive definite"
        )
    missing = sorted(set(int(v) for v in tracks.frames) - set(int(v) for v in frames))
    if missing:
        raise InvalidInputError(
            f"tracks hold frames {missing[:5]}{'...' if len(missing) > 5 else ''} that are not frames of the targets "
            f"({min(frames)}..{max(frames)}); select the tracks of the fitted frames"
        )
    return tracks


@dataclass
class TrackAttachments:
    """The tracks of a fit and the material points they are attached to.

    ``anchor[n]`` is the index (into ``tracks.frames``) of track n's frame nearest the rest
    frame (-1 without any position); ``neighbours`` / ``phi`` hold its attachment once that
    frame is fitted (``attached[n]``); ``unplaced[n]``: its anchor frame was fitted but no
    material point could be placed there (never attached); ``early[n]``: attached ahead of
    its anchor frame's fit (module docs), so it pulls that frame too.
    """

    tracks: Tracks
    k: int
    terms: TrackTerms
    lengths: TrackLengths
    rest_frame: int = 0
    rest_positions: NDArray[np.float64] | None = None
    early: NDArray[np.bool_] = field(init=False)
    older_near: NDArray[np.int64] = field(init=False)
    last_offset: NDArray[np.float64] = field(init=False)
    last_frame: NDArray[np.int64] = field(init=False)
    origin: NDArray[np.float64] = field(init=False)
    anchor: NDArray[np.int64] = field(init=False)
    neighbours: NDArray[np.int64] = field(init=False)
    phi: NDArray[np.float64] = field(init=False)
    attached: NDArray[np.bool_] = field(init=False)
    unplaced: NDArray[np.bool_] = field(init=False)

    @classmethod
    def build(cls, tracks: Tracks, rest_frame: int, k: int, terms: TrackTerms, node_spacing: float) -> TrackAttachments:
        """Anchors of ``tracks`` about ``rest_frame``; ``k`` nodes per material point;
        ``terms`` say how late tracks are attached (``relay``, ``ahead`` and their options;
        module docs), their lengths left at None taken at ``node_spacing`` (the model's
        mean node spacing, world units; :meth:`TrackTerms.lengths`)."""
        self = cls(tracks, k, terms, terms.lengths(node_spacing), rest_frame)
        tracked = tracks.flags == TrackFlag.TRACKED
        # Nearest the rest frame; on a tie, after it (the forward run is fitted first).
        gap = np.abs(tracks.frames - rest_frame) * 2 + (tracks.frames < rest_frame)
        cost = np.where(tracked, gap[:, None], np.iinfo(np.int64).max)
        self.anchor = np.where(tracked.any(axis=0), cost.argmin(axis=0), -1)
        n = len(tracks.ids)
        self.neighbours = np.zeros((n, k), np.int64)
        self.phi = np.zeros((n, k))
        self.attached = np.zeros(n, bool)
        self.unplaced = np.zeros(n, bool)
        self.early = np.zeros(n, bool)
        # Each attached track's last tracked frame and how far the fit was off at its
        # material point there (tracked position minus fitted one): ``relay_memory``.
        self.last_offset = np.zeros((n, 3))
        self.last_frame = np.full(n, np.iinfo(np.int64).min // 2, np.int64)
        # The frame a track's trust in the spread is aged from: its anchor frame, for a
        # track attached ahead (with ``ahead_age``) the mean of its carriers' (module docs).
        self.origin = np.where(self.anchor >= 0, tracks.frames[np.maximum(self.anchor, 0)], rest_frame).astype(np.float64)
        # How many older attached tracks were tracked within ``relay_radius`` of each track
        # at its anchor frame when it was attached there (:meth:`count_older`).
        self.older_near = np.zeros(n, np.int64)
        return self

    def _row(self, frame: int) -> int | None:
        rows = np.flatnonzero(self.tracks.frames == frame)
        return int(rows[0]) if len(rows) else None

    def attach(self, frame: int, positions: NDArray[np.float64]) -> int:
        """Attach the tracks anchored at ``frame`` to the model at its fitted ``positions``
        (N, 3); returns how many (not counting those attached ahead)."""
        if frame == self.rest_frame:
            self.rest_positions = np.array(positions, dtype=np.float64)
        row = self._row(frame)
        if row is None:
            return 0
        which = np.flatnonzero((self.anchor == row) & ~self.attached)
        if len(which):
            points = self.tracks.positions[row, which] - self._offsets(row, which, positions)
            # A point whose nearest nodes do not span space (a track far off the model, its
            # nodes all on one side; held-out seed 5 at 5 px, benches/README.md, trackfit4)
            # has no material point: it stays unattached instead of failing the fit.
            neighbours, phi, placed = placeable_weights(points, positions, self.k)
            self.unplaced[which[~placed]] = True
            which = which[placed]
            self.neighbours[which], self.phi[which] = neighbours[placed], phi[placed]
            self.attached[which] = True
        if self.terms.relay_memory > 0:
            seen = np.flatnonzero(self.attached & (self.tracks.flags[row] == TrackFlag.TRACKED))
            fitted = np.einsum("tk,tkd->td", self.phi[seen], positions[self.neighbours[seen]])
            self.last_offset[seen] = self.tracks.positions[row, seen] - fitted
            self.last_frame[seen] = frame
        return len(which)

    def attach_ahead(self, frame: int, start: NDArray[np.float64] | None = None) -> int:
        """Attach the tracks anchored at ``frame`` through the rigid motion of their older
        neighbours back to the rest frame (module docs), before ``frame`` is fitted (the
        rest frame must be attached); returns how many. Those it cannot place are left to
        :meth:`attach` after the fit.

        With ``ahead_check`` and the frame's ``start`` (N, 3), a carry is dropped (left to
        the relay after the fit) where it lands farther than ``ahead_check`` (world units,
        at rest) from the material point the relay's offsets, measured on ``start``, give
        the track. With ``ahead_chain``, up to that many more passes follow in which the
        tracks just attached ahead at this frame carry the others too (a limb whose tracks
        all start here is carried from its older end)."""
        row = self._row(frame)
        if self.terms.ahead <= 0 or row is None or self.rest_positions is None or frame == self.rest_frame:
            return 0
        tracked = self.tracks.flags[row] == TrackFlag.TRACKED
        m = max(self.terms.ahead, 3)
        total = 0
        for _ in range(1 + max(self.terms.ahead_chain, 0)):
            which = np.flatnonzero((self.anchor == row) & ~self.attached & ~self.unplaced)
            # Carriers: the older tracks attached, and (from the second pass) this frame's
            # tracks attached ahead in the passes before.
            old = np.flatnonzero(self.attached & tracked & ((self.anchor != row) | self.early))
            moved = self.tracks.positions[row, old]
            if self.terms.ahead_memory and start is not None:
                # Tracks lost in the last frames carry too, where the start and their last
                # offset from the fit put them (``relay_memory``).
                lost = self._lost(row)
                old = np.concatenate([old, lost])
                moved = np.concatenate([moved, np.einsum("tk,tkd->td", self.phi[lost], start[self.neighbours[lost]])
                                        + self.last_offset[lost]])
            if len(which) == 0 or len(old) < m:
                break
            rest = np.einsum("tk,tkd->td", self.phi[old], self.rest_positions[self.neighbours[old]])
            new = self.tracks.positions[row, which]
            rest_new, good, carriers = rigid_carry(moved, rest, new, m, self.lengths.relay_radius, self.lengths.ahead_tolerance,
                                                   neighbours=True)
            if self.lengths.ahead_check > 0 and start is not None:
                relayed, known = self._relay_rest(row, which, start)
                good &= ~known | (np.linalg.norm(rest_new - relayed, axis=1) <= self.lengths.ahead_check)
            which, rest_new, carriers = which[good], rest_new[good], carriers[good]
            if len(which) == 0:
                break
            neighbours, phi, placed = placeable_weights(rest_new, self.rest_positions, self.k)
            which, carriers = which[placed], carriers[placed]
            self.neighbours[which], self.phi[which] = neighbours[placed], phi[placed]
            self.attached[which] = True
            self.early[which] = True
            if self.terms.ahead_age:
                # A carried track is as far from the rest frame's evidence as its carriers.
                self.origin[which] = self.origin[old[carriers]].mean(axis=1)
            total += len(which)
        return total

    def _relay_rest(self, row: int, which: NDArray[np.int64],
                    positions: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """(len(which), 3) the material points at rest that the relay gives the tracks
        ``which`` on the fit ``positions`` of frame ``row``, and which it gives one (enough
        older tracks near, nodes spanning space) (len(which),) bool."""
        offsets, near = self._offsets(row, which, positions, with_near=True)
        neighbours, phi, placed = placeable_weights(self.tracks.positions[row, which] - offsets, positions, self.k)
        assert self.rest_positions is not None
        return np.einsum("tk,tkd->td", phi, self.rest_positions[neighbours]), near & placed

    def _lost(self, row: int) -> NDArray[np.int64]:
        """The attached tracks not tracked at ``row`` whose last tracked frame lies at most
        ``relay_memory`` frames before it, on the rest frame's side."""
        frame = int(self.tracks.frames[row])
        gap = (frame - self.last_frame) * np.sign(frame - self.rest_frame)
        here = self.tracks.flags[row] == TrackFlag.TRACKED
        return np.flatnonzero(self.attached & ~here & (gap > 0) & (gap <= self.terms.relay_memory))

    def _offsets(self, row: int, which: NDArray[np.int64], positions: NDArray[np.float64], with_near: bool = False) -> Any:
        """(len(which), 3): how far the fit ``positions`` of frame ``row`` is off around
        the new tracks ``which``, from the older tracks tracked there (module docs); 0
        where fewer than ``relay`` lie within ``relay_radius`` (with ``with_near``, also
        which do, (len(which),) bool)."""
        offsets = np.zeros((len(which), 3))
        near = np.zeros(len(which), bool)
        here = self.tracks.flags[row] == TrackFlag.TRACKED
        old = np.flatnonzero(self.attached & here & (self.anchor != row))
        placed = np.einsum("tk,tkd->td", self.phi[old], positions[self.neighbours[old]])
        tracked = self.tracks.positions[row, old]
        if self.terms.relay_memory > 0:
            # Tracks lost in the last ``relay_memory`` frames (on the rest frame's side of
            # this one) relay too, with the offset they last had, placed where it puts their
            # material point now: on a fast limb whose tracks all ended and were re-seeded
            # here, no track tracked here is older than this frame.
            lost = self._lost(row)
            fitted = np.einsum("tk,tkd->td", self.phi[lost], positions[self.neighbours[lost]])
            placed = np.concatenate([placed, fitted])
            tracked = np.concatenate([tracked, fitted + self.last_offset[lost]])
        if self.terms.relay <= 0 or len(tracked) < self.terms.relay:
            return (offsets, near) if with_near else offsets
        distance, nearest = cKDTree(tracked).query(self.tracks.positions[row, which], k=self.terms.relay)
        # k = 1 gives 1-D answers.
        distance, nearest = distance.reshape(len(which), self.terms.relay), nearest.reshape(len(which), self.terms.relay)
        near = (distance <= self.lengths.relay_radius).all(axis=1)
        # The median, not the mean: a track the tracker's filters kept on a wrong match
        # must not move its neighbours' anchors.
        offsets[near] = np.median((tracked - placed)[nearest[near]], axis=1)
        return (offsets, near) if with_near else offsets

    def _pulling(self, row: int) -> NDArray[np.bool_]:
        """(N,) the attached tracks tracked at ``row`` that pull it: not anchored there,
        unless attached ahead of its fit."""
        return self.attached & (self.tracks.flags[row] == TrackFlag.TRACKED) & ((self.anchor != row) | self.early)

    def frame_relayed(self, frame: int) -> NDArray[np.bool_]:
        """Which tracks of :meth:`frame_arrays` (same order) were attached by the relay
        alone: anchored after (or before) the rest frame and not carried ahead, so that
        their material point is only as good as the fit of their anchor frame and the
        relay's offsets there."""
        row = self._row(frame)
        if row is None:
            return np.zeros(0, bool)
        use = self._pulling(row)
        return (self.tracks.frames[self.anchor[use]] != self.rest_frame) & ~self.early[use]

    def count_older(self, frame: int) -> None:
        """Record, for the tracks anchored at ``frame`` not yet attached, how many older
        attached tracks are tracked within ``relay_radius`` of them there
        (``older_near``): few on a fast limb whose tracks all ended (94-96% of the relayed
        tracks with under 20 are on the fast limbs of the textured capture; benches/README.md,
        trackfit9), many on the trunk. Call before :meth:`attach_ahead` / :meth:`attach`."""
        row = self._row(frame)
        if row is None:
            return
        which = np.flatnonzero((self.anchor == row) & ~self.attached)
        old = np.flatnonzero(self.attached & (self.tracks.flags[row] == TrackFlag.TRACKED) & (self.anchor != row))
        if len(which) == 0 or len(old) == 0:
            return
        near = cKDTree(self.tracks.positions[row, old]).query_ball_point(self.tracks.positions[row, which],
                                                                          self.lengths.relay_radius, return_length=True)
        self.older_near[which] = near

    def frame_older_near(self, frame: int) -> NDArray[np.int64]:
        """``older_near`` of the tracks of :meth:`frame_arrays` (same order)."""
        row = self._row(frame)
        if row is None:
            return np.zeros(0, np.int64)
        return self.older_near[self._pulling(row)]

    def frame_ages(self, frame: int) -> NDArray[np.float64]:
        """Frames between each track of :meth:`frame_arrays` (same order) and its anchor."""
        row = self._row(frame)
        if row is None:
            return np.zeros(0)
        use = self._pulling(row)
        return np.abs(self.tracks.frames[row] - self.origin[use]).astype(np.float64)

    def frame_arrays(
        self, frame: int
    ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None:
        """The track term's arrays for ``frame`` (``_core.FitCore.fit_frame(tracks=)``):
        nodes (T, k), weights (T, k), tracked positions (T, 3) and precisions
        ``(Sigma + sigma^2 I)^-1`` (T, 3, 3, sigma the terms' floor, world units) of the
        attached tracks tracked there, not anchored there; None when there are none."""
        row = self._row(frame)
        if row is None:
            return None
        use = self._pulling(row)
        if not use.any():
            return None
        covariance = self.tracks.covariances[row, use]
        sigma = self.lengths.sigma
        precision = np.linalg.inv(0.5 * (covariance + covariance.transpose(0, 2, 1)) + sigma**2 * np.eye(3))
        if self.terms.relayed_weight != 1.0:
            # Tracks attached after their (late) anchor frame's fit, where only the relay
            # says where their material is: trusted less.
            precision[self.frame_relayed(frame)] *= self.terms.relayed_weight
        return (
            np.ascontiguousarray(self.neighbours[use]),
            np.ascontiguousarray(self.phi[use]),
            np.ascontiguousarray(self.tracks.positions[row, use]),
            np.ascontiguousarray(precision),
        )


def select_frames(tracks: Tracks, frames: Sequence[int]) -> Tracks:
    """The part of ``tracks`` at ``frames`` (frames of the tracks not listed are dropped;
    listed frames the tracks do not have stay absent)."""
    keep = np.isin(tracks.frames, np.asarray(list(frames), np.int64))
    views = None if tracks.views is None else tracks.views[keep]
    return Tracks(
        frames=tracks.frames[keep],
        ids=tracks.ids,
        positions=tracks.positions[keep],
        covariances=tracks.covariances[keep],
        flags=tracks.flags[keep],
        views=views,
    )
