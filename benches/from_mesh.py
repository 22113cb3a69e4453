"""Where the time of ``ElasticModel.from_mesh`` goes, stage by stage, as JSON lines.

The mesh is the synthetic figure's skin at rest (19,396 vertices, 38,788 triangles: a closed
human-shaped mesh of a captured hull's size). (The horse gallop's meshes have 19 open edges:
``from_mesh`` rejects them.) Each stage is timed ``--repeats`` times (default 7) and
its median printed: ``{"case", "stage", "seconds", "cpu_seconds", ...}``. ``cpu_seconds`` is
the process's CPU time over all threads: on a busy machine it shows the work when the wall
clock shows the queue. With ``RAYON_NUM_THREADS=1`` it is the whole work on one core (rayon's
idle workers spin, which counts as CPU time when there are several).

Run: ``python benches/from_mesh.py [--nodes 2465]``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import trimesh

from elastocap.elastic import nodes as _nodes
from elastocap.elastic.model import ElasticModel, _density_volumes
from elastocap.geometry.mesh_distance import TriangleMesh


def _mesh() -> trimesh.Trimesh:
    from elastocap.synth import CapsuleFigure

    return CapsuleFigure(0).mesh(0, spacing=0.012)


def _timed(fn: Callable[[], Any], repeats: int) -> tuple[float, float, Any]:
    walls, cpus, result = [], [], None
    for _ in range(repeats):
        wall, cpu = time.perf_counter(), time.process_time()
        result = fn()
        cpus.append(time.process_time() - cpu)
        walls.append(time.perf_counter() - wall)
    return statistics.median(walls), statistics.median(cpus), result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nodes", type=int, default=2465)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    mesh = _mesh()
    case = f"from_mesh_figure_{len(mesh.vertices)}v_{args.nodes}n"
    ElasticModel.from_mesh(mesh, n_nodes=args.nodes)  # warm up: thread pools, caches

    def emit(stage: str, wall: float, cpu: float, **extra: Any) -> None:
        print(json.dumps({"case": case, "stage": stage, "seconds": round(wall, 5), "cpu_seconds": round(cpu, 5), **extra}))

    # A fresh copy each time: trimesh caches volume and area on the object, a new mesh (a
    # hull's surface) has none.
    wall, cpu, model = _timed(lambda: ElasticModel.from_mesh(mesh.copy(), n_nodes=args.nodes), args.repeats)
    emit("total", wall, cpu, n_nodes=model.n_nodes, n_surface=len(model.surface_nodes),
         volume_error=round(float(model.volumes.sum() / abs(mesh.volume) - 1), 6))
    # The same steps one by one.
    emit("mesh copy (part of the total above)", *_timed(lambda: mesh.copy(), args.repeats)[:2])
    emit("index (BVH, pseudo-normals, closedness)", *_timed(lambda: TriangleMesh(mesh), args.repeats)[:2])
    wall, cpu, (_, index) = _timed(lambda: _nodes.check_mesh(mesh.copy()), args.repeats)
    emit("check_mesh (the index and the checks)", wall, cpu)
    rounds: list[float] = []
    h, exponent = _nodes._first_spacing(index.volume, index.area, args.nodes)

    def counting(h: float) -> _nodes.NodeSet:
        rounds.append(h)
        return _nodes._sample_mesh_at(index, mesh, h, np.random.default_rng(0))

    wall, cpu, found = _timed(lambda: (rounds.clear(), _nodes._search_spacing(counting, h, args.nodes, exponent))[1], args.repeats)
    emit("node placement (all rounds)", wall, cpu, rounds=len(rounds), spacing=round(found.spacing, 5))
    emit("one round at the final spacing", *_timed(lambda: _nodes._sample_mesh_at(index, mesh, found.spacing, np.random.default_rng(0)), args.repeats)[:2])
    emit("nodal volumes (k = 20 density)", *_timed(lambda: _density_volumes(found.nodes, 20, abs(mesh.volume)), args.repeats)[:2])
    volumes = _density_volumes(found.nodes, 20, abs(mesh.volume))
    emit("core model build", *_timed(lambda: ElasticModel(found.nodes, volumes, surface_nodes=np.arange(found.n_surface), surface_faces=found.faces), args.repeats)[:2])


if __name__ == "__main__":
    main()
