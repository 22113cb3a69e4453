"""The pictures and the static HTML page of a fitted sequence: fitted meshes over camera
images, a strip of the sequence, per-frame error and volume plots, ``OUT/report.html``.

Plots are drawn with OpenCV (already a dependency) rather than matplotlib.
"""

from __future__ import annotations

import html
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._io import save_bytes
from elastocap.capture.folder import Capture
from elastocap.elastic.fit import SequenceFit
from elastocap.pipeline.pictures import contact_sheet, mesh_over_image, save_png

__all__ = ["line_plot", "write_fit_report"]

_COLOURS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40)]


def line_plot(
    x: Sequence[float],
    series: Mapping[str, Sequence[float]],
    *,
    title: str,
    y_label: str,
    size: tuple[int, int] = (640, 300),
) -> NDArray[np.uint8]:
    """``(H, W, 3)`` RGB: one line per named series against ``x``, axes with min/max ticks."""
    width, height = size
    image = np.full((height, width, 3), 255, np.uint8)
    left, right, top, bottom = 70, 20, 30, 40
    xs = np.asarray(x, dtype=np.float64)
    values = np.concatenate([np.asarray(v, dtype=np.float64) for v in series.values()])
    lo, hi = float(np.nanmin(values)), float(np.nanmax(values))
    if hi - lo < 1e-12:
        lo, hi = lo - 0.5 * max(abs(lo), 1e-3), hi + 0.5 * max(abs(hi), 1e-3)
    x_lo, x_hi = float(xs.min()), float(xs.max()) if xs.max() > xs.min() else float(xs.min()) + 1

    def to_pixel(u: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.int32]:
        pu = left + (u - x_lo) / (x_hi - x_lo) * (width - left - right)
        pv = height - bottom - (v - lo) / (hi - lo) * (height - top - bottom)
        return np.stack([pu, pv], axis=1).round().astype(np.int32)

    cv2.rectangle(image, (left, top), (width - right, height - bottom), (0, 0, 0), 1)
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(image, title, (left, 20), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(image, f"{hi:.4g}", (4, top + 5), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(image, f"{lo:.4g}", (4, height - bottom), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(image, y_label, (4, height // 2), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(image, f"frame {x_lo:.0f}", (left, height - 15), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(image, f"{x_hi:.0f}", (width - right - 25, height - 15), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    for index, (name, v) in enumerate(series.items()):
        colour = _COLOURS[index % len(_COLOURS)]
        points = to_pixel(xs, np.asarray(v, dtype=np.float64))
        cv2.polylines(image, [points.reshape(-1, 1, 2)], False, colour, 2, cv2.LINE_AA)
        cv2.putText(image, name, (left + 10 + 180 * index, top + 18), font, 0.45, colour, 1, cv2.LINE_AA)
    return image


def write_fit_report(
    out: Path,
    capture: Capture,
    fit: SequenceFit,
    *,
    extra: dict[str, Sequence[float]] | None = None,
    summary: dict[str, Any] | None = None,
) -> Path:
    """Write ``fit_views.png``, ``fit_strip.png``, ``fit_plots.png`` and ``report.html`` into
    ``out``; returns the page. ``extra`` adds per-frame series to the error plot (e.g. the
    distance to a ground truth), ``summary`` figures to the page's table."""
    fitted = fit.frames
    cameras = capture.cameras
    picks = [fitted[round(i * (len(fitted) - 1) / 3)] for i in range(4)] if len(fitted) >= 4 else fitted
    views, labels = [], []
    for frame in picks:
        surface = fit.surface(frame)
        for name in (cameras[0], cameras[len(cameras) // 2]):
            views.append(mesh_over_image(capture.image(name, frame), surface, capture.rig[name]))
            labels.append(f"{name}, frame {frame}")
    save_png(out / "fit_views.png", contact_sheet(views, labels, columns=4))
    strip_frames = fitted[:: max(1, len(fitted) // 8)][:8]
    name = cameras[0]
    strip = [mesh_over_image(capture.image(name, f), fit.surface(f), capture.rig[name]) for f in strip_frames]
    save_png(out / "fit_strip.png", contact_sheet(strip, [f"frame {f}" for f in strip_frames], columns=8, width=200))
    x = list(fitted)
    errors = {"mean |d| to hull (mm)": [1000 * fit.fits[i].metrics.get("mean_distance", np.nan) for i in fitted]}
    for key, values in (extra or {}).items():
        errors[key] = list(values)
    error_plot = line_plot(x, errors, title="surface error per frame", y_label="mm")
    volume_plot = line_plot(
        x,
        {"volume / rest volume": [fit.fits[i].metrics.get("volume_ratio", np.nan) for i in fitted]},
        title="volume per frame",
        y_label="ratio",
    )
    plots = [error_plot, volume_plot]
    iou_plot, warning = _reprojection(out, x)
    if iou_plot is not None:
        plots.append(iou_plot)
    save_png(out / "fit_plots.png", np.concatenate(plots, axis=0))
    rows = "".join(
        f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(f'{v:.4g}' if isinstance(v, float) else str(v))}</td></tr>"
        for k, v in (summary or {}).items()
    )
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>elastocap fit</title>
<style>body{{font-family:sans-serif;max-width:1300px;margin:2em auto}} img{{max-width:100%}}
td{{padding:2px 12px}}</style></head><body>
<h1>elastocap: elastic model fitted through {len(fitted)} frames</h1>
<table>{rows}</table>
{warning}
<h2>Fitted surfaces over the camera images</h2><img src="fit_views.png">
<h2>The sequence from {html.escape(name)}</h2><img src="fit_strip.png">
<h2>Error, volume and reprojection IoU per frame</h2><img src="fit_plots.png">
<h2>Visual hull of the first frame</h2><img src="hull_views.png">
</body></html>
"""
    path = out / "report.html"
    save_bytes(path, page.encode())
    return path


def _reprojection(out: Path, frames: list[int]) -> tuple[NDArray[np.uint8] | None, str]:
    """The plot of the worst camera's reprojection IoU per frame and the page's warning
    naming the frames where a camera's core IoU drops, from ``out/metrics.json`` (the fit
    stage's); ``(None, "")`` without those figures."""
    path = out / "metrics.json"
    if not path.exists():
        return None, ""
    metrics = json.loads(path.read_text())
    rows = {row["frame"]: row for row in metrics.get("frames", []) if "reprojection_core_iou" in row}
    if not rows or not all(f in rows for f in frames):
        return None, ""
    series = {
        f"{label}, worst camera": [min(rows[f][key].values()) for f in frames]
        for label, key in (("IoU", "reprojection_iou"), ("core IoU", "reprojection_core_iou"))
    }
    plot = line_plot(frames, series, title="fitted silhouette vs. masks (no ground truth needed)", y_label="IoU")
    drops = metrics.get("summary", {}).get("iou_drops", {})
    if not drops:
        return plot, "<p>Reprojection: every camera's core IoU is above its floor in every frame.</p>"
    listed = "; ".join(f"frame {html.escape(frame)}: {html.escape(', '.join(names))}" for frame, names in drops.items())
    warning = (
        '<p style="color:#b00"><b>Warning:</b> the fitted silhouette drops away from the masks in '
        f"{len(drops)} frame(s), a limb lost most likely (core reprojection IoU below its floor): {listed}</p>"
    )
    return plot, warning


_BODY_START, _BODY_END = "<!-- body -->", "<!-- /body -->"


def add_body_section(page: Path, metrics: dict[str, Any]) -> Path:
    """Add (or replace) the body fit's section of ``page``: the fitted skin over the camera
    views (``metrics["picture"]``, relative to the page) and its joint-angle errors
    against the capture's body truth."""
    text = page.read_text()
    if _BODY_START in text:
        text = text[: text.index(_BODY_START)] + text[text.index(_BODY_END) + len(_BODY_END) :]
    rows = "".join(
        f"<tr><td>{html.escape(k)}</td><td>{html.escape(str(metrics[k]))}</td></tr>"
        for k in ("joint_angle_rms_deg", "leg_joint_angle_rms_deg", "explained", "seconds_this_run")
        if k in metrics
    )
    section = (
        f"{_BODY_START}\n<h2>Body model fitted to a body-model capture (silhouettes only)</h2>"
        f"<table>{rows}</table><img src=\"{html.escape(metrics['picture'])}\">\n"
        "<p>Joint angles against ground_truth/body.json. The legs are found to a few "
        "degrees; the arms (shoulder twist, arms against the torso) are not determined by "
        "six silhouettes of 320x240 pixels.</p>\n"
        f"{_BODY_END}\n"
    )
    text = text.replace("</body></html>", section + "</body></html>")
    save_bytes(page, text.encode())
    return page


def write_take_index(out: Path, takes: Mapping[str, Mapping[str, Any]]) -> Path:
    """``out/index.html``: one row per take of a batch (its status, the reason it failed,
    its time, a link to its ``report.html`` and its sequence strip), so a batch of many
    takes is looked at from one page. ``takes``: ``OUT/batch.json``'s ``takes``."""
    rows = []
    for take, record in sorted(takes.items()):
        folder = out / take
        status = str(record.get("status", "not run"))
        link = html.escape(take)
        if (folder / "report.html").is_file():
            link = f'<a href="{html.escape(take)}/report.html">{link}</a>'
        strip = f'<img src="{html.escape(take)}/fit_strip.png">' if (folder / "fit_strip.png").is_file() else ""
        seconds = record.get("seconds")
        rows.append(
            f"<tr class={html.escape(status)}><td>{link}</td><td>{html.escape(status)}</td>"
            f"<td>{'' if seconds is None else f'{seconds:.1f} s'}</td>"
            f"<td>{html.escape(str(record.get('reason', '')))}</td><td>{strip}</td></tr>"
        )
    failed = sum(1 for record in takes.values() if record.get("status") == "failed")
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>elastocap batch</title>
<style>body{{font-family:sans-serif;max-width:1500px;margin:2em auto}} img{{max-width:800px}}
td{{padding:2px 12px;vertical-align:top}} tr.failed td{{color:#b00}}</style></head><body>
<h1>elastocap batch: {len(takes)} take(s), {failed} failed</h1>
<p>Details per take in <a href="batch.json">batch.json</a>.</p>
<table><tr><th>take</th><th>status</th><th>time</th><th>reason</th><th>sequence</th></tr>
{''.join(rows)}
</table></body></html>
"""
    path = out / "index.html"
    save_bytes(path, page.encode())
    return path
