"""The shape families the body tracker fits (issue 16, SPEC 6): which shape coefficients
are free, tied or held, and the prior on them: :func:`narrow_shape_family`,
:func:`limb_length_groups`."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap.body.model import SHAPE_NAMES, BodyModel

__all__ = ["SHAPE_PRIOR_SIGMA", "SHAPE_PRIOR_SIGMA_MASKS", "SHAPE_RANGE", "limb_length_groups", "narrow_shape_family"]

#: Default ``sigma_shape`` of :class:`BodyTracker`: the shape prior's standard deviation
#: (``fit_body(sigma_shape=)``) when the fitted frames carry stereo points. Chosen on the
#: capsule figure's tuning seeds 0-2 (3 frames): alone, 0.05-0.2 changed nothing
#: measurable and 0.005 was worse than 0.01 (seed 0); with the limb lengths tied, 0.01
#: took the skin from 8.6-11.4 mm (tie alone) to 5.9-7.8 mm and the joints from 21-29 to
#: 16-27 mm RMS (neither: 38-43 mm, 8.3-8.7 mm; ``benches/README.md``, branch body6).
SHAPE_PRIOR_SIGMA = 0.01
#: Default ``sigma_shape_masks`` of :class:`BodyTracker`: the shape prior's standard
#: deviation when the fitted frames carry silhouettes alone (the narrow family, limb
#: lengths tied). The frame-0 shape fit of the capsule figure from the search's pose (8
#: masks, tuning seeds 20 and 12; joints RMS / skin mean): free lengths, no prior 100.6 /
#: 10.14 mm and 43.8 / 10.72 mm (knees 13-21 cm along the thighs); tied, no prior 27.1 /
#: 10.79 and 22.6 / 10.91; tied with 0.2 / 0.1 / 0.05 / 0.02: 27.0 / 26.7 / **25.8** / 22.8
#: mm joints, 10.75 / 10.52 / **10.47** / 10.74 mm skin on seed 20 and 22.6 / 22.3 /
#: **21.7** mm, 10.52 / 10.48 / **10.41** mm on seed 12 (the prior alone, untied, 0.05:
#: 77.5 and 21.8 mm: it does not hold seed 20's knees; ``benches/README.md``, branch body11).
SHAPE_PRIOR_SIGMA_MASKS = 0.05
#: Default bounds of every shape coefficient (the core's ``SHAPE_RANGE``, ``fit_body``'s
#: default ``shape_bounds``).
SHAPE_RANGE = (0.5, 2.0)


def narrow_shape_family(model: BodyModel, groups: Any) -> tuple[NDArray[np.int64], tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """The shape family for thin data: each part's depth tied to its width and its taper
    held at 1 (SPEC 6's length and width), on top of ``groups`` (``fit_body``'s
    ``shape_groups``). Returns ``(shape_groups, shape_bounds)`` for :func:`fit_body`; the
    held tapers leave the normal equations (bounds lower = upper), so they stay exactly 1."""
    groups = np.asarray(groups, dtype=np.int64).reshape(-1, len(SHAPE_NAMES)).copy()
    width, depth, taper = (SHAPE_NAMES.index(k) for k in ("width", "depth", "taper"))
    # depth joins width's group (the same merge for a mirrored twin's depth)
    merged = {int(d): int(w) for d, w in zip(groups[:, depth], groups[:, width])}
    groups[:, depth] = [merged[int(d)] for d in groups[:, depth]]
    _, renumbered = np.unique(groups.reshape(-1), return_inverse=True)
    lower = np.full(model.n_shape, SHAPE_RANGE[0])
    upper = np.full(model.n_shape, SHAPE_RANGE[1])
    lower.reshape(-1, len(SHAPE_NAMES))[:, taper] = 1.0
    upper.reshape(-1, len(SHAPE_NAMES))[:, taper] = 1.0
    return renumbered.astype(np.int64), (lower, upper)


def limb_length_groups(model: BodyModel, groups: Any) -> NDArray[np.int64]:
    """``groups`` (``fit_body``'s ``shape_groups``) with the length coefficients of each
    limb's segments tied: a left or right part (``l_`` / ``r_``, as
    :meth:`BodyModel.mirrored_shape_groups`) that continues its parent's bone (a left or
    right part too, the child's offset along the parent's z axis, no rest turn: the
    forearm and hand under the upper arm, the shin under the thigh, not the foot) shares
    its parent's length, so a limb keeps the described proportions of its segments and
    only its overall length is fitted.

    Why: along a limb that does not bend in the fitted frames (the capsule figure's wrist
    never does; its knees are straight for most of a 5-frame window) the skin does not
    say where one segment ends and the next begins, and free lengths slide the joint along
    the bone to wherever the model's flesh best matches the subject's profile: the capsule
    figure's wrists 4-7 cm towards the elbow under a 1.6 times wider hand, its knees 13 cm
    down a 1.28 times longer thigh (``benches/README.md``, branch body6)."""
    table = np.asarray(groups, dtype=np.int64).reshape(-1, len(SHAPE_NAMES)).copy()
    description = model.to_dict()["parts"]
    length = SHAPE_NAMES.index("length")
    limb = [p["name"][:2] in ("l_", "r_") for p in description]
    index = {p["name"]: i for i, p in enumerate(description)}
    for i, part in enumerate(description):
        parent = index.get(part["parent"]) if part["parent"] is not None else None
        if parent is None or not (limb[i] and limb[parent]):
            continue
        along = part["offset"][0] == 0.0 and part["offset"][1] == 0.0 and part["offset"][2] > 0.0
        if along and np.array_equal(np.asarray(part["rest"]), np.eye(3)):
            # parents come first, so the parent's group already holds its own parent's
            old = table[i, length]
            table[table == old] = table[parent, length]
    _, renumbered = np.unique(table.reshape(-1), return_inverse=True)
    return renumbered.astype(np.int64)
