"""Test-wide settings.

Under CI (``CI=true``) hypothesis runs derandomised: the same examples every run, so a
submission's result does not depend on which random examples a run happened to draw.
Locally it explores with fresh examples (and keeps failures in its database).
"""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
    settings.load_profile("ci")
