"""Point tracking (SPEC 7, issue 15): surface points followed through time in every camera
and across cameras, 3-D trajectories with covariances and flags."""

from elastocap.tracking.flags import TrackFlag
from elastocap.tracking.tracker import track_points
from elastocap.tracking.tracks import Tracks, load_tracks

__all__ = ["TrackFlag", "Tracks", "load_tracks", "track_points"]
