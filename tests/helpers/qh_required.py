"""Which outside services a test run must have: skipping them is allowed only off CI.

``make test`` (what CI runs) sets ``QUICKHEALTH_REQUIRE_SERVICES=1`` after installing the
PostgreSQL server and headless Chromium, so there a missing service fails its tests with one
line instead of letting the run pass silently.  A developer's plain ``pytest`` on a machine
without them skips those tests with the reason.
"""

from __future__ import annotations

import os

import pytest

ENV_VAR = "QUICKHEALTH_REQUIRE_SERVICES"


def required() -> bool:
    """True under ``make test``, in CI (``CI`` set) or as root (``make test`` installs them)."""
    return bool(os.environ.get(ENV_VAR) or os.environ.get("CI")) or os.geteuid() == 0


def unavailable(reason: str) -> None:
    """Fail (required) or skip (a developer's machine) a test whose service is missing."""
    if required():
        pytest.fail(f"{reason} ({ENV_VAR}/CI/root: this run must not skip it)", pytrace=False)
    pytest.skip(f"{reason} -- not required here, so the test skips")
