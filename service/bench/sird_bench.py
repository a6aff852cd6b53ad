"""Autostereogram benchmark: ms per frame against decoded-depth accuracy and streaks.

For every method (``row``, ``interpolated``, ``tiw``) x size x scene (a sphere, the
seed's slope, steps, the game's centre view), :func:`service.autostereogram.stereogram`
is timed (wall and CPU ms, the median of ``--repeats`` runs after a warm-up, buffers
reused as the service does), the picture is decoded
(:mod:`service.autostereogram.decode`: the fraction of edge-free pixels read back to
the expected separation +-1; ``interpolated`` against blends at quarter-pixel
separations, its own constraint) and its streak fraction counted (pixels in runs of
3+ equal colours).  ``stability``: a small ball moving 2 px per frame over 12 frames,
the fraction of pixels that change per frame, against about 255/256 for new random
dots every frame.  Writes ``sird_bench.json``, ``sird_bench.csv`` and
``sird_bench.png``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numba
import numpy as np

from service.autostereogram import (
    SirdSettings,
    SirdWorkspace,
    broken_constraints,
    default_eye_sep,
    finite_range,
    random_dots,
    stereogram,
)
from service.autostereogram.decode import (
    METHOD_CONVENTION,
    METHOD_DECODE,
    accuracy,
    decode,
    edge_free,
    expected_separation,
    streak_fraction,
)
from service.autostereogram.depth_scenes import seed_slope, sphere, steps
from service.autostereogram.source import centre_depth
from service.builtin_scenes import builtin_scene
from service.cli_args import comma_list, int_range, plain_help, size

METHOD_NAMES = ("row", "interpolated", "tiw")
SCENE_NAMES = ("sphere", "slope", "steps", "game")
#: Targets from issue 12 at 640x480 (frames per second).
TARGET_FPS = {"row": 2000, "interpolated": 1000, "tiw": 1000}


def scene_depth(name: str, cols: int, rows: int, eye_sep: float) -> tuple[np.ndarray, float, float]:
    """(depth, near, far) of a benchmark scene."""
    if name == "game":
        d = centre_depth(builtin_scene("game"), cols, rows)
        return (d, *finite_range(d))
    if name == "slope":
        s = SirdSettings(eye_sep=eye_sep)
        return seed_slope(cols, rows, s.max_sep - s.min_sep), 0.0, 1.0
    return (sphere(cols, rows) if name == "sphere" else steps(cols, rows)), 0.0, 1.0


def time_ms(fn, repeats: int) -> tuple[float, float]:
    """(wall, CPU) ms: medians of ``repeats`` runs after one warm-up."""
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    return statistics.median(wall), statistics.median(cpu)


def measure(method: str, scene: str, cols: int, rows: int, repeats: int) -> dict:
    """One row of the table."""
    eye = default_eye_sep(cols)
    depth, near, far = scene_depth(scene, cols, rows, eye)
    s = SirdSettings(method=method, eye_sep=eye, near=near, far=far)
    pattern = random_dots(s.max_sep, seed=1)
    work = SirdWorkspace(rows, cols, 1)
    wall, cpu = time_ms(lambda: stereogram(depth, s, pattern, work), repeats)
    img, stats = stereogram(depth, s, pattern, work)
    conv = METHOD_CONVENTION[method]
    expected = expected_separation(depth, s)
    tol, sub = METHOD_DECODE[method]
    decoded = decode(img, s.min_sep - 2, s.max_sep + 2, convention=conv, tol=tol, sub=sub)
    reach = (s.max_sep if conv == "left" else s.max_sep // 2) + 4
    mask = edge_free(expected, reach, conv)
    return {
        "method": method, "scene": scene, "size": f"{cols}x{rows}", "pixels": cols * rows,
        "eye_sep_px": round(eye, 2), "ms": round(wall, 4), "cpu_ms": round(cpu, 4),
        "fps": round(1e3 / wall, 1), "accuracy": round(accuracy(decoded, expected, mask), 5),
        "edge_free": round(float(mask.mean()), 4), "streaks": round(streak_fraction(img), 5),
        "constraints": stats.constraints, "broken": broken_constraints(img, s, work),
        "hidden": stats.hidden,
    }


def stability(method: str, cols: int, rows: int, frames: int = 12) -> dict:
    """Fraction of pixels changed per frame while a small ball moves 2 px per frame."""
    s = SirdSettings(method=method, eye_sep=default_eye_sep(cols), near=0.0, far=1.0)
    pattern = random_dots(s.max_sep, seed=1)
    work = SirdWorkspace(rows, cols, 1)
    yy, xx = np.mgrid[0:rows, 0:cols]
    r = rows / 12
    prev, changed = None, []
    for f in range(frames):
        d = np.full((rows, cols), np.inf, np.float32)
        d[(xx - cols / 3 - 2 * f) ** 2 + (yy - rows / 2) ** 2 < r * r] = 0.3
        img = stereogram(d, s, pattern, work)[0].copy()
        if prev is not None:
            changed.append(float((img != prev).any(axis=2).mean()))
        prev = img
    return {"method": method, "size": f"{cols}x{rows}", "ball_radius_px": round(r, 1),
            "changed_per_frame": round(statistics.mean(changed), 5),
            "new_dots_every_frame": round(1 - 1 / 256, 5)}


def chart(rows: list[dict], path: Path) -> None:
    """Ms per frame (log) against accuracy, and streak fractions, one panel per scene."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"row": "tab:red", "interpolated": "tab:blue", "tiw": "tab:green"}
    scenes = [s for s in SCENE_NAMES if any(r["scene"] == s for r in rows)]
    fig, axes = plt.subplots(2, len(scenes), figsize=(4.5 * len(scenes), 8), squeeze=False)
    for i, name in enumerate(scenes):
        mine = [r for r in rows if r["scene"] == name]
        ax = axes[0][i]
        for r in mine:
            ax.scatter(r["ms"], r["accuracy"], color=colours[r["method"]], s=40)
            ax.annotate(r["size"], (r["ms"], r["accuracy"]), fontsize=6, xytext=(3, 3),
                        textcoords="offset points")
        ax.set_xscale("log")
        ax.set_xlabel("ms per frame (log)")
        ax.set_ylabel("decoded within 1 px (edge-free)")
        ax.set_title(name)
        ax.grid(True, which="both", alpha=0.3)
        ax = axes[1][i]
        labels = [f"{r['method'][:6]}\n{r['size']}" for r in mine]
        ax.bar(range(len(mine)), [r["streaks"] for r in mine],
               color=[colours[r["method"]] for r in mine])
        ax.set_xticks(range(len(mine)), labels, fontsize=5)
        ax.set_ylabel("streak pixels (runs of 3+)")
    handles = [plt.Line2D([], [], marker="o", ls="", color=c, label=m) for m, c in colours.items()]
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=8)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write(rows: list[dict], stable: list[dict], meta: dict, out: Path) -> list[Path]:
    """Write JSON, CSV and the chart; return the paths."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "sird_bench.json", out / "sird_bench.csv", out / "sird_bench.png"]
    paths[0].write_text(json.dumps({"meta": meta, "rows": rows, "stability": stable}, indent=1))
    with paths[1].open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    chart(rows, paths[2])
    return paths


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """Command-line options (each value checked here: a bad one is a usage error)."""
    ap = argparse.ArgumentParser(prog="holo-bench sird",
                                 description=plain_help(__doc__.splitlines()[0]))
    ap.add_argument("--out", type=Path, default=Path("bench-out/sird"), help="output folder")
    ap.add_argument("--methods", type=comma_list(_choice(METHOD_NAMES)),
                    default=",".join(METHOD_NAMES), help="comma-separated (default: %(default)s)")
    ap.add_argument("--scenes", type=comma_list(_choice(SCENE_NAMES)),
                    default=",".join(SCENE_NAMES), help="comma-separated (default: %(default)s)")
    ap.add_argument("--sizes", type=comma_list(size), default="320x240,640x480,1280x720",
                    help="comma-separated WxH (default: %(default)s)")
    ap.add_argument("--repeats", type=int_range(1), default=30,
                    help="timed runs per variant (median; default: %(default)s)")
    return ap.parse_args(argv)


def _choice(names: tuple[str, ...]):
    def parse(text: str) -> str:
        if text not in names:
            raise argparse.ArgumentTypeError(f"want one of {', '.join(names)}, got {text!r}")
        return text
    parse.__name__ = "name"
    return parse


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, write its files and print a summary table."""
    args = parse_args(argv)
    rows = []
    for cols, nrows in args.sizes:
        for scene in args.scenes:
            print(f"{scene} {cols}x{nrows}", file=sys.stderr, flush=True)
            rows += [measure(m, scene, cols, nrows, args.repeats) for m in args.methods]
    stable = [stability(m, 640, 480) for m in args.methods]
    meta = {"what": "stereogram() ms per frame, decoded accuracy, streaks, dot stability",
            "repeats": args.repeats, "machine": platform.platform(), "cpus": os.cpu_count(),
            "numba_threads": numba.get_num_threads(), "load_average": list(os.getloadavg()),
            "target_fps_640x480": TARGET_FPS}
    paths = write(rows, stable, meta, args.out)
    print(f"{'method':13s} {'scene':7s} {'size':>9s} {'ms':>8s} {'cpu ms':>8s} {'fps':>8s} "
          f"{'decoded':>8s} {'streaks':>8s} {'broken':>6s} {'hidden':>7s}")
    for r in rows:
        print(f"{r['method']:13s} {r['scene']:7s} {r['size']:>9s} {r['ms']:8.3f} "
              f"{r['cpu_ms']:8.3f} {r['fps']:8.0f} {r['accuracy']:8.4f} {r['streaks']:8.4f} "
              f"{r['broken']:6d} {r['hidden']:7d}")
    for r in stable:
        print(f"stability {r['method']:13s} {r['size']}: {r['changed_per_frame']:.4f} of pixels "
              f"change per frame (new dots: {r['new_dots_every_frame']})")
    print("wrote", ", ".join(str(p) for p in paths))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
