"""Peak memory of ``elastocap capture`` against the take's length: it must not grow with the
number of frames (every stage reads, processes and writes a frame at a time).

Writes one synthetic capture of the longest length asked for, makes takes of its first N
frames (links, no copies), runs ``elastocap capture`` on each in a fresh process and reads
that process's peak resident memory (``wait4``'s ``ru_maxrss``). Prints one JSON line per
length, then the least-squares growth per frame and the peak extrapolated to
``--extrapolate`` frames.

    python benches/memory_long_take.py                           # 8 x 800x800, 128^3, 2,500 nodes
    python benches/memory_long_take.py --frames 20,40,80 --size 320 --resolution 64 --nodes 800
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from elastocap.synth.capture import write_synthetic_capture


def take_of_first_frames(capture: Path, take: Path, frames: int) -> Path:
    """A capture folder of the first ``frames`` frames of ``capture``, by symbolic links."""
    take.mkdir(parents=True, exist_ok=True)
    for name in ("intri.yml", "extri.yml", "background"):
        link = take / name
        if not link.exists():
            link.symlink_to((capture / name).resolve())
    for folder in ("images", "masks"):
        for camera in sorted((capture / folder).iterdir()):
            target = take / folder / camera.name
            target.mkdir(parents=True, exist_ok=True)
            for file in sorted(camera.iterdir())[:frames]:
                if not (target / file.name).exists():
                    (target / file.name).symlink_to(file.resolve())
    return take


def peak_rss(command: list[str]) -> tuple[float, float]:
    """Run ``command``; its peak resident memory (MB) and wall time (s)."""
    start = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(process.pid, 0)
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed with status {process.returncode}")
    return usage.ru_maxrss / 1024.0, time.perf_counter() - start  # Linux: kilobytes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", default="50,100,200", help="take lengths (default: 50,100,200)")
    parser.add_argument("--cameras", type=int, default=8)
    parser.add_argument("--size", type=int, default=800, help="image width and height (default: 800)")
    parser.add_argument("--resolution", type=int, default=128, help="hull voxels along the longest side")
    parser.add_argument("--nodes", type=int, default=2500)
    parser.add_argument("--extrapolate", type=int, default=1000, help="frames to extrapolate the peak to")
    parser.add_argument("--work", default="memory-bench", help="folder for the capture and outputs")
    args = parser.parse_args()
    lengths = sorted(int(n) for n in args.frames.split(","))
    work = Path(args.work)
    started = time.perf_counter()
    capture = write_synthetic_capture(
        work / "capture", frames=lengths[-1], cameras=args.cameras, image_size=(args.size, args.size), progress=True
    )
    print(json.dumps({"case": "synth", "frames": lengths[-1], "seconds": round(time.perf_counter() - started, 1)}), flush=True)
    rows = []
    for frames in lengths:
        take = take_of_first_frames(capture, work / f"take_{frames}", frames)
        command = [
            sys.executable, "-m", "elastocap.pipeline.cli", "capture", str(take), "--out", str(work / f"out_{frames}"),
            "--resolution", str(args.resolution), "--nodes", str(args.nodes), "--fps", "25", "--exports", "glb,pc2",
            "--quiet",
        ]
        rss, seconds = peak_rss(command)
        rows.append((frames, rss))
        print(json.dumps({
            "case": "capture", "frames": frames, "cameras": args.cameras, "size": args.size, "resolution": args.resolution,
            "nodes": args.nodes, "peak_rss_mb": round(rss, 1), "seconds": round(seconds, 1),
        }), flush=True)
    x, y = np.array(rows, dtype=float).T
    slope, intercept = np.polyfit(x, y, 1) if len(rows) > 1 else (0.0, y[0])
    print(json.dumps({
        "case": "growth", "mb_per_frame": round(float(slope), 4), "intercept_mb": round(float(intercept), 1),
        "frames": args.extrapolate, "peak_rss_mb_extrapolated": round(float(intercept + slope * args.extrapolate), 1),
    }), flush=True)


if __name__ == "__main__":
    main()
