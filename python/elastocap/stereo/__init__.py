"""Stereo: least-squares matching and forward intersection (SPEC 7)."""

from elastocap.stereo.matching import PARAMETERS, Matches, MatchStatus, match_patches, noise_level

__all__ = ["PARAMETERS", "MatchStatus", "Matches", "match_patches", "noise_level"]
