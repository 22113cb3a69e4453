"""Models that reach a worker process (Dask, a process pool) pickle: the core objects they
hold do not, so the models rebuild them from what they were built from."""

from __future__ import annotations

import pickle
import multiprocessing
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import trimesh

from elastocap import BodyModel, ElasticModel


def _forces(model: ElasticModel, positions: np.ndarray) -> np.ndarray:
    return model.forces(positions)


def _model() -> ElasticModel:
    return ElasticModel.from_mesh(trimesh.creation.capsule(height=1.0, radius=0.3), n_nodes=300, poisson=0.35, k=16)


def test_elastic_model_round_trips_with_its_options_and_forces() -> None:
    model = _model()
    copy = pickle.loads(pickle.dumps(model))
    assert (copy.k, copy.poisson, copy.rotation, copy.rotation_fit) == (16, 0.35, model.rotation, model.rotation_fit)
    np.testing.assert_array_equal(copy.nodes, model.nodes)
    np.testing.assert_array_equal(copy.neighbors, model.neighbors)
    np.testing.assert_array_equal(copy.surface_faces, model.surface_faces)
    moved = model.nodes + 0.01 * np.random.default_rng(0).standard_normal(model.nodes.shape)
    np.testing.assert_array_equal(copy.forces(moved), model.forces(moved))


def test_elastic_model_computes_in_a_worker_process() -> None:
    model = _model()
    moved = model.nodes * 1.02
    # "spawn", as Dask's worker processes: a forked child inherits the rayon pool's locks
    # without its threads and can hang in the first parallel call.
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        remote = pool.submit(_forces, model, moved).result(timeout=120)
    np.testing.assert_array_equal(remote, model.forces(moved))


def test_body_model_round_trips() -> None:
    model = BodyModel.default_human()
    copy = pickle.loads(pickle.dumps(model))
    assert copy.to_dict() == model.to_dict()
    state = model.rest_state()
    points = np.random.default_rng(1).uniform(-0.5, 0.5, (200, 3))
    for ours, theirs in zip(copy.field(points, state), model.field(points, state)):
        np.testing.assert_array_equal(ours, theirs)
