"""The tracker's per-frame step (issue 15): the state carried from frame to frame and one
frame's work on it, stage by stage. Every camera's points tracked from the previous frame
in one Rust call (prediction, NCC box search, temporal LSM, forward-backward check),
corrected by their anchors and rescued from them, re-tied to one another across the
cameras (:mod:`elastocap.tracking.step_views`); intersected and filtered as trajectories
(:mod:`elastocap.tracking.step_points`); then the lost views re-acquired
(:mod:`elastocap.tracking.reacquire`), optionally handed over to another stereo pair
(:mod:`elastocap.tracking.handover`), lost points revived (:mod:`elastocap.tracking.revival`)
and new points seeded (:mod:`elastocap.tracking.new_points`).
The step returns the arrays that :func:`elastocap.tracking.tracks.write_frame` writes
(positions as :mod:`elastocap.tracking.step_report` reports them), with the 2-D state that
:meth:`FrameTracker.resume` reads back (:mod:`elastocap.tracking.step_state`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap.capture import Capture
from elastocap.stereo.matching import noise_level
from elastocap.tracking import settings
from elastocap.tracking.anchors import Anchors
from elastocap.tracking.depth_slide import along_state
from elastocap.tracking.filters import pixel_size
from elastocap.tracking.frame_images import CheckedImages
from elastocap.tracking.handover import hand_over
from elastocap.tracking.new_points import add_new_points
from elastocap.tracking.pyramid_search import Pyramids
from elastocap.tracking.reacquire import reacquire
from elastocap.tracking.revival import Lost, revive
from elastocap.tracking.rigid_prediction import predicting_before, rigid_predictions
from elastocap.tracking.seed_pairs import drop_unpaired
from elastocap.tracking.step_points import locate_points
from elastocap.tracking.step_report import reported
from elastocap.tracking.step_state import forget_history, resume_state
from elastocap.tracking.step_views import ViewStep, correct_views, step_views
from elastocap.tracking.views import facing_normals, surface_normals

__all__ = ["FrameTracker"]


def _grey_levels(image: NDArray[np.uint8]) -> NDArray[np.generic]:
    """(H, W) uint8 grey levels of an RGB image; :class:`CheckedImages` makes them float32
    (whole numbers: no NaN to scan for, unlike a float image's check)."""
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


def _grey(image: NDArray[np.uint8]) -> NDArray[np.float32]:
    """(H, W) float32 grey levels of an RGB image: the values the tracker's images hold
    (benches/track_ceiling.py reads its images so)."""
    return np.ascontiguousarray(_grey_levels(image).astype(np.float32))


def _mask_weights(mask: NDArray[np.bool_]) -> NDArray[np.generic]:
    """A mask as :class:`CheckedImages` takes it to 0/1 float32 weights: a bool mask as its
    bytes (converted without the float image's NaN scan), any other as float32."""
    return mask.view(np.uint8) if mask.dtype == bool else np.ascontiguousarray(mask, dtype=np.float32)


class FrameTracker:
    """The state carried from frame to frame (all points, ids in order of seeding)."""

    # pixel_last() of the state the current step started from (None: not yet computed).
    _pixel_last: NDArray[np.float64] | None = None

    def __init__(self, capture: Capture, spacing: int, size: int, radius: int, min_correlation: float,
                 options: dict[str, Any]) -> None:
        self.capture = capture
        self.names = capture.rig.names
        self.cameras = capture.rig.cameras
        self.spacing, self.size, self.radius, self.min_correlation = spacing, size, radius, min_correlation
        self.o = options
        c = len(self.cameras)
        self.uv = np.zeros((0, c, 2))
        self.uv_last = np.zeros((0, c, 2))
        self.x_last = np.zeros((0, 3))
        self.x_before = np.zeros((0, 3))
        self.point_flags = np.zeros(0, np.uint8)
        self.grey: list[NDArray[np.float32]] | None = None
        # The previous frame's template weights (its masks as 0/1 floats), when used.
        self.weights: list[NDArray[np.float32]] | None = None
        # The previous frame's masks (the depth edges' images, settings.DEPTH_WEIGHTS).
        self.masks: list[NDArray[np.bool_]] | None = None
        self.anchors = Anchors(c, size) if options["anchor"] else None
        self.lost = Lost(settings.REVIVE_FRAMES) if options["revive"] else None
        # Per point and camera: consecutive frames its held view was predicted hidden.
        self.hidden = np.zeros((0, c), np.int64)
        # Per point: the frame it was first tracked on (-1: not yet), and the positions
        # reported on such frames, for the neighbours' rigid motion since (settings.RIGID).
        self.seeded_at = np.zeros(0, np.int64)
        self.history: dict[int, NDArray[np.float64]] = {}
        # Per point: found slid off its neighbours' rigid map (settings.SLIDE); withheld
        # from then on.
        self.slid = np.zeros(0, bool)
        # Per point: consecutive frames its depth lay beyond settings.SLIDE_ALONG from that
        # map (depth_slide.py).
        self.along_run = np.zeros(0, np.int64)
        self.depth_slid = np.zeros(0, bool)
        self.texture: list[float] = []
        self.keep_texture = 0.0
        # The coarse-to-fine search's reduced images of the last two frames (a frame's
        # current images are the next frame's previous ones: reduced once).
        self.pyramids = Pyramids()

    def _read(self, frame: int) -> tuple[list[NDArray[np.float32]], list[NDArray[np.bool_]]]:
        # Checked once here for every match of the frame (frame_images.py).
        grey = CheckedImages(_grey_levels(self.capture.image(name, frame)) for name in self.names)
        masks = [self.capture.mask(name, frame) for name in self.names]
        if not self.texture:
            self.texture = [settings.TEXTURE_OVER_NOISE * noise_level(g) for g in grey]
            self.keep_texture = settings.KEEP_TEXTURE_OVER_NOISE / settings.TEXTURE_OVER_NOISE * min(self.texture)
        return grey, masks

    def _weights(self, masks: list[NDArray[np.bool_]]) -> list[NDArray[np.float32]] | None:
        if not self.o["mask_weights"]:
            return None
        return CheckedImages(_mask_weights(m) for m in masks)

    def resume(self, out: str | Path, chosen: list[int]) -> int:
        """Restores the state after the longest prefix of ``chosen`` already written;
        returns the index to continue from (:func:`~elastocap.tracking.step_state.resume_state`)."""
        return resume_state(self, out, chosen)

    def _before(self) -> NDArray[np.float64]:
        """(N, C, 2) the views' positions on the frame before as the Rust step reads them
        (it predicts ``2 uv - before``, ``uv`` without one): ``uv_last``, or with
        ``settings.RIGID_PREDICTION`` set so that the chosen views are predicted by their
        neighbourhood's rigid 3-D motion (:mod:`elastocap.tracking.rigid_prediction`)."""
        if settings.RIGID_PREDICTION is None or len(self.uv) == 0:
            return self.uv_last
        held = np.isfinite(self.uv[..., 0])
        prediction = rigid_predictions(self.cameras, self.uv, self.x_last, self.x_before, self.pixel_last(),
                                       neighbours=settings.RIGID_PREDICTION_NEIGHBOURS,
                                       min_neighbours=settings.RIGID_PREDICTION_MIN_NEIGHBOURS,
                                       reach=settings.RIGID_PREDICTION_REACH)
        if settings.RIGID_PREDICTION == "all":
            use = held
        elif settings.RIGID_PREDICTION == "new":
            use = held & ~np.isfinite(self.uv_last[..., 0])
        else:
            raise ValueError(f"RIGID_PREDICTION must be None, 'new' or 'all', not {settings.RIGID_PREDICTION!r}")
        return predicting_before(self.uv, self.uv_last, prediction, use)

    def pixel_last(self) -> NDArray[np.float64]:
        """(N,) world size of a pixel at each point's last position, over the cameras that
        held it (:func:`~elastocap.tracking.filters.pixel_size`): the rigid prediction and
        the 2-D searches' reach ask it alike on a frame, so it is computed once a step."""
        if self._pixel_last is None:
            self._pixel_last = pixel_size(self.cameras, self.x_last, np.isfinite(self.uv[..., 0]))
        return self._pixel_last

    def step(self, frame: int, *, first: bool, reseed: bool, bare: int = 0) -> dict[str, NDArray[np.generic]]:
        self._pixel_last = None
        grey, masks = self._read(frame)
        weights = self._weights(masks)
        n, c = self.uv.shape[:2]
        alive = np.any(np.all(np.isfinite(self.uv), axis=2), axis=1)
        if first or n == 0 or self.grey is None:
            views = ViewStep.untracked(n, c)
        else:
            before = self._before()
            views = correct_views(self, frame, grey, weights, before, step_views(self, grey, masks, weights, before))
        flags2d, corr = views.flags2d, views.corr
        located = locate_points(self, masks, views, alive)
        uv, cov2d, x, xcov, flags = located.uv, located.cov2d, located.x, located.xcov, located.flags
        tracked, single, anchor = located.tracked, located.single, located.anchor

        # Lost views re-acquired by spatial matching from the view of best correlation.
        reacquire(self, grey, masks, weights, uv, cov2d, corr, x, xcov, flags, tracked, single, anchor)
        if settings.HANDOVER:
            # The other stereo pairs that see a tracked point take it on before its pair
            # loses it.
            hand_over(self, grey, masks, weights, uv, cov2d, x, xcov, tracked & np.all(np.isfinite(x), axis=1))
        lone = np.isfinite(uv[..., 0]).sum(axis=1) < 2
        uv[lone & ~single] = np.nan
        # A single view that found no partner is given up.
        uv[single & ~np.isfinite(x).all(axis=1) & lone] = np.nan
        # Keep the prediction of a point that waits on one view (its next frame predicts on).
        x_state = np.where((single & ~np.isfinite(x).all(axis=1))[:, None], anchor, x)

        if self.lost is not None and n:
            x, x_state = revive(self, frame, grey, masks, alive, uv, cov2d, x, xcov, x_state, flags, flags2d)

        # New points where the textured masks have none (with ``bare`` alone: only where
        # none lies within ``bare`` cells, seeding.seed_candidates).
        if reseed or bare > 0:
            uv, x, xcov, flags, flags2d = add_new_points(self, grey, masks, uv, x, xcov, flags, flags2d,
                                                         bare=0 if reseed else bare)
            if settings.SEED_NEEDS_PAIR:
                # Seeds whose depth no narrow pair measured (seed_pairs.py).
                uv, x, xcov, flags, flags2d = drop_unpaired(self, n, uv, x, xcov, flags, flags2d)
        total = len(uv)
        if self.anchors is not None:
            views_now = np.isfinite(uv[..., 0])
            self.anchors.grow(total)
            # A lost point keeps the anchors it had while it may be revived.
            waiting = np.zeros(total, bool)
            if self.lost is not None:
                self.lost.grow(total)
                waiting = self.lost.since[:total] >= 0
            self.anchors.drop(~views_now & ~waiting[:, None])
            self.anchors.cut(grey, uv, views_now & ~self.anchors.held[:total], frame, weights=weights)
        self.uv_last, self.uv = self.uv, uv
        if len(x_state) < len(x):
            x_state = np.concatenate([x_state, x[len(x_state):]])
        self.x_before, self.x_last = self.x_last, x_state
        self.point_flags = flags
        if self.lost is not None:
            self.lost.remember(frame, x)
        self.grey = grey
        self.weights = weights
        self.masks = masks
        self.seeded_at = np.concatenate([self.seeded_at, np.full(total - len(self.seeded_at), -1, np.int64)])
        new = (self.seeded_at < 0) & np.all(np.isfinite(x), axis=1)
        self.seeded_at[new] = frame
        if new.any():
            # The intersections, not the fused positions: what the neighbours' motion is
            # measured from then does not depend on the fusion or on withheld positions.
            self.history[frame] = x.copy()
        x_out, xcov, flags_out = reported(self, uv, x, xcov, flags)
        forget_history(self)
        return {
            "ids": np.arange(total, dtype=np.int64),
            "positions": x_out,
            "intersections": x,
            "covariances": xcov,
            "flags": flags_out,
            "uv": uv,
            "flags2d": flags2d,
            # Consecutive frames each held view was predicted hidden: a resumed run ends
            # the same views (settings.HIDDEN_FRAMES) as one run.
            "hidden_run": self.hidden.astype(np.int32),
            **along_state(self, total),
            **({} if self.lost is None else self.lost.state(total)),
            **({} if self.anchors is None else {
                "anchor_frame": np.where(self.anchors.held[:total], self.anchors.frame[:total], -1),
                "anchor_uv": self.anchors.uv[:total],
                "anchor_cuts": self.anchors.cuts[:total],
            }),
        }

    def normals(self, points: NDArray[np.float64], cloud: NDArray[np.float64],
                 seen: NDArray[np.bool_]) -> NDArray[np.float64]:
        """Surface normals at ``points`` for the start shape of wide-baseline matches."""
        towards = facing_normals(self.cameras, points, seen)
        return surface_normals(points, cloud, towards) if settings.FITTED_NORMALS else towards
