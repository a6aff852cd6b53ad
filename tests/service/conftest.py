"""Fixtures of the service tests (shared helpers: ``tests/testkit.py``; the
``service_factory`` fixture: ``tests/conftest.py``)."""

from __future__ import annotations

import pytest
from testkit import SMALL_SERVICE, ServiceProcess


@pytest.fixture
def small_service(service_factory) -> ServiceProcess:
    """A service rendering the game scene on a tiny display, in process."""
    return service_factory(*SMALL_SERVICE)
