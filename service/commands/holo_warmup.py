"""``holo-warmup``: compile every numba kernel ahead, once, with progress.

Examples
--------
holo-warmup                 # progress lines and a summary on stderr
holo-warmup --jsonl         # one JSON object per line on stdout (for a parent process)

Human mode writes one line per job to stderr, ``compiling kernels 7/15 render bsp
(1.2 s)`` (``cached`` instead of the time when nothing had to be compiled), and a
summary.  ``--jsonl`` writes ``{"event": "kernel", "done": i, "total": n, "name":
..., "seconds": s, "cached": bool, "kernels": k}`` per job, then ``{"event": "done", "total": n,
"compiled": k, "cached": m, "seconds": s, "kernels": K}``.  The kernels land in
numba's cache (``NUMBA_CACHE_DIR`` if set) and every later process loads them.

A full run (no ``--job``) also leaves a record beside the cache
(:func:`service.warmup.write_record`: its events, whether the cache was empty when
it started, and the cache files it left), so that ``make test`` can check a fresh
clone's own cold warm-up instead of compiling every kernel a second time.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from service.base.cli_args import int_range, plain_help
from service.base.signals import EXIT_RULE, end_with_parent, exit_now, interruptible
from service.kernel_cache import drop_stale, mark_warm
from service.warmup import COMPILE_GC_THRESHOLD, JOBS, cache_files, warm_up, write_record

if TYPE_CHECKING:
    from service.warmup import WarmupStep


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``holo-warmup``."""
    p = argparse.ArgumentParser(
        prog="holo-warmup",
        description="Compile (or load from numba's cache) every numba kernel the render "
        "service, the Galilean stage and the game use, for the types they are called "
        "with, so that no later process waits on the compiler. The first run on a "
        "machine takes a few minutes; later runs take seconds.",
        epilog=f"The cache is numba's: NUMBA_CACHE_DIR if set, else __pycache__ next to "
        f"each module. {plain_help(EXIT_RULE)}",
    )
    p.add_argument("--jsonl", action="store_true",
                   help="one JSON object per line on stdout instead of progress on stderr")
    p.add_argument("--processes", type=int_range(1, 2), default=2, metavar="N",
                   help="2 (default): on an empty cache, a second process compiles the "
                   "Galilean stage's kernels meanwhile, then shares the other jobs; 1: one "
                   "process")
    p.add_argument("--job", action="append", choices=list(JOBS), metavar="NAME",
                   help="run only this job (repeat it); one of: " + "; ".join(JOBS))
    p.add_argument("--nice", type=int_range(0, 19), default=0, metavar="N",
                   help="lower this process's priority by N first (0-19; 0: as is), as a "
                   "service's background compile does, so that it takes only idle CPU")
    p.add_argument("--parent-pid", type=int, default=0, help=argparse.SUPPRESS)
    # warm_up's second process: wait for a line on stdin before this job (its parent
    # is still compiling the render kernels that job uses)
    p.add_argument("--hold-before", choices=list(JOBS), help=argparse.SUPPRESS)
    # warm_up's second process: run a HERE job only if claimed first in this folder
    # (its parent takes them from the same folder)
    p.add_argument("--share", type=Path, help=argparse.SUPPRESS)
    return p


def _human(step: WarmupStep) -> None:
    how = "cached" if step.cached else f"{step.seconds:.1f} s"
    word = "loading" if step.cached else "compiling"
    print(f"{word} kernels {step.done}/{step.total} {step.name} ({how})", file=sys.stderr,
          flush=True)


def _event(step: WarmupStep) -> dict:
    return {"event": "kernel", "done": step.done, "total": step.total, "name": step.name,
            "seconds": round(step.seconds, 3), "cached": step.cached, "kernels": step.kernels}


def _drop_stale(jsonl: bool) -> None:
    """Drop cached kernels built before a change to a module they use (service.kernel_cache)."""
    stale = drop_stale()
    if not stale:
        return
    changed = sorted({m for kernel in stale for m in kernel.changed})
    if jsonl:
        print(json.dumps({"event": "stale", "dropped": len(stale), "changed": changed}),
              flush=True)
    else:
        more = f" and {len(changed) - 4} more" if len(changed) > 4 else ""
        print(f"holo-warmup: {len(stale)} cached kernels predate a change to "
              f"{', '.join(changed[:4])}{more}; compiling them again", file=sys.stderr,
              flush=True)


def _run(args: argparse.Namespace) -> int:
    # the collector as :func:`warm_up` sets it, for the whole command: it restores
    # what it found, and the default would then collect every object numba made
    # (0.4 s at the end of each process) just before the process ends
    gc.set_threshold(*COMPILE_GC_THRESHOLD)
    if not args.jsonl:
        print("holo-warmup: compiling numba kernels (a few minutes the first time, "
              "seconds once cached)", file=sys.stderr, flush=True)
    _drop_stale(args.jsonl)
    empty = not cache_files()
    events: list[dict] = []

    def progress(step: WarmupStep) -> None:
        events.append(_event(step))
        if args.jsonl:
            print(json.dumps(events[-1]), flush=True)
        else:
            _human(step)

    def before_job(name: str) -> None:
        if name == args.hold_before:
            sys.stdin.readline()  # the parent's release, or end of file if it is gone

    report = warm_up(progress, args.processes, args.job, before_job, args.share)
    if args.job is None:  # only every job's kernels make the cache warm
        mark_warm()  # holo-service then skips its own warm-up child (service.readiness)
    done = {"event": "done", "total": report.total, "compiled": report.compiled,
            "cached": report.cached, "seconds": round(report.seconds, 3),
            "kernels": report.kernels}
    if args.job is None:  # a full warm-up: what a later process may check (tests/warmup)
        write_record(empty, [*events, done])
    if args.jsonl:
        print(json.dumps(done), flush=True)
    elif report.compiled == 0:
        print(f"holo-warmup: all {report.total} jobs cached ({report.kernels} kernels), "
              f"{report.seconds:.1f} s", file=sys.stderr)
    else:
        print(f"holo-warmup: compiled {report.compiled} of {report.total} jobs "
              f"({report.kernels} kernels) in {report.seconds:.1f} s; later starts load "
              f"them from the cache", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit status."""
    args = build_parser().parse_args(argv)
    if args.parent_pid:
        # warm_up's second process: a parent killed outright (SIGKILL, a test's
        # timeout) would leave it compiling for minutes.  SIGKILL, not SIGTERM: a
        # compile holds the interpreter until its kernel is done, and numba writes
        # each cache file whole (a temporary file, then a rename)
        end_with_parent(args.parent_pid, signal.SIGKILL)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as holo-service, before numba
    if args.nice:
        os.nice(args.nice)  # the second process, started later, inherits it
    return interruptible("holo-warmup", lambda: _run(args))


def cli(argv: list[str] | None = None) -> NoReturn:
    """The ``holo-warmup`` command (and its second process): :func:`main`, then no teardown.

    Numba's cache files are written whole and the record by a rename before
    :func:`main` returns, so the interpreter's teardown (1-2.4 s of collecting
    numba's objects in each process after a cold warm-up) is skipped.
    """
    exit_now(main(argv))


if __name__ == "__main__":
    cli()
