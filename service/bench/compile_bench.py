"""Cold compile benchmark: ``holo-bench compile --out DIR``.

What a new user pays before the first frame: every warm-up job
(:data:`service.warmup.JOBS`) run from an empty numba cache, in a child process
with a temporary ``NUMBA_CACHE_DIR`` (removed afterwards; the user's cache is never
touched).  The child runs the jobs one after the other, in :data:`JOBS` order, and
times

* each job: wall seconds and CPU seconds (the process's, numba's threads included),
  and whether a cold service compiles it before its first frame (``first_frame``;
  their CPU seconds summed as ``first_frame_cpu_s``);
* each kernel signature it compiled: CPU seconds of the compiling thread
  (``time.thread_time``) between numba's ``numba:compile`` start and end events,
  minus the kernels compiled inside it (a kernel calling another compiles it
  first), so each signature is counted once.

With ``--whole`` (the default unless ``--job`` picks jobs) a second child then runs
``holo-warmup`` as a user does (two processes on an empty cache) into another
empty cache: its wall and CPU seconds are the budget's figure.  CPU seconds are
the less load-sensitive measure; wall seconds on a busy machine stretch with the
load (the 1-minute load average is recorded at start and end).

Writes ``DIR/compile_jobs.csv``, ``DIR/compile_kernels.csv``, ``DIR/compile.json``
(totals, the budget and which jobs exceed it) and ``DIR/compile.png``.  The budget
(issue 29): the whole warm-up <= :data:`WHOLE_BUDGET_S` wall seconds on 2 quiet
cores, no job over :data:`JOB_BUDGET_S`.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from numba.core import event
from numba.core.event import Listener

from service.base.cli_args import exit_rule_epilog
from service.base.errors import HoloError
from service.bench.rows import write_csv
from service.numba_patches import apply_all
from service.warmup import JOBS, cache_counts, fewer_collections
from service.warmup_job import Kit

#: Budget for the whole cold ``holo-warmup``, wall seconds on 2 quiet cores.
WHOLE_BUDGET_S = 60.0
#: Budget for one warm-up job from an empty cache, wall seconds.
JOB_BUDGET_S = 15.0
#: Top-level packages whose kernels are listed (numba's own overloads count in theirs).
OURS = ("service", "drivers", "game", "sim_devices")
#: Kernels shown in the chart's second panel (the costliest).
TOP_KERNELS = 15


class _CompileTimer(Listener):
    """A ``numba:compile`` listener: own CPU and wall seconds per kernel signature.

    Only our kernels are listed (:data:`OURS`); numba's own overloads compiled
    inside one count in its seconds.

    Attributes
    ----------
    rows : list of dict
        One per compile that finished: ``kernel``, ``signature``, ``cpu_s``,
        ``wall_s`` (nested compiles subtracted), ``job`` (set by the caller).
    """

    def __init__(self) -> None:
        self.rows: list[dict] = []
        self.job = ""
        self._stack: list[list[float]] = []  # [cpu0, wall0, nested cpu, nested wall]

    def on_start(self, event) -> None:  # noqa: ANN001 -- numba's Event
        self._stack.append([time.thread_time(), time.perf_counter(), 0.0, 0.0])

    def on_end(self, event) -> None:  # noqa: ANN001
        cpu0, wall0, in_cpu, in_wall = self._stack.pop()
        cpu, wall = time.thread_time() - cpu0, time.perf_counter() - wall0
        d = event.data["dispatcher"]
        if d.py_func.__module__.split(".")[0] not in OURS:
            # numba's own overloads (array constructors, string helpers): part of
            # the kernel that needed them, not subtracted from it
            if self._stack:
                self._stack[-1][2] += in_cpu
                self._stack[-1][3] += in_wall
            return
        if self._stack:
            self._stack[-1][2] += cpu
            self._stack[-1][3] += wall
        args = ", ".join(str(a) for a in event.data["args"])
        self.rows.append({"job": self.job, "kernel": f"{d.py_func.__module__}.{d.__name__}",
                          "signature": args[:160], "cpu_s": round(cpu - in_cpu, 3),
                          "wall_s": round(wall - in_wall, 3)})


def child(jobs: list[str]) -> dict:
    """In the child (an empty ``NUMBA_CACHE_DIR``): run ``jobs`` in order, timing each.

    Returns ``{"jobs": [{job, wall_s, cpu_s, kernels}], "kernels": [...]}``.
    """
    apply_all()  # as holo-warmup does
    timer = _CompileTimer()
    event.register("numba:compile", timer)
    kit, out = Kit(), []
    with fewer_collections():  # as holo-warmup does
        for name in jobs:
            timer.job = name
            misses0 = cache_counts()[1]
            t0, c0 = time.perf_counter(), time.process_time()
            JOBS[name].run(kit)
            out.append({"job": name, "wall_s": round(time.perf_counter() - t0, 3),
                        "cpu_s": round(time.process_time() - c0, 3),
                        "kernels": cache_counts()[1] - misses0,
                        "first_frame": JOBS[name].first_frame})
    return {"jobs": out, "kernels": timer.rows}


def _cold_env(cache: str) -> dict[str, str]:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    return env


def per_job(jobs: list[str]) -> dict:
    """:func:`child` in a subprocess on an empty temporary cache."""
    with tempfile.TemporaryDirectory(prefix="holo-compile-") as cache:
        cmd = [sys.executable, "-m", "service.bench.compile_bench", "--child",
               *(f"--job={j}" for j in jobs)]
        proc = subprocess.run(cmd, env=_cold_env(cache), capture_output=True, text=True,
                              check=False)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise HoloError(f"the cold compile child exited {proc.returncode}: {last}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def whole() -> dict:
    """``holo-warmup`` as a user runs it (two processes) on an empty cache: wall, CPU s."""
    with tempfile.TemporaryDirectory(prefix="holo-compile-") as cache:
        t0 = time.perf_counter()
        c0 = os.times()
        proc = subprocess.run([sys.executable, "-m", "service.commands.holo_warmup", "--jsonl"],
                              env=_cold_env(cache), capture_output=True, text=True,
                              check=False)
        c1 = os.times()
    if proc.returncode != 0:
        raise HoloError(f"holo-warmup exited {proc.returncode}")
    cpu = (c1.children_user - c0.children_user) + (c1.children_system - c0.children_system)
    return {"wall_s": round(time.perf_counter() - t0, 3), "cpu_s": round(cpu, 3)}


def run(out_dir: Path, jobs: list[str], with_whole: bool) -> dict:
    """Measure, write the CSVs, JSON and chart; return the JSON's content."""
    load0 = os.getloadavg()[0]
    res = per_job(jobs)
    res["whole"] = whole() if with_whole else None
    res["load"] = [round(load0, 2), round(os.getloadavg()[0], 2)]
    res["cores"] = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    res["budget"] = {"whole_wall_s": WHOLE_BUDGET_S, "job_wall_s": JOB_BUDGET_S}
    res["over_budget"] = [j["job"] for j in res["jobs"] if j["wall_s"] > JOB_BUDGET_S]
    res["total_cpu_s"] = round(sum(j["cpu_s"] for j in res["jobs"]), 3)
    # what a cold service compiles before its first frame (service.warmup.FIRST_FRAME_JOBS)
    res["first_frame_cpu_s"] = round(sum(j["cpu_s"] for j in res["jobs"] if j["first_frame"]), 3)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_csv(res["jobs"], out_dir / "compile_jobs.csv")
    write_csv(sorted(res["kernels"], key=lambda r: -r["cpu_s"]), out_dir / "compile_kernels.csv")
    (out_dir / "compile.json").write_text(json.dumps(res, indent=1) + "\n")
    chart(res, out_dir / "compile.png")
    return res


def chart(res: dict, path: Path) -> None:
    """Per job wall and CPU seconds (budget line), and the costliest kernels' CPU seconds."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    jobs = res["jobs"]
    kernels = sorted(res["kernels"], key=lambda r: -r["cpu_s"])[:TOP_KERNELS]
    fig, (a, b) = plt.subplots(2, 1, figsize=(9, 3 + 0.28 * (len(jobs) + len(kernels))),
                               gridspec_kw={"height_ratios": [max(len(jobs), 1),
                                                              max(len(kernels), 1)]})
    y = range(len(jobs))
    a.barh([v - 0.2 for v in y], [j["wall_s"] for j in jobs], 0.4, label="wall s")
    a.barh([v + 0.2 for v in y], [j["cpu_s"] for j in jobs], 0.4, label="CPU s")
    a.axvline(JOB_BUDGET_S, color="red", ls="--", label=f"budget {JOB_BUDGET_S:.0f} s a job")
    a.set_yticks(list(y), [j["job"] for j in jobs], fontsize=7)
    a.invert_yaxis()
    w = res.get("whole")
    head = (f"whole holo-warmup {w['wall_s']:.0f} s wall, {w['cpu_s']:.0f} s CPU"
            if w else "jobs one after the other")
    a.set_title(f"Cold compile per warm-up job ({head}; load {res['load'][0]}-"
                f"{res['load'][1]})", fontsize=9)
    a.set_xlabel("seconds from an empty numba cache")
    a.legend(fontsize=7)
    b.barh(range(len(kernels)), [k["cpu_s"] for k in kernels], color="tab:orange")
    b.set_yticks(range(len(kernels)), [k["kernel"].removeprefix("service.") for k in kernels],
                 fontsize=7)
    b.invert_yaxis()
    b.set_xlabel("CPU seconds per kernel signature (nested compiles subtracted)")
    b.set_title(f"The {len(kernels)} costliest kernel compiles", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``holo-bench compile``."""
    p = argparse.ArgumentParser(
        prog="holo-bench compile",
        description="Seconds (wall and CPU) each warm-up job and each numba kernel takes "
        "to compile from an empty cache (a temporary NUMBA_CACHE_DIR in a child process; "
        "your cache is not touched), and the whole holo-warmup's.",
        epilog=exit_rule_epilog())
    p.add_argument("--out", metavar="DIR", type=Path, default=Path("bench-out/compile"),
                   help="directory for the CSVs, JSON and chart (default: %(default)s)")
    p.add_argument("--job", action="append", choices=list(JOBS), metavar="NAME",
                   help="time only this warm-up job (repeat it; each from an empty cache "
                   "with the jobs before it); one of: " + "; ".join(JOBS))
    p.add_argument("--whole", action=argparse.BooleanOptionalAction, default=None,
                   help="also time a whole cold holo-warmup (default: on unless --job)")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point."""
    args = build_parser().parse_args(argv)
    jobs = [n for n in JOBS if args.job is None or n in args.job]
    if args.child:
        print(json.dumps(child(jobs)), flush=True)
        return 0
    with_whole = args.job is None if args.whole is None else args.whole
    res = run(args.out, jobs, with_whole)
    for j in res["jobs"]:
        flag = "  OVER BUDGET" if j["wall_s"] > JOB_BUDGET_S else ""
        print(f"{j['job']:45s} {j['wall_s']:7.1f} s wall {j['cpu_s']:7.1f} s CPU "
              f"{j['kernels']:4d} kernels{flag}")
    print(f"{'jobs one after the other':45s} {sum(j['wall_s'] for j in res['jobs']):7.1f} s "
          f"wall {res['total_cpu_s']:7.1f} s CPU (load {res['load'][0]}-{res['load'][1]})")
    print(f"{'of which first-frame jobs (a cold service)':45s} {'':7s}        "
          f"{res['first_frame_cpu_s']:7.1f} s CPU")
    if res["whole"]:
        w = res["whole"]
        flag = "  OVER BUDGET" if w["wall_s"] > WHOLE_BUDGET_S else ""
        print(f"{'whole holo-warmup (2 processes)':45s} {w['wall_s']:7.1f} s wall "
              f"{w['cpu_s']:7.1f} s CPU{flag}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
