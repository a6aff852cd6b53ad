"""Fixtures of the command-line tests (helpers are in ``cli_helpers``)."""

from __future__ import annotations

import pytest
from cli_helpers import Proc


@pytest.fixture
def procs():
    """Start processes with ``procs(module, *args)``; every one is killed at the end."""
    started: list[Proc] = []

    def start(*args: str, **kw) -> Proc:
        proc = Proc(*args, **kw)
        started.append(proc)
        return proc

    try:
        yield start
    finally:
        for proc in started:
            proc.kill()
