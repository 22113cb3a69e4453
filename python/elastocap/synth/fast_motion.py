"""The capsule figure's fast motion (``CapsuleFigure(seed, motion="fast")``): one arm swings
through a large arc in front of the body and across the chest while one leg kicks, each
limb tip moving 10 to 35 cm per frame, so that the elastic fit's closest-point association
starts a limb-width or more away from where the limb now is (issue 17, item 5).

Limbs: the right arm swings from behind the body (``arm_mid - arm_amplitude``) to above
the head in front (``arm_mid + arm_amplitude``), a sine of period ``arm_cycle`` frames,
crossing the chest (horizontal adduction up to ``arm_cross``) on the way, so that cameras
behind it lose the chest and it comes within a few centimetres of the torso (the hull
merges them there); the elbow bends on the way up. The left arm swings against it, more
slowly and within a smaller arc. The left leg kicks: a sine of period ``kick_cycle`` frames
from ``kick_mid - kick_amplitude`` behind to ``kick_mid + kick_amplitude`` in front, knee
chambered while the thigh rises and snapped straight at the top, crossing in front of the
standing leg by up to ``kick_cross``. The right leg stands, slightly bent. The whole body
turns by ``yaw_per_frame``.

At frame 0 both sines are near their middle, rising: the arm hangs in front of the body
away from the torso and the kicking leg is chambered in front, clear of the standing one,
so a model built from frame 0's hull has its limbs apart.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

__all__ = ["FAST_MOTION_KEYS", "draw_fast_motion", "fast_joint_angles"]

# The motion's parameters, besides the proportions every figure has (angles in degrees,
# times in frames).
FAST_MOTION_KEYS = (
    "yaw_start", "yaw_per_frame",
    "arm_cycle", "arm_phase", "arm_mid", "arm_amplitude", "arm_abduction", "arm_cross",
    "elbow_min", "elbow_max", "other_arm_mid", "other_arm_amplitude", "other_elbow",
    "kick_cycle", "kick_phase", "kick_mid", "kick_amplitude", "kick_cross",
    "knee_min", "knee_max", "stance_knee", "leg_abduction",
)


def draw_fast_motion(rng: np.random.Generator) -> dict[str, float]:
    """The fast motion's parameters (:data:`FAST_MOTION_KEYS`) drawn from ``rng``."""
    return {
        "yaw_start": float(rng.uniform(0.0, 360.0)),
        "yaw_per_frame": float(rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 1.5)),
        # Peak angular speed 2 pi amplitude / cycle: 25-33 degrees per frame, so the hand
        # (0.6 m from the shoulder) moves up to 0.26-0.35 m per frame, 0.17-0.22 m on average.
        "arm_cycle": float(rng.uniform(20.0, 24.0)),
        "arm_phase": float(rng.uniform(-0.7, 0.7)),
        "arm_mid": float(rng.uniform(40.0, 50.0)),
        "arm_amplitude": float(rng.uniform(85.0, 95.0)),
        "arm_abduction": float(rng.uniform(10.0, 16.0)),
        "arm_cross": float(rng.uniform(35.0, 45.0)),
        "elbow_min": float(rng.uniform(8.0, 14.0)),
        "elbow_max": float(rng.uniform(45.0, 60.0)),
        "other_arm_mid": float(rng.uniform(5.0, 15.0)),
        "other_arm_amplitude": float(rng.uniform(30.0, 40.0)),
        "other_elbow": float(rng.uniform(25.0, 40.0)),
        # The foot, ~0.9 m from the hip, moves up to 0.3-0.4 m per frame.
        "kick_cycle": float(rng.uniform(16.0, 20.0)),
        "kick_phase": float(rng.uniform(-0.5, 0.5)),
        "kick_mid": float(rng.uniform(28.0, 34.0)),
        "kick_amplitude": float(rng.uniform(50.0, 56.0)),
        "kick_cross": float(rng.uniform(8.0, 14.0)),
        "knee_min": float(rng.uniform(3.0, 6.0)),
        "knee_max": float(rng.uniform(70.0, 85.0)),
        "stance_knee": float(rng.uniform(6.0, 12.0)),
        "leg_abduction": 2.0,
    }


def fast_joint_angles(p: Mapping[str, float], frame: int) -> dict[str, float]:
    """The joint angles of the fast motion at ``frame`` (degrees; the keys of
    :meth:`CapsuleFigure.joint_angles`, plus ``hip_inward_<l|r>``, the leg's horizontal
    adduction)."""
    arm = 2 * math.pi * (frame + p["arm_phase"]) / p["arm_cycle"]
    kick = 2 * math.pi * (frame + p["kick_phase"]) / p["kick_cycle"]
    flex = p["arm_mid"] + p["arm_amplitude"] * math.sin(arm)
    # Across the chest and face while the arm is raised in front of them (flex 40-150, most
    # at 95): in front of the torso for the cameras behind the arm, clear of it.
    cross = p["arm_cross"] * max(0.0, 1.0 - ((flex - 95.0) / 55.0) ** 2)
    angles: dict[str, float] = {
        "clap": 0.0,
        "arm_flex_r": flex,
        "arm_abduction_r": p["arm_abduction"],
        "arm_inward_r": cross,
        "elbow_r": p["elbow_min"] + (p["elbow_max"] - p["elbow_min"]) * (0.5 + 0.5 * math.cos(arm)),
        "arm_flex_l": p["other_arm_mid"] - p["other_arm_amplitude"] * math.sin(arm),
        "arm_abduction_l": p["arm_abduction"],
        "arm_inward_l": 0.0,
        "elbow_l": p["other_elbow"],
        "hip_flex_l": p["kick_mid"] + p["kick_amplitude"] * math.sin(kick),
        # Chambered while the thigh rises, straight at the top and on the way down.
        "knee_l": p["knee_min"] + (p["knee_max"] - p["knee_min"]) * max(0.0, math.cos(kick)),
        "hip_inward_l": p["kick_cross"] * max(0.0, math.sin(kick)),
        "hip_flex_r": 0.0,
        "knee_r": p["stance_knee"],
        "hip_inward_r": 0.0,
    }
    return angles
