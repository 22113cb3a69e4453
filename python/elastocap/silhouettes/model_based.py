"""Model-based silhouette extraction in clutter (SPEC 8; paper 002, section 4.3):
:class:`SilhouetteTracker` and :func:`extract_silhouettes`.

Per frame and camera: the previous frame's silhouette starts an active contour on the
disparity-filtered gradient image; the body model is fitted to the stereo points and
these silhouettes; the fitted model's silhouette starts a second contour, whose result is
the frame's silhouette. Each contour is then cut by colour inside the band stereo allows
(:func:`~elastocap.silhouettes.band.refine_in_band`): edges alone cut the concave parts of
a person and stop on their texture. Last, the views check each other
(:func:`~elastocap.silhouettes.consistency.consistent_silhouettes`): a part one view's
cut lost (a head against a background of its colour) comes back where the other views,
the fitted model and this view's stereo agree on it. Then each view's colour model,
learned over the previous frames (:mod:`~elastocap.silhouettes.appearance`), drops what
has the background's colours (a strip of a near distractor the cut kept) and restores
what has the subject's inside the model and stereo. The first frame starts from what the cameras agree on: the visual
hull of the disparity masks (one camera may disagree) inside the space every camera sees,
projected back into each camera. No background plate, no hand-drawn mask.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.body.fit import BodyObservations
from elastocap.body.model import Z_UP_TO_WORLD, BodyModel, BodyState
from elastocap.body.track import BodyTracker
from elastocap.cameras.rig import Rig
from elastocap.capture.folder import Capture
from elastocap.hull.carve import Hull, visual_hull
from elastocap.hull.grid import Grid, space_seen_by
from elastocap.render.mesh import render_silhouette
from elastocap.silhouettes.appearance import ColourModel, appearance_silhouette
from elastocap.silhouettes.background import clean_mask
from elastocap.silhouettes.band import refine_in_band
from elastocap.silhouettes.consistency import consistent_silhouettes
from elastocap.silhouettes.gradient import filtered_gradient
from elastocap.silhouettes.learned_background import LearnedBackground, background_outline
from elastocap.silhouettes.snake import snake_silhouette

__all__ = ["SilhouetteTracker", "agreed_silhouettes", "extract_silhouettes"]

#: Snake options for silhouettes (tuned on seed 1 of the clutter scene): a soft contour
#: that follows limbs, pulled hard by the filtered edges.
SNAKE_DEFAULTS = {"alpha": 0.01, "beta": 0.02, "kappa": 10.0, "max_iterations": 150}
#: Body tracker options in the loop: the tracker's own (one-sided rays inside and outside
#: each silhouette, sigma_ray 0.1) now that a colour cut follows each contour (seed 1, 12
#: frames: median IoU 0.948 -> 0.962 against outline rays only with sigma_ray 0.3, which
#: suited the noisier contours before the cut), with left and right limbs sharing one shape
#: (``benches/README.md``, branch clutter3).
TRACKER_DEFAULTS: dict[str, Any] = {"symmetric": True}
#: Pixels: the second contour starts from the first one where it lies within this of the
#: fitted model's silhouette, and from the model's silhouette shrunk by it elsewhere.
MODEL_MARGIN = 6
#: Options of :func:`~elastocap.silhouettes.band.refine_in_band`, the colour cut after each
#: contour (tuned on seeds 0-1).
BAND_DEFAULTS: dict[str, Any] = {}

#: Options of :func:`~elastocap.silhouettes.appearance.appearance_silhouette`, the
#: correction of the final silhouettes by each view's colour model learned over frames
#: (tuned on seeds 0-1: the defaults; ``benches/README.md``, branch sil5).
APPEARANCE_DEFAULTS: dict[str, Any] = {}
#: Pixels the colour model's log ratio is smoothed over (a pixel of the subject's texture
#: alone looks like anything).
APPEARANCE_SIGMA = 1.5
#: Pixels: the subject's colours are learned inside the fitted model's silhouette grown by
#: this, so that clutter a mask holds away from the model does not teach them.
APPEARANCE_TRUST = 2
#: Pixels: the background's colours are learned only outside the fitted model's
#: silhouette grown by this. Without it a part of the subject one frame's mask lost (the
#: figure's red shoes, seed 15 views 1 and 3) lies in the colour model's background ring,
#: teaches the background's histogram the shoe's colour, and is dropped again on every
#: later frame (~650 px a view, share 0.52 -> 0.79 over frames 0-7 of seed 15 replayed
#: offline; 2 px 0.77, 6 px 0.79; tuning seeds 20, 21 unchanged: ``benches/README.md``,
#: branch sil8).
APPEARANCE_BACKGROUND_TRUST = 4

#: Options of :func:`~elastocap.silhouettes.learned_background.background_outline`, the
#: outline test against each view's learned background: a band of 5 px (the dark strip a
#: dark column behind the figure leaves along its back is 3-5 px wide). Tuned offline on
#: seeds 0 and 12 (``benches/README.md``, branch sil7).
BACKGROUND_DEFAULTS: dict[str, Any] = {"band": 5}
#: Pixels: a pixel teaches the learned background where it lies farther than this outside
#: the fitted model's silhouette. Not outside the final mask too: the fat strip to remove is
#: inside the mask on every frame (the figure walks in place, the strip never lies far
#: from it), but outside the model, which follows the figure there; the learned
#: background's own consistency test (a colour that held over 3 confirmations) keeps out
#: what moves, the figure included where the model misses it. Seeds 0 / 12, 20 frames,
#: offline: share 0.958 / 0.825 without, 0.983 / 0.875 with 2 px; 3 px 0.939 / 0.861 and
#: outside both masks by 10 px 0.924 / 0.852 (11 / 18 frames).
BACKGROUND_MARGIN = 2

#: Voxels along the longest side of the hull that locates the subject on the first frame.
AGREEMENT_RESOLUTION = 64


def agreed_silhouettes(rig: Rig, disparity_masks: Mapping[str, Any], *, tolerance: int = 0) -> dict[str, NDArray[np.bool_]]:
    """Silhouettes of what the cameras agree on: the visual hull of the cleaned disparity
    masks (``tolerance`` cameras may disagree) inside the space every
    camera sees, its largest connected part kept, projected into every camera.

    Raises
    ------
    InvalidInputError
        When the cameras agree on nothing (no voxel survives).
    """
    from scipy import ndimage

    # Holes (poor texture) and speckle of each mask cleaned first, so that every camera
    # must agree.
    masks = {name: clean_mask(np.asarray(disparity_masks[name]) != 0, open_radius=2, close_radius=4) for name in rig.names}
    blank = [name for name, mask in masks.items() if not mask.any()]
    if len(blank) > tolerance:
        raise InvalidInputError(f"the cameras' disparity masks agree on nothing: camera(s) {blank} have an empty disparity mask")
    lower, upper = space_seen_by(rig)
    # A coarse hull over the whole shared space locates the subject; a finer one around it
    # gives its outline.
    for resolution in (AGREEMENT_RESOLUTION, 2 * AGREEMENT_RESOLUTION):
        grid = Grid.around(lower, upper, resolution)
        hull = visual_hull(masks, rig, grid, tolerance=tolerance, footprint="center")
        # Only the volume every camera sees: a voxel outside some view is not carved by it.
        centres = grid.centers().reshape(-1, 3)
        seen = np.logical_and.reduce([camera.visible(centres) for camera in rig.cameras]).reshape(grid.shape)
        labels, count = ndimage.label(hull.occupancy & seen)
        if count == 0:
            raise InvalidInputError("the cameras' disparity masks agree on nothing: no subject to start from")
        sizes = ndimage.sum(hull.occupancy, labels, index=np.arange(1, count + 1))
        occupancy = labels == 1 + int(np.argmax(sizes))
        index = np.argwhere(occupancy)
        lower = grid.origin + grid.spacing * (index.min(axis=0) - 2)
        upper = grid.origin + grid.spacing * (index.max(axis=0) + 2)
    mesh = Hull(occupancy, grid).mesh()
    return {camera.name: render_silhouette(mesh, camera) for camera in rig.cameras}


class SilhouetteTracker:
    """Model-based silhouettes, frame by frame (see the module docstring).

    Parameters
    ----------
    rig : Rig
    model : BodyModel, optional, keyword-only
        Default: :meth:`BodyModel.default_human`.
    snake : dict, optional, keyword-only
        Options of :func:`~elastocap.silhouettes.snake.active_contour`.
    gradient : dict, optional, keyword-only
        Options of :func:`~elastocap.silhouettes.gradient.filtered_gradient`.
    tracker : dict, optional, keyword-only
        Options of :class:`~elastocap.body.track.BodyTracker`.
    model_margin : int, keyword-only
        See :data:`MODEL_MARGIN`: the model corrects the first contour where it strays
        (into clutter, or away from a limb) rather than replacing it, since the body model
        is not the subject's exact shape.
    band : dict or bool, keyword-only
        Options of :func:`~elastocap.silhouettes.band.refine_in_band`, which refines each
        contour by colour inside the band stereo allows; False: contours only (the
        paper's method).
    consistency : dict or bool, keyword-only
        Options of :func:`~elastocap.silhouettes.consistency.consistent_silhouettes`, the
        multi-view check of the final silhouettes; False: none.
    appearance : dict or bool, keyword-only
        Options of :func:`~elastocap.silhouettes.appearance.appearance_silhouette`: each
        view's final silhouette is corrected by that view's
        :class:`~elastocap.silhouettes.appearance.ColourModel`, learned from the previous
        frames' final silhouettes; False: none.
    background : dict or bool, keyword-only
        Options of :func:`~elastocap.silhouettes.learned_background.background_outline`:
        before the colour model, the outline of each view's silhouette loses the pixels
        that show that view's
        :class:`~elastocap.silhouettes.learned_background.LearnedBackground`, learned from
        the pixels the previous frames confirmed as background (static cameras); False:
        none.
    """

    def __init__(
        self,
        rig: Rig,
        *,
        model: BodyModel | None = None,
        snake: Mapping[str, Any] | None = None,
        gradient: Mapping[str, Any] | None = None,
        tracker: Mapping[str, Any] | None = None,
        model_margin: int = MODEL_MARGIN,
        band: Mapping[str, Any] | None | bool = True,
        consistency: Mapping[str, Any] | None | bool = True,
        appearance: Mapping[str, Any] | None | bool = True,
        background: Mapping[str, Any] | None | bool = True,
    ) -> None:
        if not isinstance(rig, Rig):
            raise InvalidInputError(f"rig must be an elastocap.Rig, got {type(rig).__name__}")
        self.rig = rig
        self.model = BodyModel.default_human() if model is None else model
        self.snake_options = {**SNAKE_DEFAULTS, **(snake or {})}
        self.gradient_options = dict(gradient or {})
        self.model_margin = int(model_margin)
        self.band_options = None if band is False else {**BAND_DEFAULTS, **(band if isinstance(band, Mapping) else {})}
        self.consistency_options = None if consistency is False or len(rig) < 3 else dict(consistency if isinstance(consistency, Mapping) else {})
        options = None if appearance is False else {**APPEARANCE_DEFAULTS, **(appearance if isinstance(appearance, Mapping) else {})}
        self.appearance_options = options
        self.colour_models = {n: ColourModel() for n in rig.names}
        self.background_options = None if background is False else {**BACKGROUND_DEFAULTS, **(background if isinstance(background, Mapping) else {})}
        self.backgrounds = {n: LearnedBackground() for n in rig.names}
        self._gains: dict[str, NDArray[np.float32]] = {}
        body_cameras = [c.replace(R=c.R @ Z_UP_TO_WORLD) for c in rig.cameras]
        self.body = BodyTracker(self.model, cameras=body_cameras, **{**TRACKER_DEFAULTS, **(tracker or {})})
        self.previous: dict[str, NDArray[np.bool_]] | None = None
        self.states: list[BodyState] = []
        self.first_pass: dict[str, NDArray[np.bool_]] = {}
        self.model_masks: dict[str, NDArray[np.bool_]] = {}
        #: Seconds spent so far in the snakes, the colour cuts, the body fit, the
        #: multi-view check, the colour models (wall) and in the snakes (CPU, ``snakes_cpu``).
        self.timings = {"snakes": 0.0, "band": 0.0, "body": 0.0, "consistency": 0.0, "appearance": 0.0, "background": 0.0, "snakes_cpu": 0.0, "other": 0.0}
        #: CPU seconds (all threads of the process) per stage, the same stages as
        #: :attr:`timings` plus the filtered gradients and the model's projection: on a
        #: shared machine wall time measures the neighbours.
        self.cpu_timings = {"gradient": 0.0, "snakes": 0.0, "band": 0.0, "body": 0.0, "projection": 0.0, "consistency": 0.0, "background": 0.0, "appearance": 0.0}

    @contextmanager
    def _clock(self, stage: str) -> Iterator[None]:
        started, cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            if stage in self.timings:
                self.timings[stage] += time.perf_counter() - started
            self.cpu_timings[stage] += time.process_time() - cpu

    def _snake(self, attraction: NDArray[np.float64], init: NDArray[np.bool_]) -> NDArray[np.bool_]:
        if not init.any() or not attraction.any():
            return init
        cpu = time.process_time()
        with self._clock("snakes"):
            mask, _ = snake_silhouette(attraction, init, **self.snake_options)
        # CPU seconds too (all threads of the process): wall time on a shared machine
        # measures the neighbours.
        self.timings["snakes_cpu"] += time.process_time() - cpu
        # A contour that collapsed is reported by the snake; the start is kept instead.
        return init if mask is None else mask

    def _refine(self, image: Any, contour: NDArray[np.bool_], disparity: Any) -> NDArray[np.bool_]:
        if self.band_options is None or not contour.any():
            return contour
        with self._clock("band"):
            mask = refine_in_band(np.asarray(image), contour, disparity, **self.band_options)
        return mask if mask.any() else contour

    def _recolour(self, name: str, image: Any, mask: NDArray[np.bool_], model: NDArray[np.bool_] | None, disparity: Any) -> NDArray[np.bool_]:
        colours = self.colour_models[name]
        if self.appearance_options is None or not colours.trained or not mask.any():
            return mask
        with self._clock("appearance"):
            ratio = colours.log_ratio(image, sigma=APPEARANCE_SIGMA)
            out = appearance_silhouette(mask, ratio, model_mask=model, disparity_mask=disparity, **self.appearance_options)
        # A frame whose colours the model does not know (a sudden change of light) would
        # lose the subject: the mask is kept instead.
        return out if out.any() else mask

    def _outside_model(self, model: NDArray[np.bool_]) -> NDArray[np.bool_]:
        import cv2

        r = BACKGROUND_MARGIN
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        return np.asarray(cv2.dilate(model.astype(np.uint8), kernel) == 0)

    def _outline(self, name: str, image: Any, mask: NDArray[np.bool_], model: NDArray[np.bool_]) -> NDArray[np.bool_]:
        learned = self.backgrounds[name]
        if self.background_options is None or learned.count is None or not model.any():
            return mask
        with self._clock("background"):
            # The light's gain of this frame is estimated where this frame's model says
            # background, as the learned background is taught: one field for both (the
            # Gaussian blurs are most of this stage's cost).
            self._gains[name] = learned.gain(image, self._outside_model(model))
            out = mask
            if mask.any():
                out = background_outline(mask, learned.distance(image, None, gain=self._gains[name]), **self.background_options)
        return out if out.any() else mask

    def _learn_background(self, images: Mapping[str, Any], projected: Mapping[str, NDArray[np.bool_]]) -> None:
        if self.background_options is None:
            return
        with self._clock("background"):
            for n, model in projected.items():
                if model.any():
                    self.backgrounds[n].update(images[n], self._outside_model(model), gain=self._gains.get(n))
        self._gains = {}

    def _learn_colours(self, images: Mapping[str, Any], final: Mapping[str, NDArray[np.bool_]], projected: Mapping[str, NDArray[np.bool_]]) -> None:
        import cv2

        if self.appearance_options is None:
            return
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * APPEARANCE_TRUST + 1, 2 * APPEARANCE_TRUST + 1))
        r = APPEARANCE_BACKGROUND_TRUST
        outer = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        for n, mask in final.items():
            model = projected[n]
            if mask.any():
                trusted = background = None
                if model.any():
                    trusted = cv2.dilate(model.astype(np.uint8), kernel)
                    background = cv2.dilate(model.astype(np.uint8), outer) == 0
                self.colour_models[n].update(images[n], mask, trusted=trusted, background_trusted=background)

    def _second_start(self, first: NDArray[np.bool_], model: NDArray[np.bool_]) -> NDArray[np.bool_]:
        import cv2

        if self.model_margin <= 0 or not model.any():
            return model
        r = self.model_margin
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        near = cv2.dilate(model.astype(np.uint8), kernel) != 0
        core = cv2.erode(model.astype(np.uint8), kernel) != 0
        return np.asarray((first & near) | core)

    def step(
        self,
        images: Mapping[str, Any],
        *,
        disparity_masks: Mapping[str, Any] | None = None,
        points: Any = None,
    ) -> dict[str, NDArray[np.bool_]]:
        """The silhouettes of the next frame.

        Parameters
        ----------
        images : mapping of camera name to (H, W, 3) uint8
        disparity_masks : mapping of camera name to (H, W) array_like, optional
            The stereo stage's binarised disparity (a camera may lack one: its gradient is
            then unfiltered). Needed on the first frame unless ``points`` locate the body.
        points : (N, 3) array_like, optional
            Stereo points of this frame, world metres.

        Returns
        -------
        dict of camera name to (H, W) bool
        """
        names = self.rig.names
        missing = [n for n in names if n not in images]
        if missing:
            raise InvalidInputError(f"images lack camera(s) {missing}")
        disparity = dict(disparity_masks or {})
        attraction = {}
        for n in names:
            near = disparity.get(n)
            if disparity and (near is None or not np.asarray(near).any()):
                # Stereo saw nothing in this view while it did in others: the unfiltered
                # gradient would pull the contour into the clutter, so this view keeps its
                # starts (previous silhouette, then the model's) without a snake.
                attraction[n] = np.zeros(np.asarray(images[n]).shape[:2])
                continue
            with self._clock("gradient"):
                attraction[n] = filtered_gradient(images[n], near, **self.gradient_options)[0]
        if self.previous is None:
            if not disparity or any(n not in disparity for n in names):
                raise InvalidInputError("the first frame needs a disparity mask for every camera: the cameras' agreement is where the subject starts")
            start = agreed_silhouettes(self.rig, disparity)
        else:
            start = self.previous
        first = {n: self._refine(images[n], self._snake(attraction[n], start[n]), disparity.get(n)) for n in names}
        world = None if points is None else np.asarray(points, dtype=np.float64).reshape(-1, 3)
        observed = BodyObservations(
            masks=[first[n] if first[n].any() else None for n in names],
            points=None if world is None or len(world) == 0 else world @ Z_UP_TO_WORLD,
        )
        with self._clock("body"):
            state = self.body.update(observed)
        self.states.append(state)
        with self._clock("projection"):
            mesh = self.model.skin_mesh(state, spacing=0.015)
            mesh.vertices = mesh.vertices @ Z_UP_TO_WORLD.T
            projected = {c.name: render_silhouette(mesh, c) for c in self.rig.cameras}
        final = {n: self._refine(images[n], self._snake(attraction[n], self._second_start(first[n], projected[n])), disparity.get(n)) for n in names}
        if self.consistency_options is not None:
            with self._clock("consistency"):
                final = consistent_silhouettes(self.rig, final, model_masks=projected, disparity_masks=disparity, **self.consistency_options)
        final = {n: self._outline(n, images[n], final[n], projected[n]) for n in names}
        final = {n: self._recolour(n, images[n], final[n], projected[n], disparity.get(n)) for n in names}
        self._learn_colours(images, final, projected)
        self._learn_background(images, projected)
        self.first_pass, self.model_masks, self.previous = first, projected, final
        return final


def extract_silhouettes(
    capture: Capture | str | Path,
    *,
    frames: Iterable[int] | None = None,
    disparity_masks: Mapping[int, Mapping[str, Any]] | None = None,
    points: Mapping[int, Any] | None = None,
    progress: bool = False,
    **options: Any,
) -> dict[int, dict[str, NDArray[np.bool_]]]:
    """Silhouettes of every frame of a capture without a background plate (SPEC 8).

    Parameters
    ----------
    capture : Capture or path
        With colour images (or videos) and a calibration.
    frames : iterable of int, optional, keyword-only
        Consecutive frames to process (default: all).
    disparity_masks : mapping of frame to (mapping of camera name to (H, W) mask), optional
        The stereo stage's binarised disparity masks; required for the first frame.
    points : mapping of frame to (N, 3) array_like, optional
        Stereo points per frame, world metres.
    progress : bool, keyword-only
    **options
        Passed to :class:`SilhouetteTracker`.

    Returns
    -------
    dict of frame to (dict of camera name to (H, W) bool)
    """
    from tqdm import tqdm

    cap = capture if isinstance(capture, Capture) else Capture.open(capture)
    if not (cap.has_images or cap._videos):
        raise InvalidInputError(f"{cap} has no images or videos: silhouettes need colour frames")
    wanted = list(cap.frames if frames is None else frames)
    tracker = SilhouetteTracker(cap.rig, **options)
    out = {}
    for frame in tqdm(wanted, desc="silhouettes", unit="frame", disable=not progress):
        images = {n: cap.image(n, frame) for n in cap.rig.names}
        out[frame] = tracker.step(
            images,
            disparity_masks=None if disparity_masks is None else disparity_masks.get(frame),
            points=None if points is None else points.get(frame),
        )
    return out
