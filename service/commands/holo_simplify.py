"""``holo-simplify``: build a billboard cloud or a quadric decimation of a mesh.

Examples
--------
holo-simplify bunny.ply --error 1% --out bunny.hbc
holo-simplify bunny.ply --error 0.002 --method quadric --out bunny-low.ply --json

``--error EPS`` is the greatest distance allowed between the mesh and its stand-in,
in world units, or with ``%`` in percent of the mesh's bounding-box diagonal.  The
billboard method writes a billboard-cloud file (``.hbc``, ``docs/file-formats.md``);
the quadric method writes the decimated mesh as ``.ply`` or ``.obj`` with the fewest
triangles whose measured error is within EPS.  ``--json`` prints one object with what
was built and how long it took.  Exit status: 0; 2 for bad options, a bad mesh file
(or one with no faces), or an output that cannot be written; 130 / 143 on Ctrl-C /
SIGTERM (the rule of :mod:`service.base.signals`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from service.base.cli_args import int_range, os_error_text, output_problem, plain_help
from service.base.errors import HoloError
from service.base.signals import EXIT_RULE, interruptible
from service.loaders import load_mesh, save_obj, save_ply
from service.render.mesh import Mesh
from service.simplify.billboard import build_cloud
from service.simplify.cloud_file import save_cloud
from service.simplify.quadric import decimate_to_error

MESH_OUT = {".ply": save_ply, ".obj": save_obj}


def error_value(text: str) -> tuple[float, bool]:
    """Argparse type of ``--error``: (value, is_percent); value > 0 and finite."""
    pct = text.strip().endswith("%")
    try:
        value = float(text.strip().rstrip("%"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"want a number or N%, got {text!r}") from None
    if not np.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value, pct


error_value.__name__ = "EPS"


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``holo-simplify``."""
    p = argparse.ArgumentParser(
        prog="holo-simplify",
        description="Simplify a mesh within a geometric error: a billboard cloud "
        "(Decoret et al. 2003) or quadric edge-collapse decimation.",
        epilog=plain_help(EXIT_RULE),
    )
    p.add_argument("mesh", metavar="MESH", help="mesh file (.ply, .obj, .hobj)")
    p.add_argument("--error", type=error_value, required=True, metavar="EPS",
                   help="greatest error: world units, or N%% of the bounding-box diagonal")
    p.add_argument("--method", choices=("billboard", "quadric"), default="billboard",
                   help="billboard (default) or quadric")
    p.add_argument("--texture-res", type=int_range(1, 16384), default=256, metavar="N",
                   help="billboard texels across the mesh's diagonal, 1-16384 (default 256)")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="output: .hbc for billboard, .ply or .obj for quadric")
    p.add_argument("--json", action="store_true", help="print one JSON object of results")
    return p


def _check_out(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    ext = Path(args.out).suffix.lower()
    if args.method == "billboard" and ext != ".hbc":
        parser.error(f"--out for a billboard cloud must end in .hbc, got {args.out!r}")
    if args.method == "quadric" and ext not in MESH_OUT:
        parser.error(f"--out for a quadric mesh must end in .ply or .obj, got {args.out!r}")
    problem = output_problem(args.out)
    if problem:  # before the build (seconds to minutes), not after it
        print(f"holo-simplify: error: --out {problem}", file=sys.stderr)
        raise SystemExit(2)


def run(args: argparse.Namespace) -> dict:
    """Load, simplify, write; return the report."""
    mesh = load_mesh(args.mesh)
    v, f = mesh.vertices, mesh.triangles
    diag = float(np.linalg.norm(v.max(0) - v.min(0))) if v.size else 0.0
    value, pct = args.error
    eps = value / 100.0 * diag if pct else value
    report = {"method": args.method, "mesh": args.mesh, "faces_in": int(f.shape[0]),
              "diagonal": diag, "eps": eps, "out": args.out}
    what = "a billboard cloud" if args.method == "billboard" else "quadric levels"
    print(f"holo-simplify: building {what} of {args.mesh} ({int(f.shape[0])} triangles, "
          f"EPS {eps:.4g}); seconds to minutes", file=sys.stderr, flush=True)
    t0, c0 = time.perf_counter(), time.process_time()
    if args.method == "billboard":
        cloud = build_cloud(v, f, eps, args.texture_res)
        save_cloud(cloud, args.out)
        report.update(billboards=cloud.n_billboards, texels=int(cloud.rgba.shape[0]),
                      texture_res=args.texture_res, error=eps)
    else:
        vs, fs, err = decimate_to_error(v, f, eps)
        MESH_OUT[Path(args.out).suffix.lower()](args.out, Mesh.from_triangles(vs, fs))
        report.update(faces_out=int(fs.shape[0]), error=err)
    report.update(build_s=time.perf_counter() - t0, build_cpu_s=time.process_time() - c0)
    return report


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit status."""
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    for k, arg in enumerate(argv[:-1]):  # "--error -1%" would read as a missing value
        if arg == "--error" and argv[k + 1].startswith("-"):
            argv[k:k + 2] = [f"--error={argv[k + 1]}"]
            break
    args = parser.parse_args(argv)
    _check_out(args, parser)
    return interruptible("holo-simplify", lambda: _main(args))


def _main(args: argparse.Namespace) -> int:
    try:
        report = run(args)
    except (HoloError, OSError) as exc:
        text = os_error_text(exc) if isinstance(exc, OSError) else str(exc)
        print(f"holo-simplify: error: {text}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(report))
    elif args.method == "billboard":
        print(f"{report['faces_in']} triangles -> {report['billboards']} billboards "
              f"(EPS {report['eps']:.4g}, {report['texels']} texels) in "
              f"{report['build_s']:.1f} s; wrote {args.out}")
    else:
        print(f"{report['faces_in']} triangles -> {report['faces_out']} "
              f"(error {report['error']:.4g} <= EPS {report['eps']:.4g}) in "
              f"{report['build_s']:.1f} s; wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
