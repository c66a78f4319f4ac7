"""Shared fixtures: a real Zenoh router session on a free loopback port."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from riskfield.testing import ZenohRouter


@pytest.fixture(scope="session")
def router() -> Iterator[ZenohRouter]:
    """One in-process Python router for the whole test session (tests use distinct robot ids)."""
    with ZenohRouter() as r:
        yield r


@pytest.fixture
def router_endpoint(router: ZenohRouter) -> str:
    return router.endpoint
