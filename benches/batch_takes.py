"""``elastocap batch`` on a LocalCluster against a serial run: same geometry, the bad take
isolated, and the scheduler's own time per task.

Writes synthetic takes (one with a corrupt mask), runs ``elastocap batch`` twice in fresh
processes (``--workers W --threads T`` and ``--serial``), compares every geometry output
(masks, hulls, model, fitted positions, exports) byte for byte, and measures the cluster's
round trip of no-op tasks. Prints JSON lines.

    python benches/batch_takes.py                       # 4 takes (1 bad), 2 workers x 1 thread
    python benches/batch_takes.py --takes 8 --frames 10 --size 640 --resolution 96 --nodes 1500
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from elastocap.synth.capture import write_synthetic_capture

TIMINGS = {"seconds", "solver_seconds"}


def geometry(out: Path) -> dict[str, bytes]:
    files = {}
    for path in sorted(out.rglob("*")):
        relative = path.relative_to(out).as_posix()
        if not path.is_file() or relative.split("/")[0] not in ("hull", "fit", "model", "masks", "export"):
            continue
        if path.suffix == ".npz":
            with np.load(path) as data:
                for key in data.files:
                    # Per-frame figures other than positions are parallel sums: last bits vary.
                    if not relative.startswith("fit/") or key == "positions":
                        files[f"{relative}:{key}"] = data[key].tobytes()
        else:
            files[relative] = path.read_bytes()
    return files


def no_op_round_trip(workers: int, tasks: int) -> float:
    """Median seconds per no-op task through a LocalCluster (submit to result)."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, Client(cluster) as client:
        client.submit(int, 0).result()
        times = []
        for batch in range(5):
            start = time.perf_counter()
            client.gather(client.map(int, range(batch * tasks, (batch + 1) * tasks), pure=False))
            times.append((time.perf_counter() - start) / tasks)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--takes", type=int, default=4)
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--cameras", type=int, default=6)
    parser.add_argument("--size", type=int, default=320)
    parser.add_argument("--resolution", type=int, default=48)
    parser.add_argument("--nodes", type=int, default=500)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--work", default="batch-bench")
    args = parser.parse_args()
    work = Path(args.work)
    names = [f"take{i}" for i in range(args.takes)]
    for seed, name in enumerate(names):
        write_synthetic_capture(work / "takes" / name, frames=args.frames, cameras=args.cameras,
                                image_size=(args.size, args.size * 3 // 4), seed=seed, progress=False)
    bad = work / "takes" / names[-1] / "masks" / "cam01" / "000001.png"
    bad.write_bytes(bad.read_bytes()[:20])
    common = ["--resolution", str(args.resolution), "--nodes", str(args.nodes), "--fps", "25", "--quiet"]
    runs = {}
    for label, extra in (("cluster", ["--workers", str(args.workers), "--threads", str(args.threads)]), ("serial", ["--serial"])):
        out = work / label
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "elastocap.pipeline.cli", "batch", str(work / "takes"), "--out", str(out), *common, *extra],
                       check=False, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        record = json.loads((out / "batch.json").read_text())
        runs[label] = record
        print(json.dumps({"case": f"batch {label}", "wall_s": round(time.perf_counter() - start, 1), **record["summary"]}), flush=True)
    cluster = runs["cluster"]["takes"]
    good = [n for n in names if cluster[n]["status"] == "done"]
    identical = all(geometry(work / "cluster" / n) == geometry(work / "serial" / n) for n in good)
    print(json.dumps({
        "case": "identical to serial", "takes": good, "identical": identical,
        "failed": {n: cluster[n]["reason"] for n in names if cluster[n]["status"] == "failed"},
        "take_seconds": {n: cluster[n]["seconds"] for n in good},
        "scheduler_seconds": {n: cluster[n]["scheduler_seconds"] for n in names if "scheduler_seconds" in cluster[n]},
        "threads_per_worker": sorted({cluster[n].get("threads") for n in good}),
    }), flush=True)
    print(json.dumps({"case": "no-op task round trip", "workers": args.workers,
                      "seconds_per_task": round(no_op_round_trip(args.workers, 200), 5)}), flush=True)


if __name__ == "__main__":
    main()
