"""Visual hulls: voxel grids, hierarchical carving, signed distance fields."""

from elastocap.hull.grid import Grid, space_seen_by
from elastocap.hull.carve import Hull, visual_hull
from elastocap.hull.phantoms import drop_phantoms
from elastocap.hull.sdf import SDF, signed_distance

__all__ = ["Grid", "Hull", "drop_phantoms", "SDF", "signed_distance", "space_seen_by", "visual_hull"]
