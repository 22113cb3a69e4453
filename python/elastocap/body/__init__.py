"""The articulated metaball body model (SPEC 6): skeleton, field, skin, silhouettes, fit.

See :class:`BodyModel` for the model and its description format and :func:`fit_body` for
the sparse Levenberg-Marquardt fit to points, silhouettes and joints.
"""

from elastocap.body.fit import BodyFit, BodyObservations, fit_body, silhouette_rays
from elastocap.body.model import SKIN_LEVEL, BodyModel, BodyState

__all__ = [
    "SKIN_LEVEL",
    "BodyFit",
    "BodyModel",
    "BodyObservations",
    "BodyState",
    "fit_body",
    "silhouette_rays",
]
