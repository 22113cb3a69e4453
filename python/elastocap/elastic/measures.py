"""How far a fitted surface is from a known true surface: the figures the tests, the demo
and ``benches/eval_horse.py`` all quote (issue 17, item 7).

The **lost-limb measure** of a frame is the 99th percentile of the point-to-surface
distances pooled in both directions: every fitted vertex to the true surface, and every
true vertex to the fitted surface. The first direction sees a limb that went astray (its
vertices are far from any true surface); the second sees a limb that collapsed onto the
torso or stayed behind inside the body (the true limb's vertices are far from any fitted
surface), which a one-sided measure misses. A limb is lost when the measure exceeds
:data:`LOST_LIMB_FRACTION` of the true surface's bounding-box diagonal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.geometry._distance import distance_to_mesh

__all__ = ["LOST_LIMB_FRACTION", "LOST_LIMB_PERCENTILE", "SurfaceError", "lost_limb", "surface_error"]

# The percentile of the pooled distances: a limb is a few percent of a body's surface (a
# forearm and hand about 3% of the capsule figure's, a horse's lower leg about 2%), so
# the 99th percentile rises when one limb is off while a uniform error of the whole
# surface leaves it near the mean.
LOST_LIMB_PERCENTILE = 99.0
# Issue 17: a limb counts as lost when the measure reaches 5% of the true bounding-box
# diagonal (9-10 cm on the 1.9 m capsule figure, about a limb's width).
LOST_LIMB_FRACTION = 0.05


@dataclass(frozen=True)
class SurfaceError:
    """A fitted surface against the true one; distances in world units.

    Attributes
    ----------
    lost_limb : float
        The 99th percentile of the pooled distances (the lost-limb measure).
    lost_limb_fraction : float
        ``lost_limb`` over the true surface's bounding-box diagonal.
    mean, p95 : float
        Mean and 95th percentile of the pooled distances.
    fitted_to_truth, truth_to_fitted : float
        The mean of each direction alone.
    diagonal : float
        The true surface's bounding-box diagonal.
    """

    lost_limb: float
    lost_limb_fraction: float
    mean: float
    p95: float
    fitted_to_truth: float
    truth_to_fitted: float
    diagonal: float

    @property
    def limb_lost(self) -> bool:
        """Whether the measure reaches :data:`LOST_LIMB_FRACTION` of the diagonal."""
        return self.lost_limb_fraction >= LOST_LIMB_FRACTION


def _vertices(name: str, mesh: trimesh.Trimesh, max_points: int | None, rng: np.random.Generator) -> NDArray[np.float64]:
    if not isinstance(mesh, trimesh.Trimesh):
        raise InvalidInputError(f"{name} must be a trimesh.Trimesh, got {type(mesh).__name__}")
    if len(mesh.faces) == 0:
        raise InvalidInputError(f"{name} has no faces")
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    if not np.isfinite(vertices).all():
        raise InvalidInputError(f"{name} has non-finite vertices")
    used = np.unique(np.asarray(mesh.faces).ravel())
    vertices = vertices[used]
    if max_points is not None and len(vertices) > max_points:
        vertices = vertices[np.sort(rng.choice(len(vertices), max_points, replace=False))]
    return vertices


def surface_error(
    fitted: trimesh.Trimesh, truth: trimesh.Trimesh, *, max_points: int | None = None, seed: int = 0
) -> SurfaceError:
    """The distances between a fitted surface and the true one, pooled both ways.

    Parameters
    ----------
    fitted, truth : trimesh.Trimesh
        World coordinates. Only vertices used by a face count.
    max_points : int, optional, keyword-only
        Use at most this many vertices of each surface (a random subset drawn from
        ``seed``), for speed on dense meshes; default all.
    seed : int, default 0, keyword-only
        The subset's seed.

    Returns
    -------
    SurfaceError

    Notes
    -----
    Each distance is the exact point-to-triangle distance to the nearest of the other
    surface's triangles (:func:`elastocap.geometry._distance.distance_to_mesh`).
    """
    if max_points is not None and (not isinstance(max_points, (int, np.integer)) or max_points < 100):
        raise InvalidInputError(f"max_points must be an integer >= 100, got {max_points!r}")
    rng = np.random.default_rng(seed)
    a = _vertices("fitted", fitted, max_points, rng)
    b = _vertices("truth", truth, max_points, rng)
    there, back = distance_to_mesh(a, truth), distance_to_mesh(b, fitted)
    both = np.concatenate([there, back])
    lower, upper = np.asarray(truth.bounds)
    diagonal = float(np.linalg.norm(upper - lower))
    p99 = float(np.percentile(both, LOST_LIMB_PERCENTILE))
    return SurfaceError(
        lost_limb=p99,
        lost_limb_fraction=p99 / diagonal,
        mean=float(both.mean()),
        p95=float(np.percentile(both, 95.0)),
        fitted_to_truth=float(there.mean()),
        truth_to_fitted=float(back.mean()),
        diagonal=diagonal,
    )


def lost_limb(fitted: trimesh.Trimesh, truth: trimesh.Trimesh, *, max_points: int | None = None) -> float:
    """The lost-limb measure of a frame (world units): the 99th percentile of the distances
    of ``fitted``'s vertices to ``truth`` and of ``truth``'s vertices to ``fitted``, pooled.
    See :func:`surface_error` for the parameters."""
    return surface_error(fitted, truth, max_points=max_points).lost_limb
