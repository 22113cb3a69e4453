"""The capsule figure's skeleton (:mod:`elastocap.synth.capsules`): its parts and rest
proportions, the parameters drawn per seed, and forward kinematics from joint angles to
capsules. Split from ``capsules.py``, which keeps the figure's surface (distance field, mesh,
colours) and its motion through frames.

World frame: metres, **y up**, the floor at ``y = 0``; at yaw 0 the figure faces +z with
its left side on +x.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap.synth.fast_motion import FAST_MOTION_KEYS, draw_fast_motion

__all__ = ["CONTACT_DEPTH", "MOTIONS", "PARTS", "Capsules", "draw_parameters", "parameter_names", "pose", "rx", "ry", "rz"]

# The figure's motions: walking in place with a clap (the default), or a fast arm swing and
# leg kick (:mod:`elastocap.synth.fast_motion`).
MOTIONS = ("walk", "fast")

# The body parts, in the order their capsules are blended (the smooth union is a left fold,
# so the order is part of the definition of the surface).
PARTS = (
    "pelvis", "abdomen", "chest", "neck", "head",
    "upper_arm_l", "forearm_l", "hand_l", "upper_arm_r", "forearm_r", "hand_r",
    "thigh_l", "shin_l", "foot_l", "thigh_r", "shin_r", "foot_r",
)

# The hands of the clap overlap by this much (metres) at the clap's peak: in contact, with
# a margin that survives the discretisation of the surface.
CONTACT_DEPTH = 0.004

# Default rest proportions of the skeleton (metres) at scale 1; each seed scales lengths
# and girths by a few percent. Heights are above the floor (y = 0).
_REST: dict[str, float] = {
    "hip_height": 0.93, "hip_half_width": 0.09,
    "pelvis_height": 0.965, "pelvis_half_width": 0.07, "pelvis_radius": 0.115,
    "abdomen_bottom": 1.02, "abdomen_top": 1.20, "abdomen_radius": 0.115,
    "chest_height": 1.30, "chest_half_width": 0.075, "chest_radius": 0.115,
    "neck_bottom": 1.40, "neck_top": 1.52, "neck_radius": 0.05,
    "head_bottom": 1.585, "head_top": 1.615, "head_forward": 0.02, "head_radius": 0.095,
    "shoulder_height": 1.41, "shoulder_half_width": 0.195,
    "upper_arm_length": 0.29, "upper_arm_radius": 0.045,
    "forearm_length": 0.25, "forearm_radius": 0.037,
    "hand_offset": 0.015, "hand_length": 0.10, "hand_radius": 0.032,
    "thigh_length": 0.43, "thigh_radius": 0.075,
    "shin_length": 0.42, "shin_radius": 0.052,
    "foot_drop": 0.035, "heel_back": 0.045, "toe_forward": 0.14, "foot_radius": 0.042,
}
_RADII = {name for name in _REST if name.endswith("_radius")}


@dataclass(frozen=True)
class Capsules:
    """The figure's capsules in one frame, in blending order.

    Attributes
    ----------
    names : tuple of str
        Part names (:data:`PARTS`).
    starts, ends : (S, 3) float64
        Segment end points, world (metres).
    radii : (S,) float64
        Radii, metres.
    frames : (S, 3, 3) float64
        Each part's rotation, body part -> world (columns: the part's x, y, z axes in
        world coordinates); the segment runs along the part's -y axis for limbs.
    """

    names: tuple[str, ...]
    starts: NDArray[np.float64]
    ends: NDArray[np.float64]
    radii: NDArray[np.float64]
    frames: NDArray[np.float64]


def draw_parameters(seed: int, motion: str = "walk") -> dict[str, float]:
    rng = np.random.default_rng([seed, 0x5F1])
    scale = float(rng.uniform(0.95, 1.05))
    girth = float(rng.uniform(0.92, 1.08))
    p = {name: value * scale * (girth if name in _RADII else 1.0) for name, value in _REST.items()}
    if motion == "fast":
        # Same proportions as the walk of this seed; the motion from a stream of its own.
        p.update(scale=scale, girth=girth, blend=0.03)
        p.update(draw_fast_motion(np.random.default_rng([seed, 0xFA5])))
        return p
    cycle = 30
    p.update(
        scale=scale,
        girth=girth,
        blend=0.03,
        cycle_frames=float(cycle),
        phase_frames=float(rng.integers(0, cycle)),
        arm_forward=float(rng.uniform(58.0, 66.0)),
        arm_back=float(rng.uniform(45.0, 52.0)),
        arm_abduction=float(rng.uniform(8.0, 11.0)),
        elbow_min=float(rng.uniform(10.0, 15.0)),
        elbow_max=float(rng.uniform(75.0, 90.0)),
        hip_swing=float(rng.uniform(26.0, 32.0)),
        leg_abduction=2.0,
        knee_min=float(rng.uniform(3.0, 6.0)),
        knee_max=float(rng.uniform(55.0, 68.0)),
        yaw_start=float(rng.uniform(0.0, 360.0)),
        yaw_per_frame=float(rng.choice([-1.0, 1.0]) * rng.uniform(2.0, 3.0)),
        clap_hold=1.0,
        clap_ramp=4.0,
        clap_flex=float(rng.uniform(55.0, 62.0)),
        clap_abduction=8.0,
        clap_elbow=float(rng.uniform(45.0, 55.0)),
        clap_inward=0.0,
    )
    p["clap_inward"] = solve_clap(p)
    return p


@lru_cache(maxsize=len(MOTIONS))
def parameter_names(motion: str = "walk") -> tuple[str, ...]:
    names = tuple(draw_parameters(0, motion))
    assert motion != "fast" or set(FAST_MOTION_KEYS) <= set(names)
    return names


def solve_clap(p: dict[str, float]) -> float:
    """The clap's inward arm angle (degrees) at which the hands overlap by CONTACT_DEPTH."""
    hands = PARTS.index("hand_l"), PARTS.index("hand_r")

    def gap(inward: float) -> float:
        angles = {"clap": 1.0}
        for side in "lr":
            angles.update({f"arm_flex_{side}": p["clap_flex"], f"arm_abduction_{side}": p["clap_abduction"],
                           f"arm_inward_{side}": inward, f"elbow_{side}": p["clap_elbow"],
                           f"hip_flex_{side}": 0.0, f"knee_{side}": p["knee_min"]})
        c = pose(p, angles, 0.0)
        (i, j) = hands
        return segment_distance(c.starts[i], c.ends[i], c.starts[j], c.ends[j]) - c.radii[i] - c.radii[j]

    # Scan for the first angle where the hands meet, then bisect.
    grid = np.linspace(0.0, 60.0, 61)
    gaps = [gap(float(angle)) for angle in grid]
    crossing = next(i for i in range(1, len(grid)) if gaps[i] <= -CONTACT_DEPTH)
    lo, hi = float(grid[crossing - 1]), float(grid[crossing])
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if gap(mid) > -CONTACT_DEPTH:
            lo = mid
        else:
            hi = mid
    return hi


def pose(p: Mapping[str, float], angles: Mapping[str, float], yaw: float) -> Capsules:
    """Forward kinematics: capsules in world coordinates for the given joint angles."""
    identity = np.eye(3)
    starts: list[NDArray[np.float64]] = []
    ends: list[NDArray[np.float64]] = []
    radii: list[float] = []
    frames: list[NDArray[np.float64]] = []

    def add(a: Any, b: Any, r: float, rotation: NDArray[np.float64] = identity) -> None:
        starts.append(np.asarray(a, dtype=np.float64))
        ends.append(np.asarray(b, dtype=np.float64))
        radii.append(r)
        frames.append(rotation)

    add([-p["pelvis_half_width"], p["pelvis_height"], -0.005], [p["pelvis_half_width"], p["pelvis_height"], -0.005],
        p["pelvis_radius"])
    add([0, p["abdomen_bottom"], 0], [0, p["abdomen_top"], 0], p["abdomen_radius"])
    add([-p["chest_half_width"], p["chest_height"], 0], [p["chest_half_width"], p["chest_height"], 0],
        p["chest_radius"])
    add([0, p["neck_bottom"], 0], [0, p["neck_top"], 0.005], p["neck_radius"])
    add([0, p["head_bottom"], p["head_forward"]], [0, p["head_top"], p["head_forward"]], p["head_radius"])
    down = np.array([0.0, -1.0, 0.0])
    for side, sign in (("l", 1.0), ("r", -1.0)):
        rad = {key: math.radians(angles[f"{key}_{side}"])
               for key in ("arm_flex", "arm_abduction", "arm_inward", "elbow")}
        shoulder = np.array([sign * p["shoulder_half_width"], p["shoulder_height"], 0.0])
        upper = ry(-sign * rad["arm_inward"]) @ rz(sign * rad["arm_abduction"]) @ rx(-rad["arm_flex"])
        elbow = shoulder + upper @ down * p["upper_arm_length"]
        fore = upper @ rx(-rad["elbow"])
        wrist = elbow + fore @ down * p["forearm_length"]
        add(shoulder, elbow, p["upper_arm_radius"], upper)
        add(elbow, wrist, p["forearm_radius"], fore)
        add(wrist + fore @ down * p["hand_offset"], wrist + fore @ down * (p["hand_offset"] + p["hand_length"]),
            p["hand_radius"], fore)
    for side, sign in (("l", 1.0), ("r", -1.0)):
        flex, knee = math.radians(angles[f"hip_flex_{side}"]), math.radians(angles[f"knee_{side}"])
        # A leg crossing in front of the other (the fast motion's kick) turns inward about y.
        inward = math.radians(angles.get(f"hip_inward_{side}", 0.0))
        splay = ry(-sign * inward) @ rz(sign * math.radians(p["leg_abduction"]))
        hip = np.array([sign * p["hip_half_width"], p["hip_height"], 0.0])
        thigh = splay @ rx(-flex)
        knee_at = hip + thigh @ down * p["thigh_length"]
        shin = thigh @ rx(knee)
        ankle = knee_at + shin @ down * p["shin_length"]
        # The foot follows the shin's pitch only partly: it stays near horizontal.
        foot = splay @ rx(-0.4 * (flex - knee))
        add(hip, knee_at, p["thigh_radius"], thigh)
        add(knee_at, ankle, p["shin_radius"], shin)
        add(ankle + foot @ [0.0, -p["foot_drop"], -p["heel_back"]], ankle + foot @ [0.0, -p["foot_drop"], p["toe_forward"]],
            p["foot_radius"], foot)
    turn = ry(yaw)
    return Capsules(
        names=PARTS,
        starts=np.stack(starts) @ turn.T,
        ends=np.stack(ends) @ turn.T,
        radii=np.array(radii),
        frames=turn @ np.stack(frames),
    )


def rx(angle: float) -> NDArray[np.float64]:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def ry(angle: float) -> NDArray[np.float64]:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rz(angle: float) -> NDArray[np.float64]:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def segment_distance(
    a0: NDArray[np.float64], a1: NDArray[np.float64], b0: NDArray[np.float64], b1: NDArray[np.float64]
) -> float:
    """Distance between segments ``a0 a1`` and ``b0 b1``: the closest pair, by the clamped
    line-line solution refined on each end (Ericson, Real-Time Collision Detection 5.1.9)."""
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a, e, f = float(d1 @ d1), float(d2 @ d2), float(d2 @ r)
    c, b = float(d1 @ r), float(d1 @ d2)
    denominator = a * e - b * b
    s = float(np.clip((b * f - c * e) / denominator, 0.0, 1.0)) if denominator > 1e-18 else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t, s = 0.0, float(np.clip(-c / a, 0.0, 1.0))
    elif t > 1.0:
        t, s = 1.0, float(np.clip((b - c) / a, 0.0, 1.0))
    return float(np.linalg.norm(a0 + s * d1 - (b0 + t * d2)))
