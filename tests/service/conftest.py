"""Fixtures of the service tests (shared helpers: ``tests/testkit.py``; the
``service_factory`` fixture: ``tests/conftest.py``)."""

from __future__ import annotations

import pytest
from testkit import SMALL_SERVICE, ServiceProcess, start_service


@pytest.fixture
def small_service(service_factory) -> ServiceProcess:
    """A service rendering the game scene on a tiny display, in process."""
    return service_factory(*SMALL_SERVICE)


@pytest.fixture(scope="module")
def svc():
    """One such service for every test of a module (each test leaves it serving).

    A module that needs another service defines its own ``svc``.
    """
    s = start_service(*SMALL_SERVICE)
    try:
        yield s
    finally:
        s.stop()
