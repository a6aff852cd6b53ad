"""``holo-sird``: a single-image random-dot stereogram (autostereogram) from depth.

Examples
--------
holo-sird builtin:game --out game-sird.png
holo-sird depth-02.npy --out sird.png --method row --pattern colour --json

INPUT is a depth ``.npy`` (as ``holo-render`` writes it) or anything ``holo-render``
takes (its centre view is rendered first).  ``--json`` prints one object: method,
size, eye_sep_px, mu, near, far, separation_px [min, max], ms (the stereogram alone:
the median of several runs after a warm-up), constraints, broken, hidden.  Exit
status: 0; 2 for bad options or input (NaN depth, nothing in the depth map, an image
too narrow for the eye separation, mu above 1/2); 130 / 143 on Ctrl-C / SIGTERM.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import numpy as np

from service.autostereogram import (
    METHODS,
    SirdSettings,
    SirdWorkspace,
    broken_constraints,
    default_eye_sep,
    finite_range,
    make_pattern,
    stereogram,
)
from service.autostereogram.source import load_depth
from service.base.cli_args import (
    add_size_option,
    float_range,
    int_range,
    os_error_text,
    output_problem,
    plain_help,
)
from service.base.errors import HoloError
from service.base.signals import EXIT_RULE, EXIT_USAGE, interruptible
from service.commands.holo_render import scene_problem
from service.png import write_png

#: Runs timed for ``ms`` (after one warm-up run).
TIMED_RUNS = 7
#: Size scenes are rendered at when ``--size`` is not given.
DEFAULT_SIZE = (640, 480)


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``holo-sird``."""
    p = argparse.ArgumentParser(
        prog="holo-sird",
        description="Draw a single-image random-dot stereogram (autostereogram) of a depth "
        "map or of a scene's centre view, and write it as PNG.",
        epilog="INPUT is a depth .npy (distance behind the display, +inf where empty, as "
        "holo-render writes it) or a .hobj/.ply/.obj/.toml scene or builtin:NAME. "
        "Methods: row (the seed's algorithm), interpolated (its smoother shader variant), "
        "tiw (Thimbleby-Inglis-Witten: symmetric constraints, hidden-surface removal). "
        f"See docs/autostereogram.md. {plain_help(EXIT_RULE)}",
    )
    p.add_argument("input", metavar="INPUT", help="depth .npy, scene file or builtin:NAME")
    p.add_argument("--out", required=True, metavar="FILE.png", help="PNG to write")
    p.add_argument("--method", choices=sorted(METHODS), default="tiw", help="algorithm (tiw)")
    p.add_argument("--eye-sep", type=float_range(2, 4096, lo_open=True), metavar="PX",
                   help="eye separation in pixels (default 2.5 in at 72 dpi, at most width/3)")
    p.add_argument("--mu", metavar="F", type=float_range(0, 0.5, lo_open=True), default=1 / 3,
                   help="depth of field, (0, 0.5]; eyes do not fuse beyond 1/2 (default 1/3)")
    p.add_argument("--near", type=float_range(), metavar="D",
                   help="depth of the near plane (default: nearest finite depth)")
    p.add_argument("--far", type=float_range(), metavar="D",
                   help="depth of the far plane (default: farthest finite depth)")
    p.add_argument("--pattern", default="random", metavar="random|colour|FILE.png",
                   help="grey dots, colour dots or an image tile (default random)")
    p.add_argument("--seed", metavar="N", type=int_range(0), default=0,
                   help="random dots' seed (0)")
    add_size_option(p, DEFAULT_SIZE, "size a scene is rendered at; a .npy is resampled "
                    "(nearest) to it only when --size is given")
    p.add_argument("--json", action="store_true", help="print one JSON object of stats")
    return p


def _size_given(argv: list[str]) -> bool:
    """Whether the command line names ``--size`` (a .npy keeps its own size otherwise)."""
    return any(a == "--size" or a.startswith("--size=") for a in argv)


def _settings(args: argparse.Namespace, depth: np.ndarray) -> SirdSettings:
    lo, hi = finite_range(depth)
    near = lo if args.near is None else args.near
    far = hi if args.far is None else args.far
    if args.near is not None and args.far is None and far <= near:
        far = near + 1.0
    if args.far is not None and args.near is None and near >= far:
        near = far - 1.0
    eye = args.eye_sep if args.eye_sep is not None else default_eye_sep(depth.shape[1])
    return SirdSettings(method=args.method, eye_sep=eye, mu=args.mu, near=near, far=far)


def run(args: argparse.Namespace) -> dict:
    """Draw and write the stereogram; return the JSON report."""
    depth = load_depth(args.input, args.size if args.size_given else None, DEFAULT_SIZE)
    settings = _settings(args, depth)
    settings.check_width(depth.shape[1])
    pattern = make_pattern(args.pattern, settings.max_sep, seed=args.seed)
    work = SirdWorkspace(depth.shape[0], depth.shape[1], pattern.shape[2])
    image, stats = stereogram(depth, settings, pattern, work)  # warm-up (and the checks)
    times = []
    for _ in range(TIMED_RUNS):
        t0 = time.perf_counter()
        image, stats = stereogram(depth, settings, pattern, work)
        times.append((time.perf_counter() - t0) * 1e3)
    write_png(args.out, image)
    return {
        "method": settings.method,
        "size": [depth.shape[1], depth.shape[0]],
        "eye_sep_px": settings.eye_sep,
        "mu": settings.mu,
        "near": settings.near,
        "far": settings.far,
        "separation_px": [settings.min_sep, settings.max_sep],
        "ms": round(statistics.median(times), 4),
        "constraints": stats.constraints,
        "broken": broken_constraints(image, settings, work),
        "hidden": stats.hidden,
        "out": str(args.out),
    }


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit status."""
    argv = sys.argv[1:] if argv is None else argv
    # as holo-bench does: OpenMP threads that spin while waiting steal the core the
    # timed kernel needs (service.commands.holo_service.main); set before numba starts its threads
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    args = build_parser().parse_args(argv)
    args.size_given = _size_given(argv)
    problem = scene_problem(args.input, first=(".npy",))
    if problem:
        print(f"holo-sird: error: {problem}", file=sys.stderr)
        return EXIT_USAGE
    problem = output_problem(args.out)
    if problem:
        print(f"holo-sird: error: --out {problem}", file=sys.stderr)
        return EXIT_USAGE
    return interruptible("holo-sird", lambda: _main(args))


def _main(args: argparse.Namespace) -> int:
    try:
        report = run(args)
    except (HoloError, OSError) as exc:
        text = os_error_text(exc) if isinstance(exc, OSError) else str(exc)
        print(f"holo-sird: error: {text}", file=sys.stderr)
        return EXIT_USAGE
    if args.json:
        print(json.dumps(report))
    else:
        s = report["separation_px"]
        print(f"{report['method']} {report['size'][0]}x{report['size'][1]}, separations "
              f"{s[0]}-{s[1]} px, {report['ms']:.2f} ms; wrote {report['out']}")
    return 0

if __name__ == "__main__":
    sys.exit(main())
