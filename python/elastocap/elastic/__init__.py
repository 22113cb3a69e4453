"""The element-free elastic model (SPEC 4) and its fit through a sequence (SPEC 5): MLS
shape functions, nodal-integration stiffness, the ElasticModel, fit_sequence and its option objects (TrackTerms, SelfIntersection, SilhouetteTerm, StiffStage,
StoppingRules)."""

from elastocap.elastic.mls import MLSShapeFunctions, mls_shape_functions
from elastocap.elastic.efg import stiffness_matrix
from elastocap.elastic.model import ElasticModel, StaticSolution
from elastocap.elastic.fit import FrameFit, SequenceFit, fit_sequence
from elastocap.elastic.fit_options import SelfIntersection, SilhouetteTerm, StiffStage, StoppingRules
from elastocap.elastic.track_terms import TrackTerms

__all__ = [
    "ElasticModel", "FrameFit", "MLSShapeFunctions", "SelfIntersection", "SequenceFit", "SilhouetteTerm", "StaticSolution",
    "StiffStage", "StoppingRules", "TrackTerms", "fit_sequence", "mls_shape_functions", "stiffness_matrix",
]
