"""The articulated metaball body model (SPEC 6): skeleton, field, skin, silhouettes, fit.

See :class:`BodyModel` for the model and its description format and :func:`fit_body` for
the sparse Levenberg-Marquardt fit to points, silhouettes and joints.
"""

from elastocap.body.bvh import write_bvh
from elastocap.body.fit import BodyFit, BodyObservations, fit_body, silhouette_rays, silhouette_samples
from elastocap.body.model import SKIN_LEVEL, BodyModel, BodyState
from elastocap.body.track import BodyTrack, BodyTracker, track_body

__all__ = [
    "SKIN_LEVEL",
    "BodyFit",
    "BodyModel",
    "BodyObservations",
    "BodyState",
    "BodyTrack",
    "BodyTracker",
    "fit_body",
    "silhouette_rays",
    "silhouette_samples",
    "track_body",
    "write_bvh",
]
