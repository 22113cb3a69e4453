"""Side-by-side timings of elastocap against the peer a user would pick instead.

Each case runs the same input through elastocap and through the peer in one process,
alternating, several times, and prints one JSON line:
``{"case", "n", "ours_s", "peer", "peer_s", "ratio", "repeats"}`` where the times are
medians and ``ratio = peer_s / ours_s`` (above 1: elastocap is faster).

Run: ``python benches/peers.py`` (all cases) or ``python benches/peers.py knn`` (cases whose
name contains ``knn``). ``--repeats R`` sets the number of alternating rounds (default 7).
The cases live in ``benches/peer_cases/``, a module per stage.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from typing import Any

from peer_cases.body import body_cases
from peer_cases.elastic import elastic_memory_cases, fit_cases, horse_cases, solve_cases
from peer_cases.geometry import mesh_distance_cases, polar_cases, sdf_cases
from peer_cases.hull import carve_cases, memory_cases
from peer_cases.neighbors import knn_cases, radius_cases
from peer_cases.render import render_cases
from peer_cases.silhouettes import snake_cases
from peer_cases.stereo import dense_cases, disparity_cases, lsm_cases
from peer_cases.tracking import track_cases

# Group name -> cases; ``python benches/peers.py NAME`` runs the groups whose name contains NAME.
CASES: dict[str, Callable[[int], list[dict[str, Any]]]] = {
    "knn": knn_cases,
    "radius": radius_cases,
    "polar": polar_cases,
    "sdf": sdf_cases,
    "carve": carve_cases,
    "memory": memory_cases,
    "solve": solve_cases,
    "body": body_cases,
    "fit": fit_cases,
    "elastic_memory": elastic_memory_cases,
    "horse": horse_cases,
    "mesh_distance": mesh_distance_cases,
    "disparity": disparity_cases,
    "snake": snake_cases,
    "lsm": lsm_cases,
    "dense": dense_cases,
    "track": track_cases,
    "render": render_cases,
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("filter", nargs="?", default="", help="run only case groups whose name contains this")
    parser.add_argument("--repeats", type=int, default=7, help="alternating rounds per case (median reported)")
    args = parser.parse_args()
    for name, run in CASES.items():
        if args.filter in name:
            for row in run(args.repeats):
                print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
