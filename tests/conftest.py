"""Shared test settings: hypothesis profiles (CI runs the larger one: ``CI=true``)."""

import os

from hypothesis import HealthCheck, settings

# derandomized: the same cases every run, so a result never depends on the draw
settings.register_profile("dev", max_examples=150, deadline=None, derandomize=True,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("ci", max_examples=1000, deadline=None, derandomize=True,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci" if os.environ.get("CI", "").lower() in ("1", "true", "yes") else "dev")
