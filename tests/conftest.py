"""Suite-wide settings: the Hypothesis profiles and the fast tier's markers (registered in
pyproject.toml).

Markers: ``runtime`` for tests that start a real distributed run or its processes (sim server,
robot agents, the central process, a Zenoh router or client process beside a run), ``slow`` for any
other test that takes more than about 5 s. The developer loop leaves both out::

    .venv/bin/python -m pytest -m "not runtime and not slow" -n 2

and the full suite (``.ci/run``) runs everything.

Hypothesis profiles: ``ci`` (selected when the environment has ``CI=true`` or ``CI=1``) derandomizes,
so every CI run draws the same examples, and uses no example database, so a run does not depend on
what earlier runs found; ``dev`` (otherwise) draws fresh examples each run and keeps the database.
Both print the ``@reproduce_failure`` blob of a failing example and have no wall-clock limits
(deadline, too-slow health check). ``HYPOTHESIS_PROFILE=NAME`` picks one by name.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

from hypothesis import HealthCheck, settings

# No wall-clock budgets (the suite must pass on a loaded machine): no per-example deadline, no
# too-slow health check; the tests that set their own settings keep their max_examples.
UNTIMED = {"deadline": None, "suppress_health_check": [HealthCheck.too_slow], "print_blob": True}
settings.register_profile("dev", **UNTIMED)
settings.register_profile("ci", derandomize=True, database=None, **UNTIMED)


def hypothesis_profile(environ: Mapping[str, str]) -> str:
    """The profile to load: ``HYPOTHESIS_PROFILE`` if set, else ``ci`` under ``CI=true``, else ``dev``."""
    if environ.get("HYPOTHESIS_PROFILE"):
        return environ["HYPOTHESIS_PROFILE"]
    return "ci" if environ.get("CI", "").strip().lower() in ("1", "true", "yes") else "dev"


PROFILE = hypothesis_profile(os.environ)
settings.load_profile(PROFILE)


def pytest_report_header(config) -> str:
    return f"hypothesis profile: {PROFILE}"
