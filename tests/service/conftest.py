"""Fixtures of the service tests (shared helpers: ``tests/testkit.py``; the
``service_factory`` fixture: ``tests/conftest.py``)."""

from __future__ import annotations

import threading

import pytest
import zmq
from testkit import HANG_S, SMALL_SERVICE, ServiceProcess, start_service

from service.net.broker import Broker


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


@pytest.fixture
def broker():
    """A :class:`Broker` routing on its own thread (job timeout 60 s), and a requester.

    Yields ``(broker, front)``: ``front`` is a DEALER connected to its frontend.
    """
    ctx = zmq.Context()
    b = Broker(ctx, "tcp://127.0.0.1:*", "tcp://127.0.0.1:*", job_timeout_s=60)
    front = ctx.socket(zmq.DEALER)
    front.connect(b.front.getsockopt_string(zmq.LAST_ENDPOINT))
    thread = threading.Thread(target=b.run, daemon=True)
    thread.start()
    try:
        yield b, front
    finally:
        b.stop()
        thread.join(HANG_S)
        front.close(0)
        ctx.term()
