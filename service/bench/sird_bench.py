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
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
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
from service.autostereogram.output import SirdOutput
from service.autostereogram.source import centre_depth
from service.base.cli_args import (
    add_size_option,
    comma_list,
    exit_rule_epilog,
    int_range,
    plain_help,
    size,
)
from service.bench.charts import save_chart
from service.bench.rows import write_csv
from service.builtin_scenes import builtin_scene
from service.display import DisplaySettings

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


def time_side_by_side(fns: dict[str, Callable[[], object]], repeats: int) -> dict[str, dict]:
    """Per name: wall ms (median and best) and CPU ms (median) of ``repeats`` runs.

    The functions take turns (one run each per round, after one warm-up round), so
    their ratios see the same machine load.
    """
    wall: dict[str, list[float]] = {k: [] for k in fns}
    cpu: dict[str, list[float]] = {k: [] for k in fns}
    for f in fns.values():
        f()
    for _ in range(repeats):
        for k, f in fns.items():
            t0, c0 = time.perf_counter(), time.process_time()
            f()
            wall[k].append((time.perf_counter() - t0) * 1e3)
            cpu[k].append((time.process_time() - c0) * 1e3)
    return {k: {"ms": statistics.median(wall[k]), "best_ms": min(wall[k]),
                "cpu_ms": statistics.median(cpu[k])} for k in fns}


def measure(methods: list[str], scene: str, cols: int, rows: int, repeats: int) -> list[dict]:
    """The table's rows for one scene and size, the methods timed side by side.

    Timed as the service runs them (:class:`SirdWorkspace` with ``keep_links=False``,
    buffers reused); checked (broken constraints) on a workspace that keeps its links.
    """
    eye = default_eye_sep(cols)
    depth, near, far = scene_depth(scene, cols, rows, eye)
    settings = {m: SirdSettings(method=m, eye_sep=eye, near=near, far=far) for m in methods}
    pattern = random_dots(settings[methods[0]].max_sep, seed=1)
    works = {m: SirdWorkspace(rows, cols, 1, keep_links=False) for m in methods}
    times = time_side_by_side(
        {m: (lambda m=m: stereogram(depth, settings[m], pattern, works[m])) for m in methods},
        repeats)
    return [_check(m, scene, settings[m], depth, pattern, eye, times[m]) for m in methods]


def _check(method: str, scene: str, s: SirdSettings, depth: np.ndarray, pattern: np.ndarray,
           eye: float, t: dict) -> dict:
    """One row: timings ``t`` plus decoded accuracy, streaks and constraint counts."""
    rows, cols = depth.shape
    work = SirdWorkspace(rows, cols, 1)
    img, stats = stereogram(depth, s, pattern, work)
    conv = METHOD_CONVENTION[method]
    expected = expected_separation(depth, s)
    tol, sub = METHOD_DECODE[method]
    decoded = decode(img, s.min_sep - 2, s.max_sep + 2, convention=conv, tol=tol, sub=sub)
    reach = (s.max_sep if conv == "left" else s.max_sep // 2) + 4
    mask = edge_free(expected, reach, conv)
    return {
        "method": method, "scene": scene, "size": f"{cols}x{rows}", "pixels": cols * rows,
        "eye_sep_px": round(eye, 2), "ms": round(t["ms"], 4), "best_ms": round(t["best_ms"], 4),
        "cpu_ms": round(t["cpu_ms"], 4), "fps": round(1e3 / t["ms"], 1),
        "best_fps": round(1e3 / t["best_ms"], 1),
        "accuracy": round(accuracy(decoded, expected, mask), 5),
        "edge_free": round(float(mask.mean()), 4), "streaks": round(streak_fraction(img), 5),
        "constraints": stats.constraints, "broken": broken_constraints(img, s, work),
        "hidden": stats.hidden,
    }


def service_cost(methods: list[str], cols: int, rows: int, repeats: int) -> list[dict]:
    """What the service's ``sird_ms_p50`` measures, the methods side by side.

    :class:`service.autostereogram.output.SirdOutput` (the service's own: its
    settings, pattern and workspace, a fresh output array per frame) on the game
    scene's centre view; ``SirdOutput.last_ms`` is the figure the service keeps.
    """
    depth = centre_depth(builtin_scene("game"), cols, rows)
    outs = {m: SirdOutput(cols, rows, DisplaySettings().width, m) for m in methods}
    ms: dict[str, list[float]] = {m: [] for m in methods}
    for o in outs.values():
        o.frame(depth)
    for _ in range(repeats):
        for m, o in outs.items():
            o.frame(depth)
            ms[m].append(o.last_ms)
    return [{"method": m, "size": f"{cols}x{rows}", "scene": "game",
             "sird_ms_p50": round(statistics.median(ms[m]), 4),
             "sird_ms_best": round(min(ms[m]), 4)} for m in methods]


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


def streak_ratios(rows: list[dict]) -> list[dict]:
    """Streak pixels of each method over ``row``'s, per scene and size (slope target: 1/10)."""
    out = []
    for r in rows:
        base = [b for b in rows if b["method"] == "row" and b["scene"] == r["scene"]
                and b["size"] == r["size"]]
        if r["method"] != "row" and base and base[0]["streaks"] > 0:
            out.append({"method": r["method"], "scene": r["scene"], "size": r["size"],
                        "of_row": round(r["streaks"] / base[0]["streaks"], 4)})
    return out


def chart(rows: list[dict], service: list[dict], path: Path) -> None:
    """Per scene: ms (log) against accuracy, and streaks; the service's cost, streak ratios.

    The last column shows the service's SIRD cost per refresh and every method's
    streak pixels relative to ``row``'s.
    """
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    colours = {"row": "tab:red", "interpolated": "tab:blue", "tiw": "tab:green"}
    scenes = [s for s in SCENE_NAMES if any(r["scene"] == s for r in rows)]
    fig, axes = plt.subplots(2, len(scenes) + 1, figsize=(4.5 * (len(scenes) + 1), 8),
                             squeeze=False)
    for i, name in enumerate(scenes):
        mine = [r for r in rows if r["scene"] == name]
        ax = axes[0][i]
        for r in mine:
            ax.scatter(r["ms"], r["accuracy"], color=colours[r["method"]], s=40)
            ax.annotate(r["size"], (r["ms"], r["accuracy"]), fontsize=6, xytext=(3, 3),
                        textcoords="offset points")
        ax.set_xscale("log")
        ax.set_xlabel("ms per frame (log; median, methods side by side)")
        ax.set_ylabel("decoded within 1 px (edge-free)")
        ax.set_title(name)
        ax.grid(True, which="both", alpha=0.3)
        ax = axes[1][i]
        labels = [f"{r['method'][:6]}\n{r['size']}" for r in mine]
        ax.bar(range(len(mine)), [r["streaks"] for r in mine],
               color=[colours[r["method"]] for r in mine])
        ax.set_xticks(range(len(mine)), labels, fontsize=5)
        ax.set_ylabel("streak pixels (runs of 3+)")
    _service_panel(axes[0][-1], service, colours)
    ratios = streak_ratios(rows)
    on_slope = [r for r in ratios if r["scene"] == "slope"]
    _ratio_panel(axes[1][-1], on_slope or ratios, colours)
    handles = [plt.Line2D([], [], marker="o", ls="", color=c, label=m) for m, c in colours.items()]
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=8)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    save_chart(fig, path, dpi=100)


def _service_panel(ax, service: list[dict], colours: dict[str, str]) -> None:
    """Bars: the service's SIRD ms per refresh (median and best), the 1 ms budget."""
    xs = range(len(service))
    ax.bar([x - 0.2 for x in xs], [r["sird_ms_p50"] for r in service], width=0.4,
           color=[colours[r["method"]] for r in service], label="median")
    ax.bar([x + 0.2 for x in xs], [r["sird_ms_best"] for r in service], width=0.4,
           color=[colours[r["method"]] for r in service], alpha=0.5, label="best")
    ax.axhline(1.0, color="k", ls="--", lw=1)
    ax.set_xticks(list(xs), [r["method"] for r in service], fontsize=7)
    ax.set_ylabel("ms per refresh (SirdOutput.frame)")
    ax.set_title(f"service, game {service[0]['size'] if service else ''} "
                 "(median | best; budget 1 ms)", fontsize=8)


def _ratio_panel(ax, ratios: list[dict], colours: dict[str, str]) -> None:
    """Bars: streak pixels over row's, per scene and size; the slope's 1/10 target."""
    ax.bar(range(len(ratios)), [max(r["of_row"], 1e-4) for r in ratios],
           color=[colours[r["method"]] for r in ratios])
    ax.set_xticks(range(len(ratios)),
                  [f"{r['method'][:6]}\n{r['scene']}\n{r['size']}" for r in ratios], fontsize=4)
    ax.set_yscale("log")
    ax.axhline(0.1, color="k", ls="--", lw=1)
    ax.set_ylabel("streak pixels / row's (log)")
    ax.set_title("streak pixels relative to row's (the slope's target: 1/10)", fontsize=8)


def write(rows: list[dict], stable: list[dict], service: list[dict], meta: dict,
          out: Path) -> list[Path]:
    """Write JSON, the CSVs and the chart; return the paths."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "sird_bench.json", out / "sird_bench.csv", out / "sird_service.csv",
             out / "sird_bench.png"]
    paths[0].write_text(json.dumps({"meta": meta, "rows": rows, "stability": stable,
                                    "service": service, "streak_ratios": streak_ratios(rows)},
                                   indent=1))
    write_csv(rows, paths[1])
    write_csv(service, paths[2])
    chart(rows, service, paths[3])
    return paths


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """Command-line options (each value checked here: a bad one is a usage error)."""
    ap = argparse.ArgumentParser(prog="holo-bench sird",
                                 description=plain_help(__doc__.splitlines()[0]),
                                 epilog=exit_rule_epilog())
    ap.add_argument("--out", metavar="DIR", type=Path, default=Path("bench-out/sird"),
                    help="output folder")
    ap.add_argument("--methods", metavar="NAME,...", type=comma_list(_choice(METHOD_NAMES)),
                    default=",".join(METHOD_NAMES), help="comma-separated (default: %(default)s)")
    ap.add_argument("--scenes", metavar="NAME,...", type=comma_list(_choice(SCENE_NAMES)),
                    default=",".join(SCENE_NAMES), help="comma-separated (default: %(default)s)")
    ap.add_argument("--sizes", metavar="WxH,...", type=comma_list(size),
                    default="320x240,640x480,1280x720",
                    help="comma-separated WxH (default: %(default)s)")
    ap.add_argument("--repeats", metavar="N", type=int_range(1), default=30,
                    help="timed runs per variant (median; default: %(default)s)")
    add_size_option(ap, default=(640, 480), flag="--service-size",
                    help="the service's SIRD cost per refresh, measured on the game scene")
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
            rows += measure(args.methods, scene, cols, nrows, args.repeats)
    stable = [stability(m, 640, 480) for m in args.methods]
    print("service", file=sys.stderr, flush=True)
    service = service_cost(args.methods, *args.service_size, args.repeats)
    meta = {"what": "stereogram() ms per frame (methods side by side), decoded accuracy, "
                    "streaks, dot stability, the service's SIRD ms per refresh",
            "repeats": args.repeats, "machine": platform.platform(), "cpus": os.cpu_count(),
            "numba_threads": numba.get_num_threads(), "load_average": list(os.getloadavg()),
            "target_fps_640x480": TARGET_FPS}
    paths = write(rows, stable, service, meta, args.out)
    print(f"{'method':13s} {'scene':7s} {'size':>9s} {'ms':>8s} {'best ms':>8s} {'cpu ms':>8s} "
          f"{'fps':>8s} {'decoded':>8s} {'streaks':>8s} {'broken':>6s} {'hidden':>7s}")
    for r in rows:
        print(f"{r['method']:13s} {r['scene']:7s} {r['size']:>9s} {r['ms']:8.3f} "
              f"{r['best_ms']:8.3f} {r['cpu_ms']:8.3f} {r['fps']:8.0f} {r['accuracy']:8.4f} "
              f"{r['streaks']:8.4f} {r['broken']:6d} {r['hidden']:7d}")
    for r in stable:
        print(f"stability {r['method']:13s} {r['size']}: {r['changed_per_frame']:.4f} of pixels "
              f"change per frame (new dots: {r['new_dots_every_frame']})")
    for r in streak_ratios(rows):
        if r["scene"] == "slope":
            print(f"streaks on the slope {r['size']}: {r['method']} {r['of_row']:.4f} of row's")
    for r in service:
        print(f"service {r['method']:13s} {r['size']} game: {r['sird_ms_p50']:.3f} ms per "
              f"refresh (best {r['sird_ms_best']:.3f})")
    print("wrote", ", ".join(str(p) for p in paths))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
