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


@pytest.fixture(scope="session", autouse=True)
def _warm_compiled_kernels() -> None:
    """Nodes compile their numba kernels in their setup when numba's on-disk cache is cold (a fresh
    checkout, as in CI): the filter's ~20 s, mapping's ~24 s here. Several nodes of a stack test
    compiling at once on two cores could outlast the test's readiness wait, so the cache is filled
    once, in this process, before the first test."""
    try:
        from riskfield.services.safety_filter.filter import SafetyFilter
    except ImportError:  # an install without the robot extra
        pass
    else:
        SafetyFilter()
    try:
        from riskfield.services.mapping.mapper import Mapper
        from riskfield.services.mapping.settings import MappingSettings
    except ImportError:  # an install without the mapping extra
        return
    for output in ("2d", "3d"):
        Mapper(MappingSettings(output=output).mapper_config(), None).warm_up()


@pytest.fixture(scope="session")
def router() -> Iterator[ZenohRouter]:
    """One in-process Python router for the whole test session (tests use distinct robot ids)."""
    with ZenohRouter() as r:
        yield r


@pytest.fixture
def router_endpoint(router: ZenohRouter) -> str:
    return router.endpoint
