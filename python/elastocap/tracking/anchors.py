"""Drift correction against each view's first appearance (Matthews, Ishikawa & Baker 2004,
"The template update problem"): frame-to-frame matching converges from far but its errors
add up as a random walk (a tenth of a pixel per frame on weak texture is most of a pixel
after fifty); matching the patch as first seen, started at the frame-to-frame result,
does not drift. The anchor patch is kept while it still matches (correlation and a
correction within ``reach``) and replaced by the current patch when it does not (the
appearance changed: a limb turned).

Anchor patches are stored per point and camera (``size + 6`` pixels square, flat memory),
laid out as tiles of one mosaic image per camera for the batched matcher."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap import _core
from elastocap.stereo import match_patches
from elastocap.stereo.matching import Matches, MatchStatus, Refined, checked_image, checked_weights, match_checked_pairs
from elastocap.tracking import settings
from elastocap.tracking.frame_images import checked as checked_images

__all__ = ["Anchors"]


class Anchors:
    """First-appearance patches of every point in every camera (NaN-free where ``held``)."""

    def __init__(self, cameras: int, size: int) -> None:
        self.size = size
        self.side = size + 6  # the patch, its gradient border and the bicubic margin
        # Per point and camera (:meth:`_view`): the patches and their template weights (the
        # frame's mask; 1 where none given); whether held; where each was cut (frame number,
        # position: a resumed run cuts it again); how many times it was cut since the view
        # was acquired (its drift grows with the cuts again: :mod:`elastocap.tracking.drift`);
        # the richer model's centre minus the affine one, smoothed over the frames since
        # the patch was cut (``settings.ANCHOR_REFINE_SMOOTH``; NaN until the first); how
        # many corrections it has been through since it was cut (the richer stage's age
        # gate, ``settings.ANCHOR_REFINE_MIN_AGE`` / ``ANCHOR_REFINE_EVERY``).
        self._new_stores(0, cameras)
        self._view(0)

    def grow(self, n: int) -> None:
        """Room for ``n`` points in all. The arrays are views of the first ``n`` rows of
        stores with room to spare: a seeding frame adds hundreds of points to ~1,500, and
        copying every patch and weight (~14 kB a point each) into new arrays on each such
        frame cost ~0.02 CPU s (more in page faults on a loaded machine); a store is copied
        only when its room runs out (to twice the points then), and only the rows taken
        into the view are written (with their start values: the room past them is never
        touched)."""
        count = len(self.held)
        if n <= count:
            return
        c = self.held.shape[1]
        if n > len(self._held_store):
            old = self._stores()
            self._new_stores(max(n, 2 * count, 64), c)
            for store, values in zip(self._stores(), old):
                store[:count] = values[:count]
        self._start(count, n)
        self._view(n)

    def _stores(self) -> tuple[NDArray[np.generic], ...]:
        return (self._patches_store, self._weights_store, self._held_store, self._frame_store, self._uv_store,
                self._cuts_store, self._offset_store, self._age_store)

    def _new_stores(self, room: int, c: int) -> None:
        """Stores of ``room`` points, not written (:meth:`_start` writes the rows taken)."""
        side = self.side
        self._patches_store = np.empty((room, c, side, side), np.float32)
        self._weights_store = np.empty((room, c, side, side), np.float32)
        self._held_store = np.empty((room, c), bool)
        self._frame_store = np.empty((room, c), np.int64)
        self._uv_store = np.empty((room, c, 2))
        self._cuts_store = np.empty((room, c), np.int64)
        self._offset_store = np.empty((room, c, 2))
        self._age_store = np.empty((room, c), np.int64)

    def _start(self, begin: int, end: int) -> None:
        """The stores' rows ``begin:end`` at their start values (nothing held)."""
        self._patches_store[begin:end] = 0.0
        self._weights_store[begin:end] = 1.0
        self._held_store[begin:end] = False
        self._frame_store[begin:end] = -1
        self._uv_store[begin:end] = np.nan
        self._cuts_store[begin:end] = 0
        self._offset_store[begin:end] = np.nan
        self._age_store[begin:end] = 0

    def _view(self, n: int) -> None:
        """The arrays as the stores' first ``n`` rows (writes go to the stores)."""
        self.patches, self.weights = self._patches_store[:n], self._weights_store[:n]
        self.held, self.frame, self.uv = self._held_store[:n], self._frame_store[:n], self._uv_store[:n]
        self.cuts, self.offset, self.age = self._cuts_store[:n], self._offset_store[:n], self._age_store[:n]

    def cut(self, images: Sequence[NDArray[np.float32]], uv: NDArray[np.float64], where: NDArray[np.bool_], frame: int, *,
            weights: Sequence[NDArray[np.float32]] | None = None) -> None:
        """Take the patches around ``uv`` (N, C, 2) where ``where`` (N, C) from the images
        of ``frame``, and their template weights from ``weights`` (per camera, e.g. the
        frame's masks; all 1 when not given)."""
        self.grow(len(uv))
        for p, k in zip(*np.nonzero(where)):
            centre = (float(uv[p, k, 0]), float(uv[p, k, 1]))
            self.patches[p, k] = cv2.getRectSubPix(images[k], (self.side, self.side), centre)
            self.weights[p, k] = 1.0 if weights is None else cv2.getRectSubPix(weights[k], (self.side, self.side), centre)
        self.held[: len(where)] |= where
        self.frame[: len(where)][where] = frame
        self.uv[: len(where)][where] = uv[where]
        self.cuts[: len(where)][where] += 1
        self.offset[: len(where)][where] = np.nan
        self.age[: len(where)][where] = 0

    def drop(self, where: NDArray[np.bool_]) -> None:
        self.held[: len(where)] &= ~where
        self.cuts[: len(where)][where] = 0

    def recuts(self, views: NDArray[np.bool_]) -> NDArray[np.int64]:
        """(N,) the most cuts again (after the first) among each point's ``views`` (N, C)."""
        n = len(views)
        self.grow(n)
        return np.where(views & self.held[:n], np.maximum(self.cuts[:n] - 1, 0), 0).max(axis=1, initial=0)

    def correct(self, images: Sequence[NDArray[np.float32]], uv: NDArray[np.float64], *, min_correlation: float,
                reach: float, min_texture: float) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """``uv`` (N, C, 2) refined against the anchors where held and tracked; returns the
        refined positions and where the anchor no longer matched (to be re-cut)."""
        out, _, good = self._match(images, uv, self.held[: len(uv)] & np.isfinite(uv[..., 0]),
                                   min_correlation=min_correlation, reach=reach, min_texture=min_texture,
                                   refine=settings.ANCHOR_REFINE, smooth=True)
        tried = self.held[: len(uv)] & np.isfinite(uv[..., 0])
        return np.where(good[..., None], out, uv), tried & ~good

    def rescue(self, images: Sequence[NDArray[np.float32]], starts: NDArray[np.float64], where: NDArray[np.bool_], *,
               min_correlation: float, reach: float, min_texture: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Views the frame-to-frame match lost (``where`` (N, C), started at ``starts``
        (N, C, 2)) matched again from their anchor patch: a weak or changing texture fails
        the frame-to-frame check by chance far more often than the first-appearance patch
        stops matching. Returns positions (N, C, 2) and covariances (N, C, 2, 2), NaN where
        not found."""
        out, cov, good = self._match(images, starts, where & self.held[: len(starts)] & np.isfinite(starts[..., 0]),
                                     min_correlation=min_correlation, reach=reach, min_texture=min_texture,
                                     refine=settings.ANCHOR_REFINE if settings.ANCHOR_REFINE_RESCUE else None)
        return np.where(good[..., None], out, np.nan), np.where(good[..., None, None], cov, np.nan)

    def search(self, images: Sequence[NDArray[np.float32]], targets: NDArray[np.float64], where: NDArray[np.bool_], *,
               radius: int, min_correlation: float, box_correlation: float, forward_backward: float,
               min_texture: float, max_iterations: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The anchor patches of ``where`` (N, C) looked for around ``targets`` (N, C, 2):
        the tracker's step from the anchor mosaic into the image (NCC box search of
        ``radius`` pixels around the target, least-squares match, forward-backward check),
        for a target that may be pixels off (a point predicted over several frames).
        Returns positions (N, C, 2) and covariances (N, C, 2, 2), NaN where not found."""
        n, c = targets.shape[:2]
        self.grow(n)
        out = np.full((n, c, 2), np.nan)
        cov = np.full((n, c, 2, 2), np.nan)
        where = where & self.held[:n] & np.isfinite(targets).all(axis=2)
        cams = [k for k in range(c) if where[:, k].any()]
        if not cams:
            return out, cov
        # Every camera's mosaic in one step call (one parallel pass over all the views, the
        # same result per view as a call per camera): rows padded with NaN (not searched)
        # to the longest camera's.
        rows_of = [np.flatnonzero(where[:, k]) for k in cams]
        m = max(rows.size for rows in rows_of)
        last = np.full((len(cams), m, 2), np.nan)
        before = np.full((len(cams), m, 2), np.nan)
        mosaics, weighs, ones = [], [], {}
        for j, (k, rows) in enumerate(zip(cams, rows_of)):
            mosaic, weigh, centres = self._mosaic(rows, k)
            mosaics.append(mosaic)
            weighs.append(weigh)
            last[j, : rows.size] = centres
            # The step predicts 2 last - before: a prediction at the target.
            before[j, : rows.size] = 2 * centres - targets[rows, k]
            shape = images[k].shape
            if shape not in ones:
                ones[shape] = np.ones(shape, np.float32)
        pos, flags, pcov, corr = _core.track_step(
            mosaics, [images[k] for k in cams], last, before, size=self.size, radius=radius,
            min_correlation=box_correlation, forward_backward=forward_backward, min_texture=min_texture,
            max_iterations=max_iterations, weights=(weighs, [ones[images[k].shape] for k in cams]))
        for j, (k, rows) in enumerate(zip(cams, rows_of)):
            good = (flags[j, : rows.size] == 0) & (corr[j, : rows.size] >= min_correlation)
            out[rows[good], k] = pos[j, : rows.size][good]
            cov[rows[good], k] = pcov[j, : rows.size][good]
        return out, cov

    def _mosaic(self, rows: NDArray[np.int64], k: int) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float64]]:
        """Camera ``k``'s anchor patches of ``rows`` as tiles of one image, their weights
        likewise, and the tiles' centres (M, 2)."""
        half = self.side // 2
        side = self.side
        per_row = int(np.ceil(np.sqrt(rows.size)))
        full, rest = divmod(rows.size, per_row) if per_row else (0, 0)

        def tiled(stored: NDArray[np.float32]) -> NDArray[np.float32]:
            # Tile i at (i // per_row, i % per_row), zeros past the last: the tiles written
            # straight into the mosaic through its (tile row, tile column, y, x) view (one
            # copy of the patches, not a padded stack and a second copy; a new array each
            # call, so the weights never overwrite the patches).
            out = np.zeros((per_row * side, per_row * side), np.float32)
            grid = out.reshape(per_row, side, per_row, side).transpose(0, 2, 1, 3)
            grid[:full] = stored[rows[: full * per_row], k].reshape(full, per_row, side, side)
            if rest:
                grid[full, :rest] = stored[rows[full * per_row :], k]
            return out

        mosaic = tiled(self.patches)
        weighs = tiled(self.weights)
        index = np.arange(rows.size)
        centres = np.column_stack([(index % per_row) * self.side + half, (index // per_row) * self.side + half]).astype(float)
        return mosaic, weighs, centres

    def _match(self, images: Sequence[NDArray[np.float32]], uv: NDArray[np.float64], where: NDArray[np.bool_], *,
               min_correlation: float, reach: float, min_texture: float,
               refine: dict[str, object] | None = None,
               smooth: bool = False) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        n, c = uv.shape[:2]
        self.grow(n)
        out = uv.copy()
        cov = np.full((n, c, 2, 2), np.nan)
        matched = np.zeros((n, c), bool)
        if refine is None:
            # The affine match (the default): every camera's mosaic into its image in one
            # parallel core call, not one call a camera.
            self._match_batched(images, uv, where, out, cov, matched, min_correlation=min_correlation, reach=reach,
                                min_texture=min_texture)
            return out, cov, matched
        for k in range(c):
            rows = np.flatnonzero(where[:, k])
            if rows.size == 0:
                continue
            mosaic, weighs, centres = self._mosaic(rows, k)
            alpha = settings.ANCHOR_REFINE_SMOOTH
            if refine is not None and smooth and alpha < 1.0:
                m, pos = self._smoothed(mosaic, weighs, centres, images[k], uv[rows, k], rows, k, alpha,
                                        min_texture=min_texture, reach=reach, refine=refine)
            else:
                m = _Rows.of(match_patches(mosaic, centres, [images[k]], initial=uv[rows, k][:, None, :],
                                           size=self.size, min_texture=min_texture, max_iterations=15,
                                           max_shift=reach, weights=weighs, refine=refine))
                pos = m.positions
            good = ((m.status == MatchStatus.CONVERGED) & (m.correlation >= min_correlation)
                    & (np.linalg.norm(pos - uv[rows, k], axis=1) <= reach))
            out[rows[good], k] = pos[good]
            cov[rows[good], k] = m.covariance[good, :2, :2]
            matched[rows[good], k] = True
        return out, cov, matched

    def _match_batched(self, images: Sequence[NDArray[np.float32]], uv: NDArray[np.float64], where: NDArray[np.bool_],
                       out: NDArray[np.float64], cov: NDArray[np.float64], matched: NDArray[np.bool_], *,
                       min_correlation: float, reach: float, min_texture: float) -> None:
        """:meth:`_match` without the richer stage, all cameras in one call (the same
        matches, bit for bit, as one ``match_patches`` call per camera); fills ``out``,
        ``cov`` and ``matched`` in place. The batch's "cameras" are the C mosaics (indices
        0..C-1, weighed by their tiles' weights) and the C images (C..2C-1)."""
        c = uv.shape[1]
        mosaics: list[NDArray[np.float32] | None] = [None] * (2 * c)
        weighs: list[NDArray[np.float32] | None] = [None] * (2 * c)
        rows_of, centres_of, pairs_of = [], [], []
        for k in range(c):
            rows = np.flatnonzero(where[:, k])
            if rows.size == 0:
                continue
            mosaic, weigh, centres = self._mosaic(rows, k)
            mosaics[k], mosaics[c + k] = checked_image(mosaic), checked_images(images, k)
            weighs[k] = checked_weights(weigh, mosaic.shape)
            rows_of.append(rows)
            centres_of.append(centres)
            pairs_of.append(np.broadcast_to(np.array([k, c + k]), (rows.size, 2)))
        if not rows_of:
            return
        rows = np.concatenate(rows_of)
        pairs = np.concatenate(pairs_of)
        camera = pairs[:, 0]
        starts = np.zeros((rows.size, 2, 3))
        starts[:, 0, 0] = starts[:, 1, 1] = 1.0
        starts[:, :, 2] = uv[rows, camera]
        m = match_checked_pairs(mosaics, pairs, np.concatenate(centres_of), starts, size=self.size,
                                min_texture=min_texture, max_iterations=15, max_shift=reach, weights=weighs)
        pos = m.positions[:, 0]
        good = ((m.status[:, 0] == MatchStatus.CONVERGED) & (m.correlation[:, 0] >= min_correlation)
                & (np.linalg.norm(pos - uv[rows, camera], axis=1) <= reach))
        out[rows[good], camera[good]] = pos[good]
        cov[rows[good], camera[good]] = m.covariance[good, :2, :2]
        matched[rows[good], camera[good]] = True

    def _smoothed(self, mosaic: NDArray[np.float32], weighs: NDArray[np.float32], centres: NDArray[np.float64],
                  image: NDArray[np.float32], start: NDArray[np.float64], rows: NDArray[np.int64], k: int,
                  alpha: float, *, min_texture: float, reach: float,
                  refine: dict[str, object]) -> tuple[_Rows, NDArray[np.float64]]:
        """Camera ``k``'s anchor match of ``rows`` (started at ``start`` (M, 2)) with the
        richer model's departure from the affine centre smoothed over frames; returns the
        match (status, correlation, covariance per row) and the corrected centres (M, 2).

        The departure (the affine model's slide on a turning, shaded patch) grows slowly
        with the anchor's age, while its noise (8 more unknowns; the fallback's switching)
        is new every frame and ends tracks in the trajectory checks (benches/README.md,
        lsm29). So the richer stage need not run on every view every frame: where it is
        skipped (the patch younger than ``settings.ANCHOR_REFINE_MIN_AGE`` corrections,
        off its ``ANCHOR_REFINE_EVERY`` turn, or its affine correlation at or above
        ``refine["skip_correlation"]``) the affine centre carries the last smoothed
        departure (none before the first)."""
        age = self.age[rows, k]
        self.age[rows, k] += 1
        every = max(int(settings.ANCHOR_REFINE_EVERY), 1)
        due = (age >= settings.ANCHOR_REFINE_MIN_AGE) & ((age - settings.ANCHOR_REFINE_MIN_AGE) % every == 0)

        def match(part: NDArray[np.bool_], how: dict[str, object] | None) -> Matches:
            return match_patches(mosaic, centres[part], [image], initial=start[part][:, None, :], size=self.size,
                                 min_texture=min_texture, max_iterations=15, max_shift=reach, weights=weighs,
                                 refine=how)

        if due.all():
            # One batch (the richer stage reports the affine centre it started from).
            m = _Rows.of(match(due, refine))
        else:
            m = _Rows.empty(len(rows))
            for part, how in ((due, refine), (~due, None)):
                if part.any():
                    m.fill(part, match(part, how))
        pos = m.positions
        converged = (m.status == MatchStatus.CONVERGED) & np.isfinite(m.affine[:, 0])
        ran = converged & (m.refined != Refined.SKIPPED)
        departure = pos - m.affine
        before = self.offset[rows, k]
        smoothed = np.where(np.isfinite(before), before + alpha * (departure - np.nan_to_num(before)), departure)
        self.offset[rows[ran], k] = smoothed[ran]
        pos = np.where(ran[:, None], m.affine + smoothed, pos)
        carried = converged & ~ran & np.isfinite(before[:, 0])
        return m, np.where(carried[:, None], m.affine + before, pos)


class _Rows:
    """The parts of one search image's :class:`Matches` the anchors use, per row: status,
    positions (M, 2), correlation, covariance (M, 8, 8), the affine centre (M, 2) and the
    richer stage's code; rows matched without the richer stage count as skipped."""

    def __init__(self, status: NDArray[np.uint8], positions: NDArray[np.float64], correlation: NDArray[np.float64],
                 covariance: NDArray[np.float64], affine: NDArray[np.float64], refined: NDArray[np.uint8]) -> None:
        self.status, self.positions, self.correlation = status, positions, correlation
        self.covariance, self.affine, self.refined = covariance, affine, refined

    @classmethod
    def empty(cls, n: int) -> _Rows:
        return cls(np.full(n, MatchStatus.LOW_TEXTURE, np.uint8), np.full((n, 2), np.nan), np.full(n, np.nan),
                   np.full((n, 8, 8), np.nan), np.full((n, 2), np.nan), np.zeros(n, np.uint8))

    @classmethod
    def of(cls, m: Matches) -> _Rows:
        assert m.affine_centre is not None and m.refined is not None
        return cls(m.status[:, 0], m.positions[:, 0], m.correlation[:, 0], m.covariance, m.affine_centre[:, 0],
                   m.refined[:, 0])

    def fill(self, where: NDArray[np.bool_], m: Matches) -> None:
        self.status[where] = m.status[:, 0]
        self.positions[where] = m.positions[:, 0]
        self.correlation[where] = m.correlation[:, 0]
        self.covariance[where] = m.covariance
        if m.refined is not None and (m.refined != Refined.NO).any():
            assert m.affine_centre is not None
            self.affine[where] = m.affine_centre[:, 0]
            self.refined[where] = m.refined[:, 0]
        else:
            # Matched affine only: its converged centre is the affine one, the stage skipped.
            self.affine[where] = np.where((m.status[:, 0] == MatchStatus.CONVERGED)[:, None], m.positions[:, 0], np.nan)
            self.refined[where] = Refined.SKIPPED
