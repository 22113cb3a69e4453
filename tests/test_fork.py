"""A process forked after the core has run can run it again (``rust/python/pool.rs``).

rayon's global pool cannot be rebuilt, and a child forked after its first use (the default
start method of :mod:`multiprocessing` on Linux) holds the pool's bookkeeping but none of
its threads: its first parallel call would wait forever. The bindings run the core on a
pool per process, so the child builds its own.
"""

from __future__ import annotations

import multiprocessing
import sys

import numpy as np
import pytest
import scipy.sparse

from elastocap import _core

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="fork is POSIX")


def _kernels(seed: int) -> tuple[float, float, float]:
    """Three parallel kernels: neighbour search, polar decomposition and a sparse
    Cholesky solve (faer on rayon). Deterministic for a seed."""
    rng = np.random.default_rng(seed)
    points = rng.random((20_000, 3))
    _, distances = _core.SpatialIndex(points).knn(8, points)
    rotations, _ = _core.polar_rotation(rng.random((20_000, 3, 3)) + np.eye(3))
    n = 60
    line = scipy.sparse.diags([-1.0, 2.5, -1.0], [-1, 0, 1], shape=(n, n))
    # A grid Laplacian per coordinate, as the elastic systems' 3x3 blocks.
    system = scipy.sparse.csr_matrix(scipy.sparse.kron(scipy.sparse.kronsum(line, line), np.eye(3)))
    factor = _core.SparseCholesky(3 * n * n, system.indptr, system.indices, system.data, 3)
    solution = factor.solve(rng.random(3 * n * n))
    return float(distances.sum()), float(np.abs(rotations).sum()), float(solution.sum())


def test_a_child_forked_after_the_parent_used_the_core_runs_it() -> None:
    expected = [_kernels(seed) for seed in (1, 2)]  # the parent's pool is up and used
    with multiprocessing.get_context("fork").Pool(2) as workers:
        # A hung child fails the test at the timeout; leaving the block terminates it.
        found = workers.map_async(_kernels, [1, 2]).get(timeout=120)
    assert found == expected


def test_a_grandchild_forked_from_a_forked_child_runs_it() -> None:
    _kernels(0)
    context = multiprocessing.get_context("fork")

    def nested(queue: multiprocessing.Queue) -> None:
        _kernels(3)  # the child's own pool, then a fork of the child
        with context.Pool(1) as workers:
            queue.put(workers.map_async(_kernels, [4]).get(timeout=120))

    queue = context.Queue()
    child = context.Process(target=nested, args=(queue,))
    child.start()
    try:
        assert queue.get(timeout=180) == [_kernels(4)]
    finally:
        child.join(timeout=10)
        if child.is_alive():
            child.terminate()
