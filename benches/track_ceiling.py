"""Issue 15's oracle ceiling: what the line ("through their visibility with <= 0.5 px RMS")
can reach with the matcher SPEC 7 specifies, on a textured synthetic capture.

For every measured point (``elastocap.tracking.accuracy``: a track seeded on a material
truth point, with a true surface point ``elastocap.synth.track_reference``) and every camera
whose truth sees it, each frame's temporal match is run by the tracker's own Rust step
(``_core.track_step``: the tracker's patch side, iterations, box correlation, mask weights,
forward-backward check; the least-squares match's correlation threshold applied after it as
``FrameTracker.step`` does) STARTED AT THE TRUTH: the search box has radius 0 and the linear
prediction is the true projection, so the box search only scores the start (its correlation
must still pass) and the least-squares match starts from it with the identity affine. Two
templates:

- ``f2f`` (frame to frame): the previous frame's patch, cut at the true projection.
- ``anchored``: the patch of the first frame on which that camera sees the point (from the
  point's seeding on), cut at the true projection there; it bridges gaps in visibility.

Each match gives the converged position's distance from the true projection (``error``,
pixels) and whether the tracker's acceptance tests pass (``accepted``). A view's first frame
of visibility (and, frame to frame, the first after a gap) is free: the tracker seeds or
re-acquires it, and the ceiling grants that exactly. A tracker built from this matcher that
never accumulates error can do no better than these figures (it may do worse: it starts
from predictions, not the truth, and must find the views it lost).

Readings of "through their visibility", each for the oracle and for ours and the LK peer
(``benches/peer_cases/tracking.py``'s own code):

- (a) the accuracy module's ``through``: on every frame from the seeding on where the truth
  is visible in two cameras, at least two views held (the oracle: accepted);
- (b) ``through_span``: the same up to the first frame seen by fewer than two cameras;
- (c) per camera 2-D tracks: each (point, camera) over its first run of visibility in that
  camera, from its first frame there: held on every frame of the run.

"and RMS": the RMS of the held views' errors (the oracle: the accepted ones) at most 0.5 px,
over the frames of the reading ((a): every frame from the seeding on, as the accuracy
module's ``rms``). The same readings with the forward-backward check, the correlation tests,
or both left out (``measured_no_fb``, ``measured_no_corr``, ``measured_converged``: the
matcher's error alone) say which test binds the ceiling.

Run: ``RAYON_NUM_THREADS=1 python -W ignore benches/track_ceiling.py CAPTURE --tracks DIR``
(``DIR``: ``track_points(capture, out=DIR)``'s output on the capture's frames; without it the
tracker runs into a temporary folder). ``--images OTHER``: the matches read their images
and masks from another rendering of the same figure (the same seed and frames, e.g.
without shading or noise); the truth and the tracks stay CAPTURE's. ``--frames K``: the
first K frames only. ``--no-peer``: skip the LK peer. Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from elastocap import _core
from elastocap.tracking import settings
from elastocap.tracking.flags import TrackFlag

MODES = ("f2f", "anchored")


class Oracle(NamedTuple):
    """One template mode's matches started at the truth, per frame, point and camera (F, N, C):
    ``error`` the converged position's distance from the true projection, pixels (NaN where
    no match ran or it gave no position); ``accepted`` the tracker's tests all passed;
    ``free`` the view's first frame of visibility (or frame to frame the first after a gap):
    granted; ``flag`` the step's code (``TrackFlag``; 255 where no match ran). The same match
    with tests left out: ``error_any`` the error of every match that converged (no
    correlation or forward-backward test), ``converged`` where it did, ``no_fb`` accepted
    without the forward-backward check, ``no_corr`` accepted without the correlation tests."""

    error: NDArray[np.float64]
    accepted: NDArray[np.bool_]
    free: NDArray[np.bool_]
    flag: NDArray[np.uint8]
    error_any: NDArray[np.float64]
    converged: NDArray[np.bool_]
    no_fb: NDArray[np.bool_]
    no_corr: NDArray[np.bool_]


class Matcher:
    """The tracker's images (grey float32, as ``FrameTracker`` reads them) and mask weights of
    a capture, cached per frame, and its step's options."""

    def __init__(self, capture: Any, frames: list[int], *, size: int = 15, min_correlation: float = 0.75,
                 forward_backward: float = 0.6, mask_weights: bool = True) -> None:
        from elastocap.stereo.matching import noise_level
        from elastocap.tracking.step import _grey

        self.capture, self.frames, self.names = capture, frames, capture.rig.names
        self._grey = _grey
        self.mask_weights = mask_weights
        self.cache: dict[int, tuple[list[NDArray[np.float32]], list[NDArray[np.float32]]]] = {}
        grey0, _ = self.read(0)
        # FrameTracker._read: the least texture a template must keep, from frame 0's noise.
        texture = [settings.TEXTURE_OVER_NOISE * noise_level(g) for g in grey0]
        keep = settings.KEEP_TEXTURE_OVER_NOISE / settings.TEXTURE_OVER_NOISE * min(texture)
        self.min_correlation = min_correlation
        self.options = dict(size=size, radius=0, min_correlation=min(min_correlation, settings.BOX_CORRELATION),
                            forward_backward=forward_backward, min_texture=keep,
                            max_iterations=settings.STEP_ITERATIONS, weighted_box=settings.WEIGHTED_BOX)

    def read(self, i: int) -> tuple[list[NDArray[np.float32]], list[NDArray[np.float32]]]:
        if i not in self.cache:
            f = self.frames[i]
            grey = [self._grey(self.capture.image(n, f)) for n in self.names]
            masks = [np.ascontiguousarray(self.capture.mask(n, f), dtype=np.float32) for n in self.names]
            self.cache[i] = (grey, masks)
        return self.cache[i]

    def match(self, i: int, j: int, start: NDArray[np.float64], truth: NDArray[np.float64], *,
              correlation: bool = True, forward_backward: bool = True, radius: int = 0) -> tuple[NDArray[np.float64], NDArray[np.uint8], NDArray[np.float64]]:
        """Templates at ``start`` (N, C, 2; NaN: none) in frame index ``i`` matched into frame
        index ``j``, started at ``truth`` (N, C, 2) there: (position (N, C, 2), flag (N, C),
        correlation (N, C)); ``correlation`` / ``forward_backward`` False leave that test out;
        ``radius`` > 0: the tracker's box search around ``truth`` (then a prediction)."""
        gi, mi = self.read(i)
        gj, mj = self.read(j)
        weights = (mi, mj) if self.mask_weights else None
        last = np.ascontiguousarray(start.transpose(1, 0, 2))
        # The step predicts 2 last - before: before so that the prediction is the truth.
        before = np.ascontiguousarray((2 * start - np.where(np.isfinite(start), truth, np.nan)).transpose(1, 0, 2))
        options = dict(self.options, radius=radius)
        if not correlation:
            options["min_correlation"] = -1.0
        if not forward_backward:
            options["forward_backward"] = 1e9
        pos, flag, _, corr = _core.track_step(gi, gj, last, before, weights=weights, **options)
        pos, flag, corr = pos.transpose(1, 0, 2), flag.T.copy(), corr.T
        if correlation:
            # FrameTracker.step: the least-squares match, not only the box, must reach the threshold.
            weak = (flag == TrackFlag.TRACKED) & ~(corr >= self.min_correlation)
            flag[weak] = TrackFlag.LOW_CORRELATION
        return pos, flag, corr


def first_views(seen: NDArray[np.bool_], first: NDArray[np.int64]) -> NDArray[np.int64]:
    """(N, C) the first frame index, from each point's ``first`` (N,) on, on which ``seen``
    (F, N, C) holds (-1: never)."""
    f = seen.shape[0]
    after = seen & (np.arange(f)[:, None, None] >= first[None, :, None])
    return np.where(after.any(axis=0), np.argmax(after, axis=0), -1)


def oracle(matcher: Matcher, truth_uv: NDArray[np.float64], seen: NDArray[np.bool_], first: NDArray[np.int64],
           mode: str) -> Oracle:
    """The matches started at the truth (module docstring) for points with true views
    ``truth_uv`` (F, N, C, 2), per-camera visibility ``seen`` (F, N, C) and seeding frame
    index ``first`` (N,; -1 never seeded)."""
    f, n, c = seen.shape
    live = seen & (np.arange(f)[:, None, None] >= first[None, :, None]) & (first >= 0)[None, :, None]
    error = np.full((f, n, c), np.nan)
    error_any = np.full((f, n, c), np.nan)
    accepted, converged, no_fb, no_corr = (np.zeros((f, n, c), bool) for _ in range(4))
    flag = np.full((f, n, c), 255, np.uint8)
    anchor = first_views(live, np.maximum(first, 0))
    if mode == "f2f":
        free = live & ~np.concatenate([np.zeros((1, n, c), bool), live[:-1]], axis=0)
    elif mode == "anchored":
        free = live & (np.arange(f)[:, None, None] == anchor[None])
    else:
        raise ValueError(f"mode must be one of {MODES}, not {mode!r}")
    tracked = TrackFlag.TRACKED
    for t in range(1, f):
        todo = live[t] & ~free[t]
        if not todo.any():
            continue
        sources = [t - 1] if mode == "f2f" else np.unique(anchor[todo]).tolist()
        for s in sources:
            rows = todo if mode == "f2f" else todo & (anchor == s)
            start = np.where(rows[..., None], truth_uv[s], np.nan)
            pos, code, _ = matcher.match(s, t, start, truth_uv[t])
            flag[t][rows] = code[rows]
            accepted[t][rows] = (code == tracked)[rows]
            error[t][rows] = np.linalg.norm(pos - truth_uv[t], axis=2)[rows]
            # The tests left out: the match alone (convergence), and each test alone.
            pos, code, corr = matcher.match(s, t, start, truth_uv[t], correlation=False, forward_backward=False)
            converged[t][rows] = (code == tracked)[rows]
            error_any[t][rows] = np.linalg.norm(pos - truth_uv[t], axis=2)[rows]
            no_fb[t][rows] = ((code == tracked) & (corr >= matcher.min_correlation))[rows]
            _, code, _ = matcher.match(s, t, start, truth_uv[t], correlation=False)
            no_corr[t][rows] = (code == tracked)[rows]
    return Oracle(error, accepted, free, flag, error_any, converged, no_fb, no_corr)


def seen_by_camera(positions0: NDArray[np.float64], first: NDArray[np.int64], truth_positions: NDArray[np.float64],
                   visible: NDArray[np.bool_], part: NDArray[np.int64], usable: NDArray[np.bool_],
                   neighbours: int = 8) -> NDArray[np.bool_]:
    """(F, N, C) whether each camera sees each track's truth, as ``track_accuracy`` decides it
    (the ``neighbours`` material truth points nearest its seeded position ``positions0``
    (N, 3) at its seeding frame index ``first`` (N,), on that point's part, all visible):
    the visibility its ``expected`` counts cameras of."""
    f, c, _ = visible.shape
    n = len(first)
    seen = np.zeros((f, n, c), bool)
    for s in np.unique(first[first >= 0]):
        rows = np.flatnonzero(first == s)
        x0 = positions0[rows]
        _, nearest = cKDTree(truth_positions[s]).query(x0, k=1)
        near = np.zeros((rows.size, neighbours), np.int64)
        for p in np.unique(part[nearest]):
            on = np.flatnonzero((part == p) & usable)
            if on.size == 0:
                on = np.flatnonzero(part == p)
            sel = part[nearest] == p
            _, idx = cKDTree(truth_positions[s, on]).query(x0[sel], k=min(neighbours, on.size))
            near[sel] = on[np.atleast_2d(idx).reshape(sel.sum(), -1)[:, :neighbours]] if on.size >= neighbours else on[0]
        for t in range(s, f):
            seen[t, rows] = visible[t][:, near].all(axis=2).T
    return seen


def _span_frames(seen: NDArray[np.bool_], first: NDArray[np.int64]) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """(F, N) frames of reading (a) (from the seeding on, seen by two cameras) and of
    reading (b) (those up to the first frame seen by fewer)."""
    f = seen.shape[0]
    after = (np.arange(f)[:, None] >= first[None, :]) & (first >= 0)[None, :]
    expected = after & (seen.sum(axis=2) >= 2)
    span = after & (np.cumsum(after & ~expected, axis=0) == 0)
    return expected, span


def _runs(seen: NDArray[np.bool_], first: NDArray[np.int64]) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Reading (c): (F, N, C) the first run of visibility of each (point, camera) from the
    point's seeding on, and (N, C) which pairs have one."""
    f = seen.shape[0]
    live = seen & (np.arange(f)[:, None, None] >= first[None, :, None]) & (first >= 0)[None, :, None]
    started = np.cumsum(live, axis=0) > 0
    broken = np.cumsum(started & ~live, axis=0) > 0
    run = live & ~broken
    return run, run.any(axis=0)


def _rms(err: NDArray[np.float64], where: NDArray[np.bool_], axis: int | tuple[int, ...]) -> NDArray[np.float64]:
    """RMS of ``err`` over ``where`` along ``axis`` (NaN where nothing counts)."""
    use = where & np.isfinite(err)
    count = use.sum(axis=axis)
    squares = (np.where(use, err, 0.0) ** 2).sum(axis=axis)
    with np.errstate(all="ignore"):
        return np.where(count > 0, np.sqrt(squares / np.maximum(count, 1)), np.nan)


def readings(held: NDArray[np.bool_], error: NDArray[np.float64], seen: NDArray[np.bool_], first: NDArray[np.int64],
             rows: NDArray[np.int64], tracked: NDArray[np.bool_] | None = None, min_views: int = 2) -> dict[str, float]:
    """Shares of the points ``rows`` (and of their (point, camera) pairs for (c)) through on
    each reading, and through with RMS <= 0.5 px: ``held`` (F, N, C) the views a tracker
    holds (the oracle: accepted or free), ``error`` (F, N, C) their image errors (pixels;
    NaN: none, a free view); ``tracked`` (F, N): on (a) and (b) a point counts as held on a frame where it is tracked
    (the accuracy module's rule for a tracker's points, whose views may lie in cameras the
    truth's neighbour rule does not count), else where ``min_views`` seeing cameras hold it
    (two: what a forward intersection needs)."""
    held, error, seen, first = held[:, rows], error[:, rows], seen[:, rows], first[rows]
    expected, span = _span_frames(seen, first)
    on = seen & held
    kept = on.sum(axis=2) >= min_views if tracked is None else tracked[:, rows]
    out: dict[str, float] = {"points": int(rows.size)}
    after = (np.arange(len(held))[:, None] >= first[None, :]) & (first >= 0)[None, :]
    for name, frames, over in (("a", expected, after), ("b", span, span)):
        # (a)'s RMS is over every frame from the seeding on (the accuracy module's ``rms``).
        through = ~(frames & ~kept).any(axis=0)
        rms = _rms(error, on & over[..., None], axis=(0, 2))
        good = rms <= 0.5
        out[f"{name}_through"] = round(float(through.mean()), 4)
        out[f"{name}_through_and_rms"] = round(float((through & good).mean()), 4)
        out[f"{name}_rms_le_0.5"] = round(float(good.mean()), 4)
    run, has = _runs(seen, first)
    through = ~(run & ~held).any(axis=0)
    rms = _rms(error, run & held, axis=0)
    good = rms <= 0.5
    out["c_pairs"] = int(has.sum())
    out["c_through"] = round(float(through[has].mean()), 4)
    out["c_through_and_rms"] = round(float((through & good)[has].mean()), 4)
    out["c_rms_le_0.5"] = round(float(good[has].mean()), 4)
    return out


def loss_causes(matcher: Matcher, ours_uv: NDArray[np.float64], truth_uv: NDArray[np.float64], tracked: NDArray[np.bool_],
                o: Oracle, seen: NDArray[np.bool_], first: NDArray[np.int64], rows: NDArray[np.int64], radius: int = 6) -> dict[str, Any]:
    """The views a tracker (views ``ours_uv`` (F, N, C, 2)) held on the frame before losing a
    point of ``rows`` in its first span, on frames where the frame-to-frame oracle ``o``
    holds two views, matched again with one of the tracker's two handicaps at a time: the
    template cut at the tracker's view (its drift) but started at the truth; the template at
    the truth but found from the tracker's own linear prediction (its velocity, applied at
    the truth) by the box search of ``radius``; and both (the plain step, which the tracker
    ran before its other searches). Shares accepted, and within 0.5 px of the truth."""
    f = seen.shape[0]
    _, span = _span_frames(seen[:, rows], first[rows])
    miss = span & ~tracked[:, rows]
    lost = miss.any(axis=0)
    t_of = np.where(lost, np.argmax(miss, axis=0), -1)
    oracle_held = ((o.accepted | o.free)[:, rows] & seen[:, rows]).sum(axis=2) >= 2
    out: dict[str, Any] = {}
    counts = {k: [0, 0, 0] for k in ("drift_only", "prediction_only", "both")}
    views = 0
    for t in range(2, f):
        cols = np.flatnonzero((t_of == t) & oracle_held[t, np.arange(rows.size)])
        if cols.size == 0:
            continue
        pts = rows[cols]
        sel = np.zeros(seen.shape[1:], bool)
        sel[pts] = seen[t, pts] & np.isfinite(ours_uv[t - 1, pts, :, 0])
        if not sel.any():
            continue
        views += int(sel.sum())
        velocity = np.where(np.isfinite(ours_uv[t - 2]), ours_uv[t - 1] - ours_uv[t - 2], 0.0)
        cases = {
            "drift_only": (ours_uv[t - 1], truth_uv[t], 0),
            "prediction_only": (truth_uv[t - 1], truth_uv[t - 1] + velocity, radius),
            "both": (ours_uv[t - 1], ours_uv[t - 1] + velocity, radius),
        }
        for name, (template, start, r) in cases.items():
            pos, code, _ = matcher.match(t - 1, t, np.where(sel[..., None], template, np.nan), start, radius=r)
            ok = (code == TrackFlag.TRACKED)[sel]
            err = np.linalg.norm(pos - truth_uv[t], axis=2)[sel]
            counts[name][0] += int(ok.sum())
            counts[name][1] += int((ok & (err <= 0.5)).sum())
    out["views"] = views
    for name, (ok, near, _) in counts.items():
        out[f"{name}_accepted"] = round(ok / max(views, 1), 4)
        out[f"{name}_accepted_within_0.5px"] = round(near / max(views, 1), 4)
    return out


def span_losses(tracked: NDArray[np.bool_], flags: NDArray[np.uint8], held: NDArray[np.bool_], error: NDArray[np.float64],
                o: Oracle, seen: NDArray[np.bool_], first: NDArray[np.int64], rows: NDArray[np.int64]) -> dict[str, Any]:
    """Where a tracker's points ``rows`` that miss reading (b) are lost (``tracked`` (F, N),
    its ``flags`` (F, N), ``held`` views (F, N, C) and their ``error`` (F, N, C)): on the
    first frame of their first span not tracked, whether the frame-to-frame oracle ``o``
    holds two views there (the matcher could have kept the point: the tracker's own loss) or
    not (the ceiling's loss), the tracker's flag there, and its views the frame before (their
    worst error against the truth, how many it held, how many cameras see the point)."""
    tracked, flags, held, error, seen, first = tracked[:, rows], flags[:, rows], held[:, rows], error[:, rows], seen[:, rows], first[rows]
    _, span = _span_frames(seen, first)
    miss = span & ~tracked
    lost = miss.any(axis=0)
    t = np.argmax(miss, axis=0)[lost]
    cols = np.flatnonzero(lost)
    oracle_held = ((o.accepted | o.free)[:, rows] & seen).sum(axis=2) >= 2
    holds = oracle_held[t, cols]
    before = np.maximum(t - 1, 0)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        worst = np.nanmax(np.where(held[before, cols], error[before, cols], np.nan), axis=1)
    views = held[before, cols].sum(axis=1)
    codes, counts = np.unique(flags[t, cols], return_counts=True)
    out: dict[str, Any] = {
        "points": int(rows.size),
        "lost_in_span": int(lost.sum()),
        "oracle_holds_at_loss": round(float(holds.mean()), 4) if lost.any() else float("nan"),
        "flags_at_loss": {TrackFlag(int(k)).name: int(v) for k, v in zip(codes, counts)},
        "age_at_loss_median": float(np.median(t - first[cols])) if lost.any() else float("nan"),
        "views_held_before_median": float(np.median(views)) if lost.any() else float("nan"),
        "views_seen_at_loss_median": float(np.median(seen[t, cols].sum(axis=1))) if lost.any() else float("nan"),
    }
    for name, sel in (("oracle_holds", holds), ("oracle_fails", ~holds)):
        w = worst[sel]
        w = w[np.isfinite(w)]
        out[f"{name}_worst_error_before_median_px"] = round(float(np.median(w)), 3) if w.size else float("nan")
        out[f"{name}_worst_error_before_over_1px"] = round(float(np.mean(w > 1.0)), 3) if w.size else float("nan")
    return out


def oracle_summary(o: Oracle, seen: NDArray[np.bool_], rows: NDArray[np.int64]) -> dict[str, Any]:
    """Per-match figures of the points ``rows``: the error's quantiles over every match that
    gave a position, the accepted share, and the rejections by flag."""
    ran = o.flag[:, rows] != 255
    e = o.error[:, rows][ran & np.isfinite(o.error[:, rows])]
    a = o.error_any[:, rows][ran & np.isfinite(o.error_any[:, rows])]
    codes, counts = np.unique(o.flag[:, rows][ran], return_counts=True)
    return {
        "matches": int(ran.sum()),
        "accepted_share": round(float(o.accepted[:, rows][ran].mean()), 4) if ran.any() else float("nan"),
        "error_median_px": round(float(np.median(e)), 4) if e.size else float("nan"),
        "error_p90_px": round(float(np.percentile(e, 90)), 4) if e.size else float("nan"),
        "error_rms_px": round(float(np.sqrt(np.mean(e**2))), 4) if e.size else float("nan"),
        "error_over_0.5px": round(float(np.mean(e > 0.5)), 4) if e.size else float("nan"),
        # Every converged match (no correlation or forward-backward test): the matcher's error.
        "converged_share": round(float(o.converged[:, rows][ran].mean()), 4) if ran.any() else float("nan"),
        "converged_error_median_px": round(float(np.median(a)), 4) if a.size else float("nan"),
        "converged_error_rms_px": round(float(np.sqrt(np.mean(a**2))), 4) if a.size else float("nan"),
        "converged_error_over_0.5px": round(float(np.mean(a > 0.5)), 4) if a.size else float("nan"),
        "flags": {TrackFlag(int(k)).name if int(k) in TrackFlag._value2member_map_ else str(int(k)): int(v)
                  for k, v in zip(codes, counts)},
    }


def true_views(cameras: Any, positions: NDArray[np.float64]) -> NDArray[np.float64]:
    """(F, N, C, 2) projections of ``positions`` (F, N, 3) (NaN rows stay NaN)."""
    f, n, _ = positions.shape
    out = np.full((f, n, len(cameras), 2), np.nan)
    flat = positions.reshape(-1, 3)
    ok = np.isfinite(flat).all(axis=1)
    for k, cam in enumerate(cameras):
        uv = np.full((flat.shape[0], 2), np.nan)
        uv[ok] = cam.project(flat[ok])[0]
        out[:, :, k] = uv.reshape(f, n, 2)
    return out


def ceiling(folder: Path, tracks_dir: Path | None, images: Path | None, frames_limit: int | None, peer: bool) -> dict[str, Any]:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from elastocap import Capture
    from elastocap.synth.textured import load_textured_truth
    from elastocap.synth.track_reference import surface_reference
    from elastocap.tracking import load_tracks, track_points
    from elastocap.tracking.accuracy import track_accuracy
    from elastocap.tracking.tracks import frame_file, read_frame

    capture = Capture.open(folder)
    truth = load_textured_truth(folder)
    frames = [int(f) for f in truth.frames]
    cpu = time.process_time()
    if tracks_dir is None:
        with tempfile.TemporaryDirectory() as out:
            ours = track_points(capture, frames=frames, out=out)
            uv0 = read_frame(frame_file(out, frames[0]))["uv"]
    else:
        ours = load_tracks(tracks_dir)
        uv0 = read_frame(frame_file(tracks_dir, frames[0]))["uv"]
    cams = capture.rig.cameras
    reference = surface_reference(ours, truth).positions
    acc = track_accuracy(ours, cams, truth.positions, truth.visible, truth.part, material=truth.material, reference=reference)
    tracked = ours.flags == TrackFlag.TRACKED
    first = np.where(tracked.any(axis=0), np.argmax(tracked, axis=0), -1)
    positions0 = ours.positions[np.maximum(first, 0), np.arange(len(first))]
    usable = np.all(np.asarray(truth.material, bool), axis=0)
    seen = seen_by_camera(positions0, first, truth.positions, truth.visible, truth.part, usable)
    f = len(frames) if frames_limit is None else min(frames_limit, len(frames))
    measured = np.flatnonzero(acc.measured & (first >= 0) & (first < f))
    born = measured[first[measured] == 0]
    uv = true_views(cams, reference)[:f]
    seen, first_f = seen[:f], first
    # Views of ours: held where the track is tracked and the view recorded.
    assert ours.views is not None
    ours_held = np.isfinite(ours.views[:f, ..., 0]) & tracked[:f, :, None]
    ours_err = np.where(ours_held, np.linalg.norm(ours.views[:f] - uv, axis=3), np.nan)
    result: dict[str, Any] = {"capture": str(folder), "images": str(images or folder), "frames": f,
                              "measured": int(measured.size), "born": int(born.size)}
    if f == len(frames):
        # The accuracy module's own figures (peers.py's true_reference row), to check the
        # readings here against.
        result["ours_accuracy_module"] = {
            "a_through": round(float(acc.through[measured].mean()), 4),
            "b_through": round(float(acc.through_span[measured].mean()), 4),
            "a_through_and_rms": round(float((acc.through & (acc.rms <= 0.5))[measured].mean()), 4),
        }
    result["ours"] = {"measured": readings(ours_held, ours_err, seen, first_f, measured, tracked=tracked[:f]),
                      "born": readings(ours_held, ours_err, seen, first_f, born, tracked=tracked[:f])}
    source = capture if images is None else Capture.open(images)
    matcher = Matcher(source, frames[:f])
    for mode in MODES:
        o = oracle(matcher, uv, seen, np.where(first < f, first, -1), mode)
        result[f"oracle_{mode}"] = {
            "matches": oracle_summary(o, seen, measured),
            # The ceiling: every test the tracker applies.
            "measured": readings(o.accepted | o.free, o.error, seen, first_f, measured),
            "born": readings(o.accepted | o.free, o.error, seen, first_f, born),
            # Which test binds it: each left out in turn, then both (the match's convergence
            # alone, its error over every converged match).
            "measured_no_fb": readings(o.no_fb | o.free, o.error_any, seen, first_f, measured),
            "measured_no_corr": readings(o.no_corr | o.free, o.error_any, seen, first_f, measured),
            "measured_converged": readings(o.converged | o.free, o.error_any, seen, first_f, measured),
            # A tracker that kept a point on one accepted view for a frame (its depth from
            # elsewhere): what the second view's rejection costs.
            "measured_one_view": readings(o.accepted | o.free, o.error, seen, first_f, measured, min_views=1),
        }
        if mode == "f2f":
            result["ours_span_losses"] = span_losses(tracked[:f], ours.flags[:f], ours_held, ours_err, o, seen,
                                                     first_f, measured)
            if images is None:
                ours_uv = np.where(ours_held[..., None], ours.views[:f], np.nan)
                result["ours_loss_causes"] = loss_causes(matcher, ours_uv, uv, tracked[:f], o, seen, first_f, measured)
    if peer and images is None:
        from peer_cases.tracking import peer_tracks

        peer_xyz, views = peer_tracks(capture, uv0[born], frames[:f])
        held = np.isfinite(views[..., 0])
        err = np.where(held, np.linalg.norm(views - uv[:, born], axis=3), np.nan)
        full_held = np.zeros_like(ours_held)
        full_err = np.full_like(ours_err, np.nan)
        full_tracked = np.zeros_like(tracked[:f])
        full_held[:, born], full_err[:, born] = held, err
        full_tracked[:, born] = peer_xyz.flags == TrackFlag.TRACKED
        result["peer"] = {"born": readings(full_held, full_err, seen, first_f, born, tracked=full_tracked)}
    result["cpu_s"] = round(time.process_time() - cpu, 1)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("capture", type=Path)
    parser.add_argument("--tracks", type=Path, help="track_points' output folder on the capture (else run it)")
    parser.add_argument("--images", type=Path, help="match in another rendering of the same figure")
    parser.add_argument("--frames", type=int, help="the first K frames only")
    parser.add_argument("--no-peer", action="store_true", help="skip the LK peer")
    args = parser.parse_args()
    print(json.dumps(ceiling(args.capture, args.tracks, args.images, args.frames, not args.no_peer)), flush=True)


if __name__ == "__main__":
    main()
