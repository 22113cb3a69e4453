"""The synthetic figure of :mod:`elastocap.synth.capture`: a smooth union of capsules on a small
human skeleton, in procedural motion (public as ``elastocap.synth.CapsuleFigure``).

World frame: metres, **y up**, the floor at ``y = 0``; at yaw 0 the figure faces +z with
its left side on +x.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray
from skimage import measure

from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_float_array, as_positive
from elastocap.synth.fast_motion import fast_joint_angles
from elastocap.synth.skeleton import CONTACT_DEPTH, MOTIONS, PARTS, Capsules, draw_parameters, parameter_names, pose

__all__ = ["CONTACT_DEPTH", "FIGURE_FORMAT", "MOTIONS", "PARTS", "Capsules", "CapsuleFigure"]

FIGURE_FORMAT = "elastocap.synth.figure/1"

# Clothing colours (RGB in [0, 1]) by part: shirt, skin, trousers, shoes.
_SHIRT, _SKIN, _TROUSERS, _SHOES = (0.20, 0.42, 0.78), (0.87, 0.66, 0.52), (0.38, 0.35, 0.33), (0.62, 0.18, 0.14)
_PART_COLOURS = np.array(
    [_TROUSERS, _SHIRT, _SHIRT, _SKIN, _SKIN,
     _SHIRT, _SKIN, _SKIN, _SHIRT, _SKIN, _SKIN,
     _TROUSERS, _TROUSERS, _SHOES, _TROUSERS, _TROUSERS, _SHOES]
)
# The surface pattern: a product of sines of this period (metres) in each part's own frame,
# so that it moves with the body (texture for stereo matching and tracking) ...
_PATTERN_PERIOD = 0.07
# ... darkening the clothing colour by up to this fraction.
_PATTERN_CONTRAST = 0.4

class CapsuleFigure:
    """An articulated figure: a smooth union of capsules on a skeleton, in procedural motion.

    Parameters
    ----------
    seed : int, default 0
        Non-negative. Draws the proportions (lengths and girths within a few percent of a 1.71 m adult),
        the swing amplitudes, the starting phase and direction of the turn, and the
        surface pattern. The same seed gives the same figure, bit for bit.
    motion : {"walk", "fast"}, default "walk", keyword-only
        ``"walk"``: walking in place with large arm and leg swings, turning, clapping once
        per cycle (below). ``"fast"``: standing, one arm swinging through a large arc
        across the chest and one leg kicking, the hand and foot moving 10 to 35 cm per
        frame (:mod:`elastocap.synth.fast_motion`).
    parameters : mapping of str to float, optional
        All parameters explicitly (as :meth:`to_dict` writes them), instead of drawing them
        from ``seed``; used to rebuild a figure from ``figure.json``.

    Attributes
    ----------
    seed : int
    motion : str
    parameters : mapping of str to float
        Read-only: lengths and radii in metres, angles in degrees, times in frames.

    Notes
    -----
    World frame: metres, **y up**, the floor at ``y = 0``, the figure turning about the y
    axis through the origin; at yaw 0 it faces +z with its left side on +x.

    Skeleton: pelvis, abdomen and chest (three capsules), neck, head, and per side an upper
    arm, forearm and hand, a thigh, shin and foot: 17 capsules (:data:`PARTS`). The surface
    is the zero level of the left fold ``f = smin(... smin(d_1, d_2) ..., d_S)`` of the
    capsule distances ``d_i = |p - segment_i| - r_i`` with the quadratic polynomial smooth
    minimum ``smin(a, b) = min(a, b) - k h^2 / 4``, ``h = max(k - |a - b|, 0) / k`` (blend
    radius ``k = parameters["blend"]``, a few centimetres). ``smin`` has partial
    derivatives in [0, 1] summing to 1, so ``f`` is 1-Lipschitz like a distance: sphere
    tracing on it is safe and ``f`` is negative exactly inside.

    Motion (frame ``n``, walk phase ``s = 2 pi (n + phase_frames) / cycle_frames``): hips
    swing ``+-hip_swing`` with the knee bending up to ``knee_max`` in the swing phase; the
    arms swing against the legs from ``arm_back`` behind to ``arm_forward`` in front (over
    100 degrees), elbows bending more the further forward; the whole body turns by
    ``yaw_per_frame``. Around ``s = pi`` (for ``clap_hold`` frames either side, blended in
    and out over ``clap_ramp`` frames) both arms leave the swing for a clap in front of
    the chest whose inward angle is solved so that the hands overlap by
    :data:`CONTACT_DEPTH`.
    """

    def __init__(self, seed: int = 0, *, motion: str = "walk", parameters: Mapping[str, float] | None = None) -> None:
        self.seed = as_count("seed", seed, minimum=0)
        if motion not in MOTIONS:
            raise InvalidInputError(f"motion must be one of {MOTIONS}, got {motion!r}")
        self.motion = motion
        if parameters is None:
            parameters = draw_parameters(self.seed, motion)
        else:
            expected, given = set(parameter_names(motion)), set(parameters)
            if given != expected:
                raise InvalidInputError(
                    f"parameters: missing {sorted(expected - given)}, unknown {sorted(given - expected)}"
                )
            parameters = {key: float(value) for key, value in parameters.items()}
            bad = sorted(key for key, value in parameters.items() if not math.isfinite(value))
            if bad:
                raise InvalidInputError(f"parameters must be finite numbers; not: {bad}")
        self.parameters: Mapping[str, float] = MappingProxyType(dict(parameters))
        self._pattern_phases = _pattern_phases(self.seed)

    # -- serialisation --------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """Everything needed to rebuild the figure (:meth:`from_dict`), JSON-ready.

        Returns
        -------
        dict
            ``format``, ``seed``, ``motion``, ``up_axis`` ("y"), ``units`` ("metres"), ``parts`` (in
            blending order), ``parameters`` (lengths in metres, angles in degrees,
            durations in frames), and the capsules of frame 0 for a quick look.
        """
        capsules = self.capsules(0)
        return {
            "format": FIGURE_FORMAT,
            "seed": self.seed,
            "motion": self.motion,
            "up_axis": "y",
            "units": "metres",
            "parts": list(PARTS),
            "parameters": dict(self.parameters),
            "frame_0": {
                name: {"start": a.tolist(), "end": b.tolist(), "radius": float(r)}
                for name, a, b, r in zip(capsules.names, capsules.starts, capsules.ends, capsules.radii)
            },
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> CapsuleFigure:
        """The figure :meth:`to_dict` (or ``ground_truth/figure.json``) describes."""
        if data.get("format") != FIGURE_FORMAT:
            raise InvalidInputError(f"not a figure description: format {data.get('format')!r}, expected {FIGURE_FORMAT!r}")
        # Descriptions written before the fast motion existed are walks.
        return cls(int(data["seed"]), motion=str(data.get("motion", "walk")), parameters=data["parameters"])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CapsuleFigure):
            return NotImplemented
        return (self.seed == other.seed and self.motion == other.motion
                and dict(self.parameters) == dict(other.parameters))

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        motion = "" if self.motion == "walk" else f", motion={self.motion!r}"
        return f"CapsuleFigure(seed={self.seed}{motion}, height={self.parameters['scale'] * 1.71:.3f} m)"

    # -- pose -----------------------------------------------------------------------------

    def yaw(self, frame: int) -> float:
        """The body's turn about the world y axis at ``frame``, radians."""
        p = self.parameters
        return math.radians(p["yaw_start"] + p["yaw_per_frame"] * _frame(frame))

    def joint_angles(self, frame: int) -> dict[str, float]:
        """The joint angles at ``frame``, degrees (keys ``<joint>_<l|r>``: ``arm_flex``
        forward, ``arm_abduction`` outward, ``arm_inward`` horizontal adduction,
        ``elbow``, ``hip_flex`` forward, ``knee``; the fast motion also ``hip_inward``,
        horizontal adduction), and ``clap`` (the blend weight of the clap, 0 to 1)."""
        p = self.parameters
        n = _frame(frame)
        if self.motion == "fast":
            return fast_joint_angles(p, n)
        cycle = p["cycle_frames"]
        s = 2 * math.pi * (n + p["phase_frames"]) / cycle
        sin_s, cos_s = math.sin(s), math.cos(s)
        forward, back = p["arm_forward"], p["arm_back"]
        middle, half = (forward - back) / 2, (forward + back) / 2
        # Frames to the nearest clap (at s = pi), signed.
        to_clap = (n + p["phase_frames"] - cycle / 2) % cycle
        to_clap = min(to_clap, cycle - to_clap)
        clap = 1.0 - _smoothstep(p["clap_hold"], p["clap_hold"] + p["clap_ramp"], to_clap)
        angles: dict[str, float] = {"clap": clap}
        for side, sign in (("l", -1.0), ("r", 1.0)):
            flex = middle + sign * half * sin_s
            elbow = p["elbow_min"] + (p["elbow_max"] - p["elbow_min"]) * (flex + back) / (forward + back)
            walk = (flex, p["arm_abduction"], 0.0, elbow)
            pose = (p["clap_flex"], p["clap_abduction"], p["clap_inward"], p["clap_elbow"])
            for key, w, c in zip(("arm_flex", "arm_abduction", "arm_inward", "elbow"), walk, pose):
                angles[f"{key}_{side}"] = (1 - clap) * w + clap * c
            angles[f"hip_flex_{side}"] = -sign * p["hip_swing"] * sin_s
            swing = max(0.0, -sign * cos_s) ** 2
            angles[f"knee_{side}"] = p["knee_min"] + (p["knee_max"] - p["knee_min"]) * swing
        return angles

    def capsules(self, frame: int) -> Capsules:
        """The capsules at ``frame``, world coordinates (see :class:`Capsules`)."""
        return pose(self.parameters, self.joint_angles(frame), self.yaw(frame))

    # -- the surface ----------------------------------------------------------------------

    def part_distances(self, points: Any, frame: int) -> NDArray[np.float64]:
        """Signed distance to each capsule, before blending.

        Parameters
        ----------
        points : (N, 3) array_like of float
            World coordinates, metres.
        frame : int
            Frame number (any integer; the motion is defined for all).

        Returns
        -------
        (N, S) float64
            ``|p - segment_i| - r_i``, metres, negative inside capsule ``i``; columns in
            :data:`PARTS` order.
        """
        X = _points("points", points)
        c = self.capsules(frame)
        return np.stack(
            [_capsule_distance(X, a, b, r) for a, b, r in zip(c.starts, c.ends, c.radii)], axis=1
        )

    def sdf(self, points: Any, frame: int) -> NDArray[np.float64]:
        """The figure's signed distance (smooth union of the capsules).

        Parameters
        ----------
        points : (N, 3) array_like of float
            World coordinates, metres.
        frame : int
            Frame number.

        Returns
        -------
        (N,) float64
            Metres, negative inside; exact distance away from the blends, a 1-Lipschitz
            lower bound of it within ``blend`` of two parts (see Notes of :class:`CapsuleFigure`).
        """
        X = _points("points", points)
        c = self.capsules(frame)
        k = self.parameters["blend"]
        result = np.empty(len(X))
        for lo in range(0, len(X), _CHUNK):
            chunk = X[lo : lo + _CHUNK]
            field = _capsule_distance(chunk, c.starts[0], c.ends[0], c.radii[0])
            for a, b, r in zip(c.starts[1:], c.ends[1:], c.radii[1:]):
                field = _smin(field, _capsule_distance(chunk, a, b, r), k)
            result[lo : lo + _CHUNK] = field
        return result

    def mesh(self, frame: int, spacing: float = 0.01) -> trimesh.Trimesh:
        """The figure's surface at ``frame``: marching cubes of :meth:`sdf`.

        Parameters
        ----------
        frame : int
            Frame number.
        spacing : float, default 0.01
            Voxel edge of the sampling grid, metres. The grid is aligned to multiples of
            ``spacing`` in world coordinates, so every frame samples the same lattice.

        Returns
        -------
        trimesh.Trimesh
            Watertight, outward normals, vertices in world coordinates (metres), vertex
            normals from the field's gradient and vertex colours (clothing, with a pattern
            fixed to each body part). About 55 k faces at 1 cm, 14 k at 2 cm.

        Notes
        -----
        Each capsule's distance is evaluated only in its box, within ``4 blend + 2
        spacing`` of it, and the field starts at ``3 blend + 2 spacing`` (a narrow band):
        ~10x less work than every capsule on the whole grid. Where the result is within a
        voxel of zero it agrees with :meth:`sdf` to better than 1e-7 m (measured), and its
        sign agrees everywhere.
        """
        spacing = as_positive("spacing", spacing)
        c = self.capsules(frame)
        k = self.parameters["blend"]
        band = 3 * k + 2 * spacing
        corners = np.concatenate([c.starts, c.ends])
        radii = np.concatenate([c.radii, c.radii])[:, None]
        lower = np.floor(((corners - radii).min(axis=0) - k - 2 * spacing) / spacing) * spacing
        upper = (corners + radii).max(axis=0) + k + 2 * spacing
        shape = tuple(int(n) for n in np.ceil((upper - lower) / spacing).astype(int) + 1)
        field = np.full(shape, band)
        axes = [lower[i] + spacing * np.arange(shape[i]) for i in range(3)]
        for a, b, r in zip(c.starts, c.ends, c.radii):
            reach = r + band + k
            lo = np.clip(np.floor((np.minimum(a, b) - reach - lower) / spacing).astype(int), 0, shape)
            hi = np.clip(np.ceil((np.maximum(a, b) + reach - lower) / spacing).astype(int) + 1, 0, shape)
            box = tuple(slice(lo[i], hi[i]) for i in range(3))
            x = axes[0][box[0], None, None] - a[0]
            y = axes[1][None, box[1], None] - a[1]
            z = axes[2][None, None, box[2]] - a[2]
            axis = b - a
            h = np.clip((x * axis[0] + y * axis[1] + z * axis[2]) / max(float(axis @ axis), 1e-300), 0.0, 1.0)
            distance = np.sqrt((x - h * axis[0]) ** 2 + (y - h * axis[1]) ** 2 + (z - h * axis[2]) ** 2) - r
            field[box] = _smin(field[box], distance, k)
        # "descent": the inside has the lower values, so faces wind outward; the normals
        # skimage returns point down the gradient, into the figure, hence the minus sign.
        vertices, faces, normals, _ = measure.marching_cubes(
            field, level=0.0, spacing=(spacing,) * 3, gradient_direction="descent"
        )
        vertices = vertices.astype(np.float64) + lower
        colours = self.surface_colours(vertices, frame)
        return trimesh.Trimesh(
            vertices=vertices,
            faces=faces.astype(np.int64),
            vertex_normals=-normals.astype(np.float64),
            vertex_colors=np.column_stack([colours, np.full(len(colours), 255, np.uint8)]),
            process=False,
        )

    def surface_colours(self, points: Any, frame: int) -> NDArray[np.uint8]:
        """The figure's colour at surface points: the nearest part's clothing colour
        modulated by a smooth pattern fixed to that part.

        Parameters
        ----------
        points : (N, 3) array_like of float
            World coordinates on (or near) the surface, metres.
        frame : int
            Frame number.

        Returns
        -------
        (N, 3) uint8
            RGB.
        """
        X = _points("points", points)
        c = self.capsules(frame)
        part = np.argmin(self.part_distances(X, frame), axis=1)
        # Coordinates in the part's own frame, so the pattern moves with the body.
        local = np.einsum("nji,nj->ni", c.frames[part], X - c.starts[part])
        phase = self._pattern_phases[part]
        wave = np.prod(np.sin(2 * np.pi * local / _PATTERN_PERIOD + phase), axis=1)
        shade = 1.0 - _PATTERN_CONTRAST * (0.5 + 0.5 * wave)
        colour = _PART_COLOURS[part] * shade[:, None]
        return np.clip(np.rint(255 * colour), 0, 255).astype(np.uint8)


# How many points CapsuleFigure.sdf folds at once (bounds the temporaries to a few MB).
_CHUNK = 1 << 16


def _pattern_phases(seed: int) -> NDArray[np.float64]:
    return np.random.default_rng([seed, 0x7E7]).uniform(0, 2 * np.pi, (len(PARTS), 3))


def _smoothstep(edge0: float, edge1: float, x: float) -> float:
    t = min(max((x - edge0) / (edge1 - edge0), 0.0), 1.0)
    return t * t * (3 - 2 * t)


def _smin(a: NDArray[np.float64], b: NDArray[np.float64], k: float) -> NDArray[np.float64]:
    """Quadratic polynomial smooth minimum with blend radius ``k``."""
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.minimum(a, b) - h * h * (0.25 * k)


def _capsule_distance(
    points: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64], r: float
) -> NDArray[np.float64]:
    pa = points - a
    axis = b - a
    h = np.clip(pa @ axis / max(float(axis @ axis), 1e-300), 0.0, 1.0)
    return np.linalg.norm(pa - h[:, None] * axis, axis=1) - r


def _frame(frame: Any) -> int:
    if isinstance(frame, (bool, np.bool_)) or not isinstance(frame, (int, np.integer)):
        raise InvalidInputError(f"frame must be an integer frame number, got {frame!r}")
    return int(frame)


def _points(name: str, value: Any) -> NDArray[np.float64]:
    points = as_float_array(name, value)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InvalidInputError(f"{name} must have shape (N, 3), got {points.shape}")
    return points
