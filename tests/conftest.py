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
    """Nodes load their numba kernels in their setup, compiled there when numba's on-disk cache is
    cold (a fresh checkout, as in CI): tens of seconds each, several at once in a stack test, which
    could outlast the test's readiness wait. So the cache is filled first, by the warm-up `make setup`
    runs (``riskfield warmup``): the nodes' own setups, in this process; a no-op when it is done."""
    try:
        from riskfield.services.runtime.warmup import warm_up
    except ImportError:  # pragma: no cover - an install without the runtime's dependencies
        return
    warm_up(say=lambda line: print(line, flush=True))


@pytest.fixture(scope="session")
def router() -> Iterator[ZenohRouter]:
    """One in-process Python router for the whole test session (tests use distinct robot ids)."""
    with ZenohRouter() as r:
        yield r


@pytest.fixture
def router_endpoint(router: ZenohRouter) -> str:
    return router.endpoint
