"""Shared pytest / hypothesis configuration.

Hypothesis runs derandomised by default so that the suite is reproducible run to run (a
failure found once is found every time); set ``HYPOTHESIS_PROFILE=explore`` to search with
fresh random seeds instead.
"""

import os

from hypothesis import HealthCheck, Phase, settings

# No 'explain' phase: it re-runs failing examples for coverage notes and costs seconds.
_PHASES = [Phase.explicit, Phase.reuse, Phase.generate, Phase.target, Phase.shrink]

settings.register_profile(
    "default",
    deadline=None,
    derandomize=True,
    print_blob=True,
    phases=_PHASES,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile(
    "explore",
    deadline=None,
    derandomize=False,
    print_blob=True,
    phases=_PHASES,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))
