"""``holo-service-worker``: a render worker for a ``holo-service`` on another host.

``holo-service --worker-address tcp://0.0.0.0:5557 --curve-keys KEYS --workers 0``
on the render host, then on every other machine::

    holo-service-worker --connect tcp://render-host:5557 --curve-keys KEYS --warm-up

It checks its address and keys before it starts (one line, status 2), says where it
connects, renders the jobs the service's broker sends until Ctrl-C or SIGTERM (one
line with the jobs done, status 130 / 143).  The service starts its own local
workers with ``python -m service.net.worker`` (:func:`service.net.worker.main`).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from service.base.cli_args import endpoint, int_range
from service.base.signals import (
    EXIT_OK,
    EXIT_RULE,
    EXIT_USAGE,
    Interrupted,
    exit_status,
    raise_on_signals,
)

PROG = "holo-service-worker"

#: The files of a ``holo-service-keys`` folder a worker reads (CurveZMQ client).
WORKER_KEYS = ("server.key", "client.key_secret")


def build_parser() -> argparse.ArgumentParser:
    """The worker's options."""
    ap = argparse.ArgumentParser(
        prog=PROG,
        description="A render worker for a holo-service on another host (started there "
        "with --worker-address and --workers 0): it connects to the service's broker and "
        "renders the jobs it is sent until stopped.",
        epilog=EXIT_RULE,
    )
    ap.add_argument("--connect", metavar="ADDR", default="tcp://127.0.0.1:5557",
                    type=endpoint(bind=False),
                    help="the service's worker address, its --worker-address "
                    "(default tcp://127.0.0.1:5557)")
    ap.add_argument("--curve-keys", metavar="DIR", default=None,
                    help="the service's holo-service-keys folder (server.key and "
                    "client.key_secret), when it runs with --curve-keys")
    ap.add_argument("--warm-up", action="store_true",
                    help="load or compile the render kernels before taking jobs")
    ap.add_argument("--nice", type=int_range(0, 19), default=5, metavar="N",
                    help="lower the worker's CPU priority by N, 0-19 (default 5)")
    return ap


def keys_problem(directory: str | None) -> str | None:
    """What a worker's ``--curve-keys`` folder lacks, or None."""
    if directory is None:
        return None
    missing = [name for name in WORKER_KEYS if not (Path(directory) / name).is_file()]
    if missing:
        return (f"--curve-keys {directory}: no {' or '.join(missing)} (copy them from "
                "the service's holo-service-keys folder)")
    return None


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``holo-service-worker``; returns the exit status."""
    args = build_parser().parse_args(argv)
    problem = keys_problem(args.curve_keys)
    if problem:
        print(f"{PROG}: {problem}", file=sys.stderr)
        return EXIT_USAGE
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # see service.commands.holo_service.main
    # deferred: --help and usage errors answer before pygame and the numba kernels load
    from service.net.worker import Worker
    from service.process import setup_frame_process

    setup_frame_process()
    if args.nice > 0:
        os.nice(args.nice)
    worker = Worker(args.connect, args.curve_keys)
    try:
        with raise_on_signals():
            if args.warm_up:
                # deferred: --help answers before the numba kernels load
                from service.render.pipeline import warm_up

                print(f"{PROG}: loading the render kernels", file=sys.stderr, flush=True)
                warm_up()
            print(f"{PROG}: taking jobs from {args.connect} (pid {os.getpid()}); "
                  "Ctrl-C stops", file=sys.stderr, flush=True)
            worker.run()
    except Interrupted as stop:
        print(f"{PROG}: stopped ({stop}) after {worker.jobs} jobs", file=sys.stderr)
        return exit_status(stop.signum, EXIT_OK)
    finally:
        worker.close()
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
