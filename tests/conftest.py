"""Fixtures of every test: started processes and services, and a check for leftovers.

After each test, :func:`no_leftovers` waits briefly for the threads, child
processes and sockets of ``zmq.Context.instance()`` the test started to end, and
fails the test's teardown naming any still there: a test that leaves a service
running or a thread spinning slows or breaks the tests after it.

Under pytest-xdist (``make test`` runs ``pytest -n 2``) the controller does the
session's one-off work before its workers start: it drops stale kernels, runs
``holo-warmup`` when the cache is not warm, and makes the cold warm-up
(:class:`testkit.ColdWarmup`) that the workers attach to.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zmq

sys.path.insert(0, str(Path(__file__).parent))  # ``import testkit`` from any folder

from testkit import (  # noqa: E402
    ROOT,
    ColdWarmup,
    Proc,
    ServiceProcess,
    children_of,
    start_service,
    wait_until,
)

#: Seconds a test's threads, children and sockets get to end after it.
LEFTOVER_GRACE_S = 5.0
#: Tests that need a cold warm-up (:class:`testkit.ColdWarmup`), started at collection.
COLD_WARMUP_TESTS = "tests/warmup/test_warmup_cache.py"
_COLD = pytest.StashKey[ColdWarmup]()
#: The ``workerinput`` key naming the controller's cold warm-up folder (pytest-xdist).
_COLD_FOLDER = "holo_cold_warmup"


def _xdist_worker(config: pytest.Config) -> bool:
    return hasattr(config, "workerinput")


def _xdist_controller(config: pytest.Config) -> bool:
    return config.pluginmanager.has_plugin("dsession")


def _may_select(config: pytest.Config, test_file: str) -> bool:
    """Whether the session's arguments take in ``test_file`` (``-k`` and ``-m`` aside)."""
    target = (ROOT / test_file).resolve()
    for arg in config.args:
        path = (Path(config.invocation_params.dir) / arg.split("::")[0]).resolve()
        if path == target or path in target.parents:
            return True
    return False


_STALE = pytest.StashKey[list]()


def pytest_sessionstart(session: pytest.Session) -> None:
    """Drop stale cached kernels, and compile what the sources now need, before any test.

    Stale: older than a module they inline (service.kernel_cache); numba would load
    them and the tests would run code no longer in the tree.  When the sources
    changed since the last warm-up (or kernels were dropped), ``holo-warmup`` runs
    first (2 s when everything is cached), so no test compiles a kernel inside its
    own deadline: a service a test starts would miss its ready deadline on a busy
    machine.  ``make test`` runs the warm-up just before, so this finds it warm.
    """
    from service.kernel_cache import drop_stale, is_warm

    config = session.config
    if _xdist_worker(config):
        return  # the controller did it before starting this worker
    stale = config.stash[_STALE] = drop_stale()
    if stale or not is_warm():
        subprocess.run([sys.executable, "-m", "service.commands.holo_warmup"], check=False,
                       timeout=1800)
    if _xdist_controller(config) and _may_select(config, COLD_WARMUP_TESTS):
        cold = config.stash[_COLD] = ColdWarmup()
        cold.announce()


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node) -> None:
    """Tell each xdist worker (``node``: its controller) where the cold warm-up is."""
    cold = node.config.stash.get(_COLD, None)
    if cold is not None:
        node.workerinput[_COLD_FOLDER] = str(cold.folder)


def pytest_report_header(config: pytest.Config) -> list[str]:
    """Say how many stale kernels the session dropped (the warm-up compiled them again)."""
    stale = config.stash.get(_STALE, [])
    if not stale:
        return []
    changed = sorted({m for kernel in stale for m in kernel.changed})
    return [f"numba cache: dropped {len(stale)} kernels built before a change to "
            f"{', '.join(changed)}; holo-warmup compiled them again"]


@pytest.hookimpl(tryfirst=True)
def pytest_collection_finish(session: pytest.Session) -> None:
    """Start the cold warm-up in the background if any selected test needs it.

    An xdist worker attaches to the controller's instead (or, when the controller
    made none, starts one in :func:`cold_warmup` if it gets such a test).
    """
    config = session.config
    if _xdist_worker(config):
        folder = config.workerinput.get(_COLD_FOLDER)
        if folder is not None:
            config.stash[_COLD] = ColdWarmup.attach(folder)
        return
    if any(item.nodeid.startswith(COLD_WARMUP_TESTS) for item in session.items):
        config.stash[_COLD] = ColdWarmup()


def pytest_sessionfinish(session: pytest.Session) -> None:
    """Stop the cold warm-up (if it still runs) and remove its cache."""
    cold = session.config.stash.get(_COLD, None)
    if cold is not None:
        cold.close()


@pytest.fixture(scope="session")
def cold_warmup(request: pytest.FixtureRequest) -> ColdWarmup:
    """The background cold warm-up (started now if collection did not start it)."""
    cold = request.config.stash.get(_COLD, None)
    if cold is None:
        cold = request.config.stash[_COLD] = ColdWarmup()
    return cold


#: Threads libraries keep for the life of the process (pyzmq's zero-copy garbage collector).
LIFELONG_THREAD_MODULES = ("zmq.",)


def _threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate()
            if t.is_alive() and not type(t).__module__.startswith(LIFELONG_THREAD_MODULES)}


def _sockets() -> set[zmq.Socket]:
    return {s for s in list(zmq.Context.instance()._sockets) if not s.closed}


def _leftovers(threads: set, children: set, sockets: set) -> list[str]:
    found = [f"thread {t.name!r}" for t in _threads() - threads]
    found += [f"child process {pid}" for pid in children_of(os.getpid()) - children]
    found += [f"open ZeroMQ socket {s.type!r}" for s in _sockets() - sockets]
    return found


@pytest.fixture(autouse=True)
def no_leftovers() -> Iterator[None]:
    """Fail a test that leaves threads, child processes or ZeroMQ sockets behind."""
    before = (_threads(), children_of(os.getpid()), _sockets())
    yield
    left = wait_until(lambda: not _leftovers(*before), LEFTOVER_GRACE_S)
    if not left:
        pytest.fail("left behind: " + ", ".join(_leftovers(*before)), pytrace=False)


@pytest.fixture
def procs() -> Iterator[Callable[..., Proc]]:
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


@pytest.fixture
def service_factory() -> Iterator[Callable[..., ServiceProcess]]:
    """Start services with ``service_factory(*args)``; every one is stopped at the end."""
    started: list[ServiceProcess] = []

    def make(*args: str, **kw) -> ServiceProcess:
        svc = start_service(*args, **kw)
        started.append(svc)
        return svc

    try:
        yield make
    finally:
        for svc in started:
            svc.stop()
