"""The articulated metaball body model (SPEC 6): :class:`BodyModel` and :class:`BodyState`.

The description is a readable dictionary (saved as JSON)::

    {"format": "elastocap body model 1", "name": "...",
     "parts": [{"name": "pelvis", "parent": null, "offset": [x, y, z],
                "rest": [[3x3 rotation]],           # optional, default identity
                "joints": [{"axis": [ax, ay, az], "limits": [lower_deg, upper_deg]}, ...],
                "balls": [{"center": [cx, cy, cz], "radii": [lx, ly, lz]}, ...]}, ...]}

Parents come before their children. A part's frame is its parent's frame moved to
``offset`` (in the parent's frame, scaled by the parent's coefficients ``(w, d, l)``),
turned by ``rest``, then by each joint in turn about its axis (given in the frame after the
previous joints): SPEC 6's chain of single-DoF joints ``D = Rot_z(theta) D_ini``. Balls are
axis-aligned ellipsoids in their part's frame; a part's length coefficient ``l`` scales
their z (centre and radius), its width coefficient ``w`` their x and its depth coefficient
``d`` their y (SPEC 6 has one width for x and y; apart, an elliptic section can become
round), and its taper ``tau`` each ball's x and y by ``1 + (tau - 1) k`` with ``k`` the
ball's place along the part (:attr:`BodyModel.taper_weight`: a cylinder from a tapered
limb, a thinner neck under a bigger head).

The state layout is defined once, in ``rust/body/skeleton.rs``: ``shape`` holds ``(l, w, d, tau)`` per part,
``motion`` the root translation (3, metres), the root angles ``(alpha, beta, gamma)`` of
``Rot_z Rot_y Rot_x`` (radians) and the joint angles (radians) in part order.
"""

from __future__ import annotations

import warnings

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray
from skimage import measure

import elastocap._core as _core
from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_float_array, as_points, as_positive
from elastocap.body.human import default_human_description
from elastocap.cameras.camera import Camera

__all__ = ["SHAPE_NAMES", "SKIN_LEVEL", "Z_UP_TO_WORLD", "BodyModel", "BodyState"]

#: The shape coefficients of each part, in state order: length scales the part's z (along
#: the bone), width its x, depth its y, taper the section of each ball by its place along
#: the part. All 1 for the part as described.
SHAPE_NAMES = ("length", "width", "depth", "taper")

#: The skin is the level set ``F = SKIN_LEVEL`` of the field (SPEC 6: T = 0.5).
SKIN_LEVEL = 0.5
FORMAT = "elastocap body model 1"

# The body model is z-up (its heading is the free root angle alpha, not the Euler-limited
# beta); captures are y-up (DESIGN: the synthetic floor is y = 0). This rotation maps body
# coordinates to a y-up world: ``world = Z_UP_TO_WORLD @ body``.
Z_UP_TO_WORLD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]).T
# Root translation is unbounded in practice; root angles are free but beta stays away from
# the Euler singularity at +-90 degrees.
_ROOT_LIMITS = [(-1e3, 1e3)] * 3 + [(-4 * np.pi, 4 * np.pi), (-1.45, 1.45), (-4 * np.pi, 4 * np.pi)]


@dataclass(frozen=True)
class BodyState:
    """One frame's state of a body model.

    Attributes
    ----------
    shape : (4 P,) float64
        ``(length, width, depth, taper)`` coefficients per part (:data:`SHAPE_NAMES`), 1 = as described.
    motion : (6 + A,) float64
        Root translation (metres), root angles z-y-x (radians), joint angles (radians).
    """

    shape: NDArray[np.float64]
    motion: NDArray[np.float64]

    def replace(self, *, shape: Any = None, motion: Any = None) -> BodyState:
        """A copy with ``shape`` and/or ``motion`` replaced."""
        return BodyState(
            self.shape if shape is None else as_float_array("shape", shape),
            self.motion if motion is None else as_float_array("motion", motion),
        )


def _bad(message: str) -> InvalidInputError:
    return InvalidInputError(f"body model description: {message}")


def _vector(value: Any, where: str, length: int) -> list[float]:
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise _bad(f"{where} must be {length} numbers, got {value!r}") from None
    if array.shape != (length,) or not np.isfinite(array).all():
        raise _bad(f"{where} must be {length} finite numbers, got {value!r}")
    return [float(v) for v in array]


class BodyModel:
    """A skeleton of body parts joined by chains of 1-DoF revolute joints, carrying
    ellipsoidal metaballs whose summed field ``F = sum exp(-2 d_i)`` defines the skin
    ``F = 0.5`` (SPEC 6).

    Build one with :meth:`default_human`, :meth:`load` (JSON) or :meth:`from_dict`.

    Attributes
    ----------
    part_names : list of str
    n_motion : int
        Motion parameters per frame (6 root + one per joint).
    n_shape : int
        Shape parameters (4 per part: :data:`SHAPE_NAMES`).
    lower, upper : (n_motion,) float64
        Motion limits (joint limits in radians; the root is effectively free).

    Notes
    -----
    Plänkers and Fua (papers 002 and 003): soft objects (metaballs) attached to an
    articulated skeleton, shape (limb lengths and widths) shared over frames.
    """

    def __init__(self, description: dict[str, Any]) -> None:
        self._description = _normalise(description)
        parts = self._description["parts"]
        index = {p["name"]: i for i, p in enumerate(parts)}
        parent = np.array([-1 if p["parent"] is None else index[p["parent"]] for p in parts], dtype=np.int64)
        offset = np.array([p["offset"] for p in parts], dtype=float).reshape(-1, 3)
        rest = np.array([p["rest"] for p in parts], dtype=float).reshape(-1, 3, 3)
        axes = np.array([j["axis"] for p in parts for j in p["joints"]], dtype=float).reshape(-1, 3)
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
        counts = np.array([len(p["joints"]) for p in parts], dtype=np.int64)
        balls = [(i, b) for i, p in enumerate(parts) for b in p["balls"]]
        self._balls = (
            np.array([i for i, _ in balls], dtype=np.int64),
            np.array([b["center"] for _, b in balls], dtype=float).reshape(-1, 3),
            np.array([b["radii"] for _, b in balls], dtype=float).reshape(-1, 3),
        )
        self._core = _core.BodySkeleton(
            parent,
            np.ascontiguousarray(offset),
            np.ascontiguousarray(rest),
            np.ascontiguousarray(axes),
            counts,
            *self._balls,
        )
        self.part_names: list[str] = [p["name"] for p in parts]
        #: Parent part of each part (-1 for the root), ``(P,) int64``.
        self.parent = parent
        self.parent.setflags(write=False)
        #: Part of each metaball, ``(M,) int64``.
        self.ball_part = self._balls[0].copy()
        self.ball_part.setflags(write=False)
        self.n_motion: int = self._core.n_motion
        self.n_shape: int = self._core.n_shape
        #: Per metaball ``(M,)``: its centre's height along its part relative to the part's
        #: balls (mean 0, spanning 1); the part's taper ``tau`` scales its x and y by
        #: ``1 + (tau - 1) k``.
        self.taper_weight = self._core.taper_weight
        self.taper_weight.setflags(write=False)
        limits = _ROOT_LIMITS + [np.radians(j["limits"]).tolist() for p in parts for j in p["joints"]]
        self.lower = np.array([lo for lo, _ in limits], dtype=float)
        self.upper = np.array([hi for _, hi in limits], dtype=float)
        self.lower.setflags(write=False)
        self.upper.setflags(write=False)
        self.motion_names: list[str] = ["root.tx", "root.ty", "root.tz", "root.rz", "root.ry", "root.rx"] + [
            f"{p['name']}.{k}" for p in parts for k in range(len(p["joints"]))
        ]

    # -- construction and files -----------------------------------------------------------

    @classmethod
    def default_human(cls) -> BodyModel:
        """An adult of about 1.75 m: 16 parts, 34 metaballs, 25 joint angles with limits.

        Its body frame has z up, y backward (the body faces -y) and x to the body's left; the pelvis sits at the
        root translation. For a world with y up, use ``rest_state(up="y")``.
        """
        return cls(default_human_description())

    @classmethod
    def from_dict(cls, description: dict[str, Any]) -> BodyModel:
        """A model from its description (the module docstring gives the format)."""
        return cls(description)

    def to_dict(self) -> dict[str, Any]:
        """The description, JSON-ready."""
        return json.loads(json.dumps(self._description))

    @classmethod
    def load(cls, path: str | Path) -> BodyModel:
        """Reads a JSON description.

        Raises
        ------
        InvalidInputError
            When the file is not JSON or the description is malformed.
        """
        try:
            text = Path(path).read_text()
            description = json.loads(text)
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
            raise InvalidInputError(f"cannot read body model {path}: {error}") from None
        try:
            return cls(description)
        except InvalidInputError as error:
            raise InvalidInputError(f"body model {path}: {error}") from None
        except (ValueError, TypeError, KeyError, AttributeError, IndexError) as error:
            # A description whose fields have the wrong types or shapes.
            raise InvalidInputError(f"body model {path}: malformed description ({type(error).__name__}: {error})") from None

    def __reduce__(self) -> tuple[Any, ...]:
        # The skeleton in the core does not pickle: rebuild it from the description.
        return (BodyModel, (self.to_dict(),))

    def save(self, path: str | Path) -> None:
        """Writes the description as indented JSON."""
        Path(path).write_text(json.dumps(self._description, indent=1))

    def __repr__(self) -> str:
        balls = sum(len(p["balls"]) for p in self._description["parts"])
        return f"BodyModel({self._description.get('name', '')!r}, parts={len(self.part_names)}, balls={balls}, n_motion={self.n_motion})"

    # -- states ---------------------------------------------------------------------------

    def rest_state(self, *, position: Any = (0.0, 0.0, 0.0), up: str = "z") -> BodyState:
        """Unit shape, zero joint angles, the root at ``position`` (metres) with the body's
        up axis along world ``up`` ("z" or "y")."""
        motion = np.zeros(self.n_motion)
        motion[:3] = _vector(position, "position", 3)
        if up == "y":
            motion[5] = -np.pi / 2
        elif up != "z":
            raise InvalidInputError(f"up must be 'z' or 'y', got {up!r}")
        return BodyState(np.ones(self.n_shape), motion)

    def check_state(self, state: BodyState) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(shape, motion)`` of ``state`` as contiguous float64, with lengths checked."""
        shape = as_float_array("state.shape", state.shape)
        motion = as_float_array("state.motion", state.motion)
        if shape.shape != (self.n_shape,):
            raise InvalidInputError(f"state.shape must have shape ({self.n_shape},), got {shape.shape}")
        if motion.shape != (self.n_motion,):
            raise InvalidInputError(f"state.motion must have shape ({self.n_motion},), got {motion.shape}")
        return shape, motion

    def as_shape(self, shape: Any) -> NDArray[np.float64]:
        """A shape vector ``(4 P,)`` from ``shape``: already ``(4 P,)``, or the earlier layout
        ``(length, width)`` per part ``(2 P,)``, whose one width scaled both cross axes and
        which had no taper (read as depth = width, taper 1: the same body)."""
        array = as_float_array("shape", shape)
        parts = len(self.part_names)
        if array.shape == (2 * parts,):
            pairs = array.reshape(parts, 2)
            array = np.column_stack([pairs, pairs[:, 1], np.ones(parts)]).reshape(-1)
        if array.shape != (self.n_shape,):
            raise InvalidInputError(f"shape must have {self.n_shape} values ({', '.join(SHAPE_NAMES)} per part), got shape {array.shape}")
        return np.ascontiguousarray(array)

    def shape_table(self, shape: Any) -> dict[str, dict[str, float]]:
        """``{part: {"length": l, "width": w, "depth": d, "taper": tau}}`` of a shape vector."""
        table = self.as_shape(shape).reshape(-1, len(SHAPE_NAMES))
        return {name: dict(zip(SHAPE_NAMES, map(float, row))) for name, row in zip(self.part_names, table)}

    def mirrored_shape_groups(self) -> NDArray[np.int64]:
        """Shape groups (``fit_body(shape_groups=...)``) that tie each left part's shape
        coefficients to its right twin's (parts named ``l_<x>`` and ``r_<x>``); other
        parts' stay free. ``(n_shape,) int64``."""
        keys = []
        for name in self.part_names:
            twin = name[2:] if name[:2] in ("l_", "r_") and {"l_" + name[2:], "r_" + name[2:]} <= set(self.part_names) else None
            keys += [(twin or name, k) for k in SHAPE_NAMES]
        numbers: dict[tuple[str, str], int] = {}
        return np.array([numbers.setdefault(k, len(numbers)) for k in keys], dtype=np.int64)

    # -- kinematics and field -------------------------------------------------------------

    def pose(self, state: BodyState) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """World rotations ``(P, 3, 3)`` and origins ``(P, 3)`` (joint positions, metres)
        of the part frames."""
        return self._core.pose(*self.check_state(state))

    def field(self, points: Any, state: BodyState) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """``F (N,)``, ``grad F (N, 3)`` (1/m) and ``Hessian (N, 3, 3)`` (1/m^2) at world
        ``points (N, 3)`` (metres)."""
        return self._core.field(*self.check_state(state), as_points("points", points, (3,)))

    def jacobian(self, points: Any, state: BodyState) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``F (N,)`` and ``dF/d(motion, shape)`` at fixed points, ``(N, n_motion + n_shape)``
        (motion columns first)."""
        return self._core.jacobian(*self.check_state(state), as_points("points", points, (3,)))

    def ray_maxima(self, origins: Any, directions: Any, state: BodyState) -> dict[str, NDArray[Any]]:
        """The field maximum along each ray ``origins + s directions``, ``s >= 0``.

        Returns a dict: ``s (N,)``, ``points (N, 3)`` (``x*``), ``values (N,)`` (``F(x*)``),
        ``hit (N,)`` (False: the ray misses every ball; value 0) and ``jacobian (N, n_motion
        + n_shape)`` of ``F(x*)`` (SPEC 6: the partial derivative at fixed ``x*``).
        """
        o = as_points("origins", origins, (3,))
        r = as_points("directions", directions, (3,))
        s, x, f, hit, j = self._core.rays(*self.check_state(state), o, r)
        return {"s": s, "points": x, "values": f, "hit": hit, "jacobian": j}

    # -- pictures -------------------------------------------------------------------------

    def ball_centres(self, state: BodyState) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Deprecated spelling of :meth:`ball_centers`."""
        warnings.warn("BodyModel.ball_centres() is now ball_centers()", DeprecationWarning, stacklevel=2)
        return self.ball_centers(state)

    def ball_centers(self, state: BodyState) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """World centers ``(M, 3)`` and largest scaled radius ``(M,)`` of the metaballs."""
        shape, _ = self.check_state(state)
        rotations, origins = self.pose(state)
        part, centre, radii = self._balls
        table = shape.reshape(-1, len(SHAPE_NAMES))[part]
        section = 1.0 + (table[:, 3] - 1.0) * self.taper_weight
        scale = np.stack([table[:, 1] * section, table[:, 2] * section, table[:, 0]], axis=1)
        world = origins[part] + np.einsum("mij,mj->mi", rotations[part], centre * scale)
        return world, (radii * scale).max(axis=1)

    def bounds(self, state: BodyState) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """A box (lower, upper corners, metres) that holds the skin: every ball's centre
        plus its largest radius (a lone ball's skin reaches 0.59 of it; overlaps a little
        more)."""
        centres, reach = self.ball_centers(state)
        return (centres - reach[:, None]).min(axis=0), (centres + reach[:, None]).max(axis=0)

    def skin_mesh(self, state: BodyState, *, spacing: float = 0.01) -> trimesh.Trimesh:
        """The skin ``F = 0.5`` as a triangle mesh (marching cubes, world metres).

        Parameters
        ----------
        state : BodyState
        spacing : float, keyword-only
            Grid spacing, metres.
        """
        h = as_positive("spacing", spacing)
        lower, upper = self.bounds(state)
        counts = np.ceil((upper - lower) / h).astype(int) + 1
        axes = [lower[a] + h * np.arange(counts[a]) for a in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        values = self._core.values(*self.check_state(state), np.ascontiguousarray(grid))
        volume = values.reshape(counts) - SKIN_LEVEL
        vertices, faces, _, _ = measure.marching_cubes(volume, level=0.0, spacing=(h, h, h))
        # skimage winds faces for a field increasing outwards; F decreases outwards.
        return trimesh.Trimesh(vertices + lower, faces[:, ::-1], process=True)

    def skin_points(self, state: BodyState, n: int, *, seed: int = 0, spacing: float = 0.01) -> NDArray[np.float64]:
        """``n`` points on the skin ``F = 0.5`` (world metres): random vertices of
        :meth:`skin_mesh`, moved onto the level set by Newton steps along the gradient
        (to rounding level, so they are exact synthetic observations)."""
        count = as_count("n", n)
        mesh = self.skin_mesh(state, spacing=spacing)
        rng = np.random.default_rng(seed)
        points = np.ascontiguousarray(mesh.vertices[rng.choice(len(mesh.vertices), count, replace=count > len(mesh.vertices))])
        shape, motion = self.check_state(state)
        for _ in range(8):
            f, g, _ = self._core.field(shape, motion, points)
            points = np.ascontiguousarray(points - ((f - SKIN_LEVEL) / np.maximum((g * g).sum(axis=1), 1e-300))[:, None] * g)
        return points

    def silhouette(self, state: BodyState, camera: Camera) -> NDArray[np.bool_]:
        """The model's silhouette in ``camera``: ``(height, width)`` bool, True where the
        pixel's ray meets the skin (the field maximum along the ray reaches 0.5)."""
        mask = np.zeros((camera.height, camera.width), dtype=bool)
        lower, upper = self.bounds(state)
        corners = np.array([[(lower, upper)[k >> a & 1][a] for a in range(3)] for k in range(8)])
        uv_box, depth = camera.project(corners)
        if (depth > 0).all() and np.isfinite(uv_box).all():
            # Rays outside the projected box cannot meet the skin (distortion moves the box
            # by less than the margin of 2 pixels only for mild lenses; else cast all).
            u0, v0 = np.floor(uv_box.min(axis=0)).astype(int) - 2
            u1, v1 = np.ceil(uv_box.max(axis=0)).astype(int) + 2
            u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, camera.width), min(v1, camera.height)
            if not camera.has_distortion:
                if u0 >= u1 or v0 >= v1:
                    return mask
                v, u = np.mgrid[v0:v1, u0:u1]
            else:
                v, u = np.mgrid[0 : camera.height, 0 : camera.width]
        else:
            v, u = np.mgrid[0 : camera.height, 0 : camera.width]
        uv = np.stack([u.ravel(), v.ravel()], axis=1).astype(float)
        origins, directions = camera.rays(uv)
        ok = np.isfinite(directions).all(axis=1)
        inside = np.zeros(len(uv), dtype=bool)
        inside[ok] = self._core.rays_inside(
            *self.check_state(state),
            np.ascontiguousarray(origins[ok]),
            np.ascontiguousarray(directions[ok]),
            SKIN_LEVEL,
        )
        mask[v.ravel(), u.ravel()] = inside
        return mask


def _normalise(description: Any) -> dict[str, Any]:
    """The description with defaults filled in, or InvalidInputError naming the fault."""
    if not isinstance(description, dict):
        raise _bad(f"must be a dict (a JSON object), got {type(description).__name__}")
    parts = description.get("parts")
    if not isinstance(parts, list) or not parts:
        raise _bad("'parts' must be a non-empty list")
    seen: set[str] = set()
    out = []
    for i, part in enumerate(parts):
        if not isinstance(part, dict):
            raise _bad(f"parts[{i}] must be an object")
        name = part.get("name")
        if not isinstance(name, str) or not name or name in seen:
            raise _bad(f"parts[{i}] needs a unique non-empty 'name', got {name!r}")
        parent = part.get("parent")
        if parent is not None and parent not in seen:
            raise _bad(f"part {name!r}: parent {parent!r} must be a part listed before it")
        seen.add(name)
        rest = part.get("rest", np.eye(3).tolist())
        rest_array = np.asarray(rest, dtype=float) if np.ndim(rest) == 2 else None
        if rest_array is None or rest_array.shape != (3, 3):
            raise _bad(f"part {name!r}: 'rest' must be a 3x3 rotation")
        joints = []
        for k, joint in enumerate(part.get("joints", [])):
            if not isinstance(joint, dict):
                raise _bad(f"part {name!r}: joints[{k}] must be an object")
            axis = _vector(joint.get("axis"), f"part {name!r} joints[{k}].axis", 3)
            if not np.linalg.norm(axis) > 0:
                raise _bad(f"part {name!r} joints[{k}]: 'axis' must be a non-zero 3-vector")
            limits = _vector(joint.get("limits", [-180, 180]), f"part {name!r} joints[{k}].limits", 2)
            if not limits[0] <= limits[1]:
                raise _bad(f"part {name!r} joints[{k}]: limits must be [lower, upper] with lower <= upper")
            joints.append({"axis": axis, "limits": limits})
        balls = []
        for k, ball in enumerate(part.get("balls", [])):
            if not isinstance(ball, dict):
                raise _bad(f"part {name!r}: balls[{k}] must be an object")
            # "centre" is the spelling of descriptions written before 0.2.
            key = "center" if "center" in ball else "centre"
            centre = _vector(ball.get(key), f"part {name!r} balls[{k}].{key}", 3)
            radii = _vector(ball.get("radii"), f"part {name!r} balls[{k}].radii", 3)
            if min(radii) <= 0:
                raise _bad(f"part {name!r} balls[{k}]: radii must be positive")
            balls.append({"center": centre, "radii": radii})
        out.append(
            {
                "name": name,
                "parent": parent,
                "offset": _vector(part.get("offset", [0, 0, 0]), f"part {name!r} offset", 3),
                "rest": rest_array.tolist(),
                "joints": joints,
                "balls": balls,
            }
        )
    if not any(p["balls"] for p in out):
        raise _bad("the model has no metaballs")
    return {"format": FORMAT, "name": str(description.get("name", "")), "parts": out}
