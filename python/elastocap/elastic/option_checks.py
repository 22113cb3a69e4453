"""Checks of the fit's option objects (:class:`~elastocap.elastic.track_terms.TrackTerms`,
:mod:`elastocap.elastic.fit_options`): each value checked once, on construction, and stored as
Python's own bool / int / float, so that a bad value is refused by name before any frame is
fitted and never reaches the solver as a NaN."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from elastocap._core import InvalidInputError

__all__ = ["checked", "checked_choice"]


def checked(owner: str, name: str, kind: str, value: Any, least: float, closed: bool) -> Any:
    """``value`` as a Python bool / int / float after checking it.

    ``kind``: "bool"; "int" (non-negative, at least ``least``); "float" or "length" (finite,
    at least ``least``, strictly above it unless ``closed``); "fraction" (a float in
    ``[least, 1)``). Errors read ``"<owner>.<name> must be ..., got <value>"``.
    """
    if kind == "bool":
        if not isinstance(value, (bool, np.bool_)):
            raise InvalidInputError(f"{owner}.{name} must be a bool, got {value!r}")
        return bool(value)
    if kind == "int":
        # A bool is an int to Python; as a count it is a mistake.
        wording = "a non-negative int" if least == 0 else f"an int >= {least:g}"
        if isinstance(value, (bool, np.bool_)) or not (isinstance(value, (int, np.integer)) and value >= least):
            raise InvalidInputError(f"{owner}.{name} must be {wording}, got {value!r}")
        return int(value)
    if kind == "fraction":
        bound = f"in [{least:g}, 1)"
    else:
        bound = f">= {least:g}" if closed else f"> {least:g}"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InvalidInputError(f"{owner}.{name} must be a finite number {bound}, got {value!r}")
    inside = value >= least if closed else value > least
    if kind == "fraction":
        inside = inside and value < 1
    if not (np.isfinite(value) and inside):
        raise InvalidInputError(f"{owner}.{name} must be a finite number {bound}, got {value}")
    return float(value)


def checked_choice(owner: str, name: str, value: Any, choices: Sequence[str]) -> str:
    """``value`` if it is one of ``choices`` (strings), else an :class:`InvalidInputError`
    naming the field, the choices and the value."""
    if not (isinstance(value, str) and value in choices):
        listed = ", ".join(repr(choice) for choice in choices)
        raise InvalidInputError(f"{owner}.{name} must be one of {listed}, got {value!r}")
    return str(value)
