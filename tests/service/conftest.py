"""Fixtures of the service tests (the helpers they use are in ``service_helpers``)."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest
from service_helpers import ServiceProcess, start_service


@pytest.fixture
def service_factory() -> Iterator[Callable[..., ServiceProcess]]:
    """Start services; every one is stopped (killed if need be) at the end."""
    started: list[ServiceProcess] = []

    def make(*args: str, **kw: object) -> ServiceProcess:
        svc = start_service(*args, **kw)
        started.append(svc)
        return svc

    try:
        yield make
    finally:
        for svc in started:
            svc.stop()


@pytest.fixture
def small_service(service_factory) -> ServiceProcess:
    """A service rendering the game scene on a tiny display, in process."""
    return service_factory(
        "--scene",
        "game",
        "--zones",
        "2",
        "--cols",
        "32",
        "--rows",
        "24",
        "--workers",
        "0",
        "--refresh",
        "30",
    )
