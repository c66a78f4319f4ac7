"""Shared fixtures: a real Zenoh router session on a free loopback port; hypothesis settings."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest
from hypothesis import settings

from riskfield.testing import ZenohRouter

# Property tests are deterministic (the same examples on every run, so a red CI run is red on
# every machine) and carry no timing assertion (hypothesis' default 200 ms deadline fails
# them on a busy machine). HYPOTHESIS_PROFILE=explore draws new examples, for hunting bugs.
settings.register_profile("riskfield", derandomize=True, deadline=None, print_blob=True)
settings.register_profile("explore", deadline=None, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "riskfield"))


def _warm_compiled_filter() -> None:
    """A safety-filter node compiles the filter's numba kernel in its setup when numba's on-disk
    cache is cold (~20 s here, on a fresh checkout): fill the cache once, before a test starts one."""
    try:
        from riskfield.services.safety_filter.filter import SafetyFilter
    except ImportError:  # an install without the robot extra
        return
    SafetyFilter()


@pytest.fixture(scope="session")
def router() -> Iterator[ZenohRouter]:
    """One in-process Python router for the whole test session (tests use distinct robot ids)."""
    _warm_compiled_filter()
    with ZenohRouter() as r:
        yield r


@pytest.fixture
def router_endpoint(router: ZenohRouter) -> str:
    return router.endpoint
