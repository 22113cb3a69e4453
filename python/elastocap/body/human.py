"""The default human body model: 16 parts, 34 metaballs, proportions of an adult of about
1.75 m, joint limits in degrees. Body frame: x to the body's left, y backward (the body
faces -y), z up; every part's z axis runs along its bone."""

from __future__ import annotations

from typing import Any

import numpy as np

# A lone ball's skin (F = T = 0.5) lies at |q| = sqrt(ln 2 / 2) of its radii: radii are the
# skin semi-axes divided by this.
SKIN_FRACTION = float(np.sqrt(np.log(2.0) / 2.0))


def _rot_y(degrees: float) -> list[list[float]]:
    a = np.radians(degrees)
    return np.round([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]], 12).tolist()


def _rot_x(degrees: float) -> list[list[float]]:
    a = np.radians(degrees)
    return np.round([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]], 12).tolist()


def _ball(centre: tuple[float, float, float], skin: tuple[float, float, float]) -> dict[str, Any]:
    """A ball whose skin, alone, has semi-axes ``skin`` (metres)."""
    return {"center": list(centre), "radii": [round(s / SKIN_FRACTION, 6) for s in skin]}


def _joint(axis: str, lower: float, upper: float) -> dict[str, Any]:
    return {"axis": {"x": [1, 0, 0], "y": [0, 1, 0], "z": [0, 0, 1]}[axis], "limits": [lower, upper]}


def _side(sign: int) -> list[dict[str, Any]]:
    """Arm and leg of one side: +1 left, -1 right."""
    s = "l" if sign > 0 else "r"
    return [
        {
            "name": f"{s}_upperarm", "parent": "chest", "offset": [0.17 * sign, 0.0, 0.23],
            "rest": _rot_y(150 * sign),
            "joints": [_joint("x", -90, 90), _joint("y", -60, 90), _joint("z", -80, 80)],
            "balls": [_ball((0, 0, 0.07), (0.045, 0.048, 0.09)), _ball((0, 0, 0.2), (0.038, 0.042, 0.09))],
        },
        {
            "name": f"{s}_forearm", "parent": f"{s}_upperarm", "offset": [0.0, 0.0, 0.29],
            # Both forearms' x axes point to the body's right: a positive angle bends the elbow
            # forward (-y), on both sides.
            "joints": [_joint("x", 0, 145)],
            "balls": [_ball((0, 0, 0.07), (0.036, 0.04, 0.09)), _ball((0, 0, 0.19), (0.028, 0.032, 0.08))],
        },
        {
            "name": f"{s}_hand", "parent": f"{s}_forearm", "offset": [0.0, 0.0, 0.26],
            "joints": [_joint("x", -70, 70)],
            "balls": [_ball((0, 0, 0.06), (0.022, 0.045, 0.06)), _ball((0, 0.0, 0.13), (0.016, 0.04, 0.04))],
        },
        {
            "name": f"{s}_thigh", "parent": "pelvis", "offset": [0.09 * sign, 0.0, -0.05],
            "rest": _rot_y(180),
            "joints": [_joint("x", -30, 110), _joint("y", -45, 45), _joint("z", -40, 40)],
            "balls": [_ball((0, 0, 0.1), (0.075, 0.08, 0.12)), _ball((0, 0, 0.3), (0.055, 0.058, 0.12))],
        },
        {
            "name": f"{s}_shin", "parent": f"{s}_thigh", "offset": [0.0, 0.0, 0.43],
            "joints": [_joint("x", -140, 0)],
            "balls": [_ball((0, 0, 0.1), (0.05, 0.055, 0.12)), _ball((0, 0, 0.29), (0.038, 0.04, 0.1))],
        },
        {
            "name": f"{s}_foot", "parent": f"{s}_shin", "offset": [0.0, 0.0, 0.42],
            # rot_x(-90) turned about the bone by half a turn: the toes point forward (-y).
            "rest": np.round(np.diag([-1.0, -1.0, 1.0]) @ np.array(_rot_x(-90)), 12).tolist(),
            # Positive points the toes down (plantar flexion, up to ~60 degrees in a walk's
            # swing), negative lifts them.
            "joints": [_joint("x", -40, 65)],
            "balls": [_ball((0, -0.05, 0.02), (0.04, 0.035, 0.06)), _ball((0, -0.06, 0.12), (0.045, 0.03, 0.07))],
        },
    ]


def default_human_description() -> dict[str, Any]:
    """The default human as a JSON-ready dictionary (see :meth:`BodyModel.from_dict`)."""
    parts: list[dict[str, Any]] = [
        {
            "name": "pelvis", "parent": None, "offset": [0.0, 0.0, 0.0],
            "balls": [
                _ball((0, 0, 0.03), (0.15, 0.1, 0.09)),
                _ball((0.08, 0, -0.04), (0.09, 0.09, 0.09)),
                _ball((-0.08, 0, -0.04), (0.09, 0.09, 0.09)),
            ],
        },
        {
            "name": "abdomen", "parent": "pelvis", "offset": [0.0, 0.0, 0.08],
            "joints": [_joint("x", -30, 60), _joint("y", -30, 30)],
            "balls": [_ball((0, 0, 0.08), (0.13, 0.095, 0.1)), _ball((0, 0.01, 0.17), (0.135, 0.095, 0.08))],
        },
        {
            "name": "chest", "parent": "abdomen", "offset": [0.0, 0.0, 0.2],
            "joints": [_joint("z", -40, 40)],
            "balls": [
                _ball((0, 0, 0.08), (0.15, 0.1, 0.1)),
                _ball((0.09, 0, 0.2), (0.08, 0.075, 0.07)),
                _ball((-0.09, 0, 0.2), (0.08, 0.075, 0.07)),
            ],
        },
        {
            "name": "head", "parent": "chest", "offset": [0.0, 0.0, 0.29],
            "joints": [_joint("x", -40, 50), _joint("y", -40, 40)],
            "balls": [_ball((0, 0, 0.04), (0.05, 0.05, 0.06)), _ball((0, -0.015, 0.16), (0.075, 0.09, 0.11))],
        },
    ]
    parts += _side(+1) + _side(-1)
    return {"format": "elastocap body model 1", "name": "default human", "parts": parts}
