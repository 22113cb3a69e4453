"""``elastocap batch TAKES_DIR --out OUT``: many takes through ``elastocap capture`` on a Dask
cluster, a take per task.

A take is a folder of ``TAKES_DIR`` (at any depth) holding a calibration (``intri.yml``,
``rig.json`` or a ``*_par.txt``); its output goes to ``OUT/<same relative path>/``. Tasks
receive paths and a dictionary of options and return a dictionary: no extension object
crosses a process boundary, so nothing from the Rust core needs pickling. A take that
fails is recorded with its reason in ``OUT/batch.json`` and the others go on; the record is
rewritten (atomically) as each take ends, so a killed batch keeps what was done, and a
rerun skips the takes done with the same options (a take stopped halfway resumes per frame).

The cluster is a ``distributed.LocalCluster`` of worker processes by default, or any
scheduler's address (``--scheduler tcp://host:8786``), e.g. one started on SLURM with
``dask-jobqueue``. Each worker runs one take at a time with the Rust core's thread pool
pinned to ``threads`` threads (``RAYON_NUM_THREADS``, also OpenCV's and BLAS's), so that
workers x threads does not oversubscribe the cores.

On SLURM (``pip install dask-jobqueue``), start the scheduler and its workers in one
Python session and hand its address to the batch; each job is one worker process, one take
at a time, with the take's threads pinned through the job's environment::

    from dask_jobqueue import SLURMCluster
    cluster = SLURMCluster(cores=8, processes=1, memory="16GB", walltime="04:00:00",
                           job_script_prologue=["export RAYON_NUM_THREADS=8"])
    cluster.scale(jobs=20)
    print(cluster.scheduler_address)   # then: elastocap batch TAKES --out OUT
                                       #   --scheduler tcp://... --threads 8

(``PBSCluster``, ``SGECluster``, ``LSFCluster`` work the same way.) The takes and ``OUT``
must be on a file system the workers share: tasks pass paths.
"""

from __future__ import annotations

import importlib
import json
import logging
import os
import time
import traceback
import warnings
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from elastocap._core import ElastocapError, InvalidInputError
from elastocap._io import save_bytes
from elastocap.pipeline.capture import run_capture
from elastocap.pipeline.options import CaptureOptions
from elastocap.pipeline.report import write_take_index

__all__ = ["BatchResult", "find_takes", "run_batch", "run_take"]

_CALIBRATIONS = ("intri.yml", "rig.json")
# Thread pools a take's libraries start, all pinned to the worker's share of the cores.
_THREAD_VARIABLES = ("RAYON_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _is_take(folder: Path) -> bool:
    return any((folder / name).is_file() for name in _CALIBRATIONS) or any(folder.glob("*_par.txt"))


def find_takes(takes_dir: str | Path) -> list[str]:
    """The takes under ``takes_dir``: relative paths (POSIX) of the folders holding a
    calibration, sorted; a take's own subfolders are not searched.

    Raises
    ------
    FileNotFoundError
        ``takes_dir`` is not a folder.
    """
    root = Path(takes_dir)
    if not root.is_dir():
        raise FileNotFoundError(f"takes folder not found: {root}")
    found: list[str] = []

    def walk(folder: Path) -> Iterator[Path]:
        for child in sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith(".")):
            if _is_take(child):
                yield child
            else:
                yield from walk(child)

    found = [take.relative_to(root).as_posix() for take in walk(root)]
    if _is_take(root):
        found.insert(0, ".")
    return found


def run_take(capture: str, out: str, options: dict[str, Any]) -> dict[str, Any]:
    """One take through :func:`run_capture`: the task a worker runs.

    Takes and returns plain data (paths as strings, the options as a dictionary, a
    dictionary of figures), so it pickles without the extension module. Never raises: a
    failure is returned as ``{"status": "failed", "reason": ...}``.
    """
    start = time.time()
    record: dict[str, Any] = {"worker": f"{os.uname().nodename}:{os.getpid()}", "started": start}
    try:
        values: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in options.items()}
        capture_options = CaptureOptions(**values)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            run = run_capture(capture, out, capture_options, progress=False)
        record.update(status="done", fps=run.fps, stages=run.stages, exports=[str(p.relative_to(run.out)) for p in run.exports])
        if caught:
            record["warnings"] = sorted({f"{w.category.__name__}: {w.message}" for w in caught})
    except Exception as error:  # a take's failure is its own: record it and let the others go on
        record.update(status="failed", reason=f"{type(error).__name__}: {error}")
        if not isinstance(error, (ElastocapError, OSError)):
            record["traceback"] = traceback.format_exc(limit=-8)
    record["threads"] = os.environ.get("RAYON_NUM_THREADS")
    record["finished"] = time.time()
    record["seconds"] = round(record["finished"] - start, 3)
    return record


@dataclass
class BatchResult:
    """What a batch run did: the record written to ``OUT/batch.json``.

    Attributes
    ----------
    takes : dict of str to dict
        Per take (relative path): ``status`` ("done" or "failed"), ``reason`` (failed),
        ``seconds`` (in the task), ``scheduler_seconds`` (dispatch and return around the
        task), ``worker``, ``options``.
    summary : dict
        Counts (done, failed, skipped this run), wall time, cluster.
    """

    takes: dict[str, dict[str, Any]] = field(default_factory=dict)
    summary: dict[str, Any] = field(default_factory=dict)


def _load_record(path: Path) -> dict[str, dict[str, Any]]:
    if not path.exists():
        return {}
    try:
        return dict(json.loads(path.read_text()).get("takes", {}))
    except (ValueError, AttributeError):
        return {}


def _same_options(stored: Any, wanted: dict[str, Any]) -> bool:
    """Whether a take done with ``stored`` options is done for ``wanted`` (threads change
    the speed, not the result)."""
    if not isinstance(stored, dict):
        return False
    return {k: v for k, v in stored.items() if k != "threads"} == {k: v for k, v in wanted.items() if k != "threads"}


def _cluster_threads(workers: int | None, threads: int | None) -> tuple[int, int]:
    cores = os.cpu_count() or 1
    workers = max(1, cores // (threads or 2)) if workers is None else workers
    threads = max(1, cores // workers) if threads is None else threads
    if workers < 1 or threads < 1:
        raise InvalidInputError(f"workers and threads must be at least 1, got {workers} and {threads}")
    return workers, threads


def run_batch(
    takes_dir: str | Path,
    out: str | Path,
    options: CaptureOptions | None = None,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    threads: int | None = None,
    serial: bool = False,
    progress: bool = True,
) -> BatchResult:
    """Run every take of ``takes_dir`` and write ``out/batch.json``.

    Parameters
    ----------
    takes_dir : path
        The folder of takes (see :func:`find_takes`).
    out : path
        The output folder: ``out/<take>/`` per take, ``out/batch.json``.
    options : CaptureOptions, optional
        For every take (``threads`` is set from ``threads`` below).
    scheduler : str, optional
        Address of a running Dask scheduler; default: a ``LocalCluster`` of ``workers``
        processes.
    workers : int, optional
        Worker processes of the local cluster (default: cores / 2, at least 1).
    threads : int, optional
        Threads of each take's Rust core, OpenCV and BLAS (default: cores / workers).
    serial : bool
        Run the takes one after the other in this process, without Dask.
    progress : bool
        A progress bar over the takes.
    """
    options = CaptureOptions() if options is None else options
    out = Path(out)
    takes = find_takes(takes_dir)
    if not takes:
        raise InvalidInputError(f"no take in {takes_dir}: a take is a folder with intri.yml/extri.yml, rig.json or *_par.txt")
    record_path = out / "batch.json"
    record = _load_record(record_path)
    workers, threads = _cluster_threads(1 if serial else workers, threads)
    take_options = asdict(options) | {"threads": threads}
    # JSON round trip: the comparison with a stored record sees lists, not tuples.
    take_options = json.loads(json.dumps(take_options))
    todo = [t for t in takes if not (record.get(t, {}).get("status") == "done" and (out / t / "metrics.json").exists()
                                     and _same_options(record[t].get("options"), take_options))]
    result = BatchResult(takes={t: record[t] for t in takes if t in record})
    started = time.time()
    cluster_name = "serial" if serial else scheduler or f"LocalCluster({workers} processes x {threads} threads)"

    def finish(take: str, outcome: dict[str, Any]) -> None:
        outcome["options"] = take_options
        result.takes[take] = outcome
        _save(record_path, result, takes, todo, started, cluster_name)

    bar = tqdm(total=len(takes), initial=len(takes) - len(todo), desc="batch", unit="take", disable=not progress)
    if serial:
        for take in todo:
            outcome = run_take(str(Path(takes_dir) / take), str(out / take), take_options)
            outcome["scheduler_seconds"] = 0.0
            finish(take, outcome)
            bar.update(1)
    elif todo:
        _on_cluster(takes_dir, out, todo, take_options, scheduler, workers, threads, finish, bar.update)
    bar.close()
    _save(record_path, result, takes, todo, started, cluster_name)
    return result


def _on_cluster(
    takes_dir: str | Path,
    out: Path,
    todo: list[str],
    options: dict[str, Any],
    scheduler: str | None,
    workers: int,
    threads: int,
    finish: Callable[[str, dict[str, Any]], None],
    tick: Callable[[int], Any],
) -> None:
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise InvalidInputError("elastocap batch needs Dask: pip install 'elastocap[batch]'") from None
    cluster = None
    if scheduler is None:
        env = {name: str(threads) for name in _THREAD_VARIABLES}
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None, env=env,
                               silence_logs=logging.ERROR)
    try:
        with Client(cluster if cluster is not None else scheduler) as client:
            # Workers import the stages once before the clock starts, so that the figure
            # below is the scheduler's time, not a cold import's.
            client.run(importlib.import_module, __name__)
            submitted: dict[Any, tuple[str, float]] = {}
            for take in todo:
                future = client.submit(run_take, str(Path(takes_dir) / take), str(out / take), options,
                                       key=f"take-{take}", pure=False)
                submitted[future] = (take, time.time())
            free_at: dict[str, float] = {}
            for future in as_completed(list(submitted)):
                take, submit_time = submitted[future]
                received = time.time()
                try:
                    outcome = future.result()
                except Exception as error:  # the worker died (killed, out of memory) under this take
                    outcome = {"status": "failed", "reason": f"{type(error).__name__}: {error}"}
                else:
                    # The scheduler's own time: from the later of submission and the worker
                    # becoming free to the task starting, plus from its end to the result
                    # being here (one machine's clock for a local cluster).
                    ready = max(submit_time, free_at.get(outcome["worker"], 0.0))
                    outcome["scheduler_seconds"] = round(max(outcome["started"] - ready, 0.0) + (received - outcome["finished"]), 4)
                    free_at[outcome["worker"]] = outcome["finished"]
                finish(take, outcome)
                tick(1)
    finally:
        if cluster is not None:
            cluster.close()


def _save(path: Path, result: BatchResult, takes: list[str], todo: list[str], started: float, cluster: str) -> None:
    done = [t for t in takes if result.takes.get(t, {}).get("status") == "done"]
    failed = [t for t in takes if result.takes.get(t, {}).get("status") == "failed"]
    ran = [t for t in todo if t in result.takes and result.takes[t].get("finished", 0) >= started]
    overheads = [result.takes[t]["scheduler_seconds"] for t in ran if "scheduler_seconds" in result.takes[t]]
    result.summary = {
        "takes": len(takes),
        "done": len(done),
        "failed": failed,
        "skipped_this_run": len(takes) - len(todo),
        "ran_this_run": len(ran),
        "wall_seconds_this_run": round(time.time() - started, 3),
        "scheduler_seconds_per_task_median": sorted(overheads)[len(overheads) // 2] if overheads else None,
        "cluster": cluster,
    }
    save_bytes(path, (json.dumps({"summary": result.summary, "takes": result.takes}, indent=2) + "\n").encode())
    write_take_index(path.parent, result.takes)
