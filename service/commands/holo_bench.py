"""``holo-bench``: run one of the project's benchmarks by name.

Each benchmark writes CSV or JSON plus matplotlib charts to ``--out``; see the
README's "Benchmarks" section for how to read them.  A bad option value is a one-line
usage error (exit status 2) before any work; a setting the benchmark itself refuses
is one line too (``holo-bench NAME: error: ...``, exit status 2).  Ctrl-C or SIGTERM
stops any benchmark with one line and exit status 130 / 143, the rule of
:mod:`service.base.signals`.
"""

from __future__ import annotations

import importlib
import os
import sys

from service.base.cli_args import output_problem
from service.base.errors import HoloError
from service.base.signals import EXIT_RULE, EXIT_USAGE, interruptible
from service.kernel_cache import drop_stale
from service.process import setup_frame_process

BENCHES = {
    "render": (
        "service.bench.render_bench",
        "occlusion methods x zone counts: ms vs % pixels unlike ray casting",
    ),
    "light": (
        "service.bench.light_bench",
        "specular per polygon / vertex / point: ms vs intensity error",
    ),
    "galilean": (
        "service.bench.galilean_bench",
        "Galilean stage: thought experiments and the order x interval sweep",
    ),
    "quality": (
        "service.bench.quality_bench",
        "--quality auto: calibrate its cost model; its error against the budget",
    ),
    "targets": (
        "service.bench.targets_bench",
        "open speed targets (zones, G(2) refresh, Galilean premise), ratios side by side",
    ),
    "service": (
        "service.bench.service_bench",
        "render service: transport overhead, round trip, workers, motion-to-photon",
    ),
    "chaos": (
        "service.bench.chaos_bench",
        "render workers killed and stopped every 5 s: longest gap between updates, jobs",
    ),
    "filters": ("service.bench.filters_bench", "pose filters: jitter vs lag"),
    "latency": (
        "service.bench.latency_bench",
        "device drivers: byte arrival to published event (p50/p99)",
    ),
    "decoders": ("service.bench.decoders_bench", "serial protocol decoders: MB/s"),
    "lod": (
        "service.bench.lod_bench",
        "level of detail: triangles vs image error vs ms; a 200-object crowd, LOD on/off",
    ),
    "lod-stall": (
        "service.bench.lod_stall_bench",
        "frame ms while an LOD chain builds: in a thread vs a child process vs none",
    ),
    "billboard": (
        "service.bench.billboard_bench",
        "billboard clouds: planes and build time vs EPS; error close up and grazing",
    ),
    "sird": (
        "service.bench.sird_bench",
        "autostereograms: ms per frame vs decoded depth and streaks, dot stability",
    ),
    "compile": (
        "service.bench.compile_bench",
        "cold compile: wall and CPU seconds per warm-up job and kernel, empty cache",
    ),
    "lookingglass": (
        "service.bench.lookingglass_bench",
        "Looking Glass interleave: ms per 2560x1600 panel from 45 views, by threads",
    ),
    "report": (
        "service.bench.report",
        "every benchmark at one size into one self-contained OUT/index.html",
    ),
}


def usage() -> str:
    """The help text listing the benchmarks."""
    lines = [
        "usage: holo-bench NAME [options]   (holo-bench NAME --help for its options)",
        "",
        "benchmarks:",
    ]
    lines += [f"  {name:10s} {text}" for name, (_, text) in BENCHES.items()]
    lines += ["", EXIT_RULE,
              "1: quality found a frame over its error budget, or report ran no benchmark."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Dispatch to a benchmark's ``main``; return the exit status."""
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    if not argv:  # a NAME is required: usage on stderr, status 2, as argparse does
        print(f"{usage()}\nholo-bench: error: name a benchmark", file=sys.stderr)
        return EXIT_USAGE
    if argv[0] not in BENCHES:
        print(f"holo-bench: error: unknown benchmark {argv[0]!r}; known: "
              f"{', '.join(BENCHES)} (holo-bench --help says what each does)", file=sys.stderr)
        return EXIT_USAGE
    # as holo-service does: OpenMP threads that spin while waiting steal the core
    # the measured code needs (see service.commands.holo_service.main); set before numba loads
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    setup_frame_process()  # heap reuse and one BLAS thread (service.process)
    prog = f"holo-bench {argv[0]}"
    problem = _out_problem(argv[1:])
    if problem:  # before any work: a typo in --out must not cost a whole benchmark
        print(f"{prog}: error: --out {problem}", file=sys.stderr)
        return EXIT_USAGE
    stale = drop_stale()  # time the code in the tree, not kernels cached before an edit
    if stale:
        print(f"{prog}: {len(stale)} cached kernels predate a change to a module they use; "
              "they compile again when first used", file=sys.stderr)
    return interruptible(prog, lambda: _run(prog, BENCHES[argv[0]][0], argv[1:]))


def _out_problem(argv: list[str]) -> str | None:
    """Why the ``--out`` folder in a benchmark's ``argv`` cannot be written, or None.

    Every benchmark's ``--out`` names a folder (made if missing); one not given
    (each benchmark's default) is left to the benchmark.
    """
    for i, word in enumerate(argv):
        value = None
        if word == "--out" and i + 1 < len(argv):
            value = argv[i + 1]
        elif word.startswith("--out="):
            value = word.split("=", 1)[1]
        if value is not None and (problem := output_problem(value, folder=True)):
            return problem
    return None


def _run(prog: str, module_name: str, argv: list[str]) -> int:
    """Import and run one benchmark; a refused setting or file is one line and status 2."""
    try:
        module = importlib.import_module(module_name)
        return int(module.main(argv) or 0)
    except (HoloError, OSError) as exc:
        print(f"{prog}: error: {_message(exc)}", file=sys.stderr)
        return EXIT_USAGE


def _message(exc: Exception) -> str:
    """``"PATH: No such file or directory"`` for a file error, not ``"[Errno 2] ..."``."""
    if isinstance(exc, OSError) and exc.strerror:
        return f"{exc.filename}: {exc.strerror}" if exc.filename else exc.strerror
    return str(exc)


if __name__ == "__main__":
    sys.exit(main())
