"""``elastocap capture CAPTURE --out OUT``: every stage the capture allows, in order, then
the figures, the report and the animation files, in one command.

Stages: silhouettes (the capture's masks, its background plates or a dark background) ->
visual hulls -> tracked surface points (``tracks = true``) -> elastic fit -> body fit
(``body = true``) -> ``metrics.json``, ``report.html`` -> ``OUT/export/<take>.*``. Each stage resumes per frame, so a rerun after
an interruption redoes only what was not finished; every file is written atomically. The
options used are written to ``OUT/capture.toml``, which is also a valid ``--config``.
"""

from __future__ import annotations

import html
import json
import os
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import trimesh

from elastocap._core import InvalidInputError
from elastocap._io import save_bytes
from elastocap.capture.folder import Capture
from elastocap.elastic.fit import SequenceFit
from elastocap.pipeline.body import run_body_stage
from elastocap.pipeline.export import FrameRateWarning, export_settings, export_take
from elastocap.pipeline.export.settings import DEFAULT_FPS
from elastocap.pipeline.fit import run_fit_stage
from elastocap.pipeline.hull import run_hull_stage
from elastocap.pipeline.masks import choose_silhouettes, masked_capture, run_masks_stage
from elastocap.pipeline.options import CaptureOptions
from elastocap.pipeline.pictures import contact_sheet, mesh_over_image, save_png
from elastocap.pipeline.report import write_fit_report
from elastocap.pipeline.track import run_track_stage

__all__ = ["CaptureRun", "run_capture", "video_frame_rate"]


@dataclass
class CaptureRun:
    """What a capture run did.

    Attributes
    ----------
    out : Path
    stages : dict of str to float
        Seconds per stage in this run (stages that had nothing left to do are quick).
    exports : list of Path
    fps : float
    fps_source : str
        ``"config"``, ``"videos"`` or ``"default"``.
    """

    out: Path
    stages: dict[str, float] = field(default_factory=dict)
    exports: list[Path] = field(default_factory=list)
    fps: float = DEFAULT_FPS
    fps_source: str = "default"


def video_frame_rate(capture: Capture) -> float | None:
    """The frame rate the capture's videos state (``videos/<camera>.mp4``), or None when it
    has none or they do not state one. Cameras that disagree by more than 0.1% raise."""
    rates = []
    for name in capture.cameras:
        path = capture.root / "videos" / f"{name}.mp4"
        if not path.exists():
            return None
        video = cv2.VideoCapture(str(path))
        try:
            rate = float(video.get(cv2.CAP_PROP_FPS)) if video.isOpened() else 0.0
        finally:
            video.release()
        if not rate > 0:
            return None
        rates.append(rate)
    if max(rates) > min(rates) * 1.001:
        raise InvalidInputError(f"the videos of {capture.root} disagree on the frame rate: {sorted(set(rates))}; set fps")
    return rates[0]


def _frame_rate(capture: Capture, options: CaptureOptions) -> tuple[float, str]:
    if options.fps is not None:
        return options.fps, "config"
    rate = video_frame_rate(capture)
    if rate is not None:
        return rate, "videos"
    warnings.warn(
        f"{capture.root} states no frame rate (no videos, no fps option): using {DEFAULT_FPS:g} frames per second",
        FrameRateWarning,
        stacklevel=3,
    )
    return DEFAULT_FPS, "default"


def run_capture(
    capture: str | Path,
    out: str | Path,
    options: CaptureOptions | None = None,
    *,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
    report_figures: Callable[[SequenceFit], tuple[dict[str, Sequence[float]], dict[str, Any]]] | None = None,
) -> CaptureRun:
    """Run every stage the capture allows and write the figures, report and exports.

    Parameters
    ----------
    capture : path
        The capture folder (calibration; images/ or videos/; masks/ or background/ or a
        dark background).
    out : path
        Output folder (created); ``out/capture.toml`` records the options.
    options : CaptureOptions, optional
        Default: :class:`CaptureOptions` ().
    progress : bool
        Progress bars per stage.
    log : callable, optional
        Receives one line per stage as it starts (default: print when ``progress``).
    report_figures : callable, optional
        ``report_figures(fit) -> (series, summary)``: per-frame series added to the
        report's error plot and figures added to its table (the demo's distances to the
        ground truth).

    Returns
    -------
    CaptureRun
    """
    options = CaptureOptions() if options is None else options
    say = log if log is not None else (lambda line: print(line, flush=True)) if progress else (lambda line: None)
    if options.threads is not None:
        # Read by the Rust core's thread pool when it starts: before its first parallel call.
        os.environ["RAYON_NUM_THREADS"] = str(options.threads)
        cv2.setNumThreads(options.threads)
    root = Path(capture).resolve()
    out = Path(out)
    cap = Capture.open(root)
    if not cap.frames:
        raise InvalidInputError(f"{cap} has no frames: it needs images/, videos/ or masks/")
    method = choose_silhouettes(cap, options.silhouettes)
    fps, fps_source = _frame_rate(cap, options)
    run = CaptureRun(out=out, fps=fps, fps_source=fps_source)
    notes = {"fps": f"from the {fps_source}" if fps_source != "config" else "given"}
    written = replace(options, fps=fps)
    save_bytes(out / "capture.toml", written.to_toml(capture=root, notes=notes).encode())

    stages: list[tuple[str, Callable[[], Any]]] = []
    if method != "masks":
        stages.append((f"silhouettes ({method})", lambda: run_masks_stage(
            cap, out, method=method, dark_threshold=options.dark_threshold, progress=progress)))
    masked = {}

    def hull() -> None:
        masked["capture"] = masked_capture(cap, out, method=method)
        run_hull_stage(masked["capture"], out, resolution=options.resolution, tolerance=options.tolerance,
                       phantoms=options.phantoms, progress=progress)

    stages.append(("hull", hull))
    if options.tracks:
        stages.append(("tracks", lambda: run_track_stage(masked["capture"], out, spacing=options.track_spacing,
                                                         progress=progress)))
    stages.append(("fit", lambda: run_fit_stage(
        masked["capture"], out, rest_frame=options.rest_frame, n_nodes=options.nodes, rotation=options.rotation,
        stiffness=options.stiffness, resolution=options.resolution, progress=progress)))
    if options.body:
        stages.append(("body", lambda: run_body_stage(masked["capture"], out, progress=progress)))
    results: dict[str, Any] = {}
    for number, (name, stage) in enumerate(stages, start=1):
        say(f"elastocap capture: [{number}/{len(stages) + 2}] {name}")
        start = time.perf_counter()
        results[name] = stage()
        run.stages[name] = round(time.perf_counter() - start, 3)

    say(f"elastocap capture: [{len(stages) + 1}/{len(stages) + 2}] report")
    start = time.perf_counter()
    _hull_picture(cap, out, cap.frames[0])
    series, figures = report_figures(results["fit"]) if report_figures is not None else ({}, {})
    page = write_fit_report(out, cap, results["fit"], extra=series, summary={**_summary(results["fit"], run), **figures})
    run.stages["report"] = round(time.perf_counter() - start, 3)

    say(f"elastocap capture: [{len(stages) + 2}/{len(stages) + 2}] exports ({', '.join(options.exports)})")
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FrameRateWarning)  # the rate was settled above
        settings = export_settings(out, take=root.name, fps=fps, units=options.units, up=options.up)
    run.exports = export_take(out, options.exports, settings)
    run.stages["exports"] = round(time.perf_counter() - start, 3)
    _add_capture_section(page, run, options)
    _write_metrics(out, root, cap, run)
    cap.close()
    return run


def _summary(fit: Any, run: CaptureRun) -> dict[str, Any]:
    return {
        "frames fitted": len(fit.frames),
        "nodes": fit.model.n_nodes,
        "frames per second": run.fps,
        **{f"{stage} seconds (this run)": seconds for stage, seconds in run.stages.items()},
    }


def _hull_picture(capture: Capture, out: Path, frame: int) -> Path:
    """``hull_views.png``: the first frame's hull over up to 8 camera images."""
    surface = trimesh.load_mesh(out / "hull" / f"{frame:06d}.ply")
    names = capture.cameras[:8]
    views = [mesh_over_image(capture.image(name, frame), surface, capture.rig[name]) for name in names]
    path = out / "hull_views.png"
    save_png(path, contact_sheet(views, [f"{name}, frame {frame}" for name in names]))
    return path


_SECTION_START, _SECTION_END = "<!-- capture -->", "<!-- /capture -->"


def _add_capture_section(page: Path, run: CaptureRun, options: CaptureOptions) -> None:
    """The run's stage times, options and exported files, and the body picture when the
    body was fitted, added to the report (replacing a previous run's)."""
    text = page.read_text()
    if _SECTION_START in text:
        text = text[: text.index(_SECTION_START)] + text[text.index(_SECTION_END) + len(_SECTION_END):]
    times = "".join(f"<tr><td>{html.escape(k)}</td><td>{v:.1f} s</td></tr>" for k, v in run.stages.items())
    files = "".join(
        f'<li><a href="{html.escape(str(p.relative_to(run.out)))}">{html.escape(str(p.relative_to(run.out)))}</a></li>'
        for p in run.exports
    )
    body = '<h2>Body model fitted to the silhouettes</h2><img src="body_views.png">' if options.body else ""
    section = (
        f"{_SECTION_START}\n<h2>This run</h2><table>{times}</table>\n"
        f"<p>{run.fps:g} frames per second ({html.escape(run.fps_source)}); options in "
        '<a href="capture.toml">capture.toml</a>; figures in <a href="metrics.json">metrics.json</a>.</p>\n'
        f"{body}<h2>Animation files (metres, +Y up)</h2><ul>{files}</ul>\n{_SECTION_END}\n"
    )
    save_bytes(page, text.replace("</body></html>", section + "</body></html>").encode())


def _write_metrics(out: Path, root: Path, capture: Capture, run: CaptureRun) -> None:
    """``metrics.json``: the fit stage's figures plus the capture, stage times and exports."""
    path = out / "metrics.json"
    metrics = json.loads(path.read_text()) if path.exists() else {}
    metrics["capture"] = {
        "path": str(root),
        "cameras": len(capture.cameras),
        "frames": len(capture.frames),
        "fps": run.fps,
        "fps_source": run.fps_source,
    }
    metrics["stages_seconds_this_run"] = run.stages
    metrics["exports"] = [str(p.relative_to(out)) for p in run.exports]
    save_bytes(path, (json.dumps(metrics, indent=2) + "\n").encode())
