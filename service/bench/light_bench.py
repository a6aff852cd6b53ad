"""Light benchmark: milliseconds per frame against intensity error vs per-point Blinn.

For every scene x zone count, the visibility buffer is made once by the real
stages 1-4 (project, modified cull, average-z sort, z-buffer: :func:`visibility`),
then :func:`service.render.light.shade` is timed for
every evaluation (polygon / vertex / point) x model (phong / blinn), plus the
game's ``ambient`` fast mode, as the median of ``--repeats`` runs after a warm-up.
Accuracy is the mean absolute difference of :func:`service.render.light.intensity` (mean
of r, g, b in [0, 1]) from per-point Blinn over the covered pixels of every zone
(``error``), and from per-point evaluation of the same model
(``error_vs_own_point``: the evaluation's error alone, without the model's).
Writes ``light_bench.json``, ``light_bench.csv`` and ``light_bench.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numba
import numpy as np

from service.base.cli_args import (
    add_size_option,
    comma_list,
    exit_rule_epilog,
    int_range,
    plain_help,
)
from service.bench.charts import save_chart
from service.bench.rows import write_csv, zones_label
from service.builtin_scenes import SCENES as BUILTIN_SCENES
from service.builtin_scenes import builtin_scene, scene_name
from service.display import DisplaySettings
from service.primitives import sphere
from service.render.cull import cull
from service.render.depth_sort import average_z, sort_polygons, triangle_order
from service.render.light import LightSettings, intensity, intensity_error, shade
from service.render.occlusion import Visibility
from service.render.occlusion.zbuffer import zbuffer
from service.render.projection import project
from service.render.scene import Light, Material, Scene, SceneArrays, SceneObject

if TYPE_CHECKING:
    from matplotlib.figure import Figure

#: (model, evaluation) pairs measured; ("blinn", "point") is the reference.
VARIANTS = (
    ("ambient", "polygon"),
    ("phong", "polygon"),
    ("blinn", "polygon"),
    ("phong", "vertex"),
    ("blinn", "vertex"),
    ("phong", "point"),
    ("blinn", "point"),
)
REFERENCE = LightSettings("blinn", "point")


def sphere_scene() -> Scene:
    """One shiny UV sphere (16 x 32) under a key, a fill and a point light."""
    ball = SceneObject(
        sphere(0.6, 16, 32),
        Material((0.85, 0.3, 0.25), ambient=0.15, diffuse=0.65, specular=0.8, shininess=5.0),
        name="sphere",
    )
    lights = [
        Light("directional", np.array([0.4, 0.6, 1.0]), (1.0, 1.0, 1.0), 0.9),
        Light("directional", np.array([-0.6, -0.2, 0.5]), (0.6, 0.7, 1.0), 0.3),
        Light("point", np.array([-0.6, 0.7, 1.2]), (1.0, 0.95, 0.85), 0.8),
    ]
    return Scene(objects=[ball], lights=lights, ambient=1.0)


#: Scene name -> builder; names other than "sphere" come from service.builtin_scenes.
SCENES = {"sphere": sphere_scene}


def load_scene(name: str) -> Scene:
    """The benchmark's own ``sphere`` or a built-in scene by name."""
    return SCENES.get(name, lambda: builtin_scene(name))()


def visibility(arrays: SceneArrays, display: DisplaySettings) -> tuple[Visibility, np.ndarray]:
    """Stages 1-4 with their default settings: (Visibility, projection (Z, V, 3))."""
    proj = project(arrays.vertices, display)
    keep, _ = cull(arrays.normals, display)
    order = sort_polygons(average_z(arrays.vertices, arrays.polygons, arrays.counts), keep)
    return zbuffer(arrays, proj, display, triangle_order(order, arrays.triangle_polygon)), proj


def time_ms(fn, repeats: int) -> tuple[float, float]:
    """Median wall and CPU (this process, all threads) milliseconds of ``fn()``.

    One warm-up call first.  On a loaded machine the CPU time of a single-threaded
    run (``NUMBA_NUM_THREADS=1``) is the fairer estimate of an idle machine's wall time.
    """
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        wall.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    return float(np.median(wall)), float(np.median(cpu))


def measure(scene_name: str, zones: int, size: tuple[int, int], repeats: int) -> list[dict]:
    """Rows {scene, zones, model, evaluation, ms, ms_per_zone, error, ...} for one setup."""
    scene = load_scene(scene_name)
    arrays = scene.flatten()
    display = DisplaySettings(zones=zones, cols=size[0], rows=size[1])
    vis, proj = visibility(arrays, display)
    covered = vis.triangle >= 0
    args = (arrays, proj, vis, display, scene.lights, scene.ambient)
    ref = intensity(*args, REFERENCE)
    own = {m: intensity(*args, LightSettings(m, "point")) for m in {m for m, _ in VARIANTS}}
    rows = []
    for model, evaluation in VARIANTS:
        st = LightSettings(model, evaluation)
        lit = intensity(*args, st)
        ms, cpu_ms = time_ms(lambda st=st: shade(*args, st), repeats)
        rows.append(
            {
                "scene": scene_name,
                "zones": zones,
                "cols": size[0],
                "rows": size[1],
                "polygons": int(arrays.n_polygons),
                "covered_pixels": int(covered.sum()),
                "model": model,
                "evaluation": evaluation,
                "ms": round(ms, 4),
                "ms_per_zone": round(ms / zones, 4),
                "cpu_ms": round(cpu_ms, 4),
                "error": round(intensity_error(lit, ref, covered), 6),
                "error_vs_own_point": round(intensity_error(lit, own[model], covered), 6),
            }
        )
    return rows


#: Chart styles: colour by light model, marker by where light is evaluated.
MODEL_COLOURS = {"ambient": "tab:grey", "phong": "tab:orange", "blinn": "tab:blue"}
EVAL_MARKERS = {"polygon": "s", "vertex": "^", "point": "o"}


def chart(rows: list[dict], path: Path) -> Figure:
    """Scatter of ms per frame (log) against intensity error, one panel per scene.

    Colour is the light model, the marker where it is evaluated (both in the legend,
    so each point is told apart without reading its label); hollow markers are 1
    zone, filled ones more, and each point is labelled with its zone count (``5z``).
    """
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    scenes = sorted({r["scene"] for r in rows})
    fig, axes = plt.subplots(1, len(scenes), figsize=(6 * len(scenes), 5), squeeze=False)
    for ax, name in zip(axes[0], scenes, strict=True):
        mine = [r for r in rows if r["scene"] == name]
        for r in mine:
            colour = MODEL_COLOURS[r["model"]]
            ax.scatter(r["ms"], r["error"], marker=EVAL_MARKERS[r["evaluation"]], s=60,
                       color=colour if r["zones"] > 1 else "none", edgecolors=colour)
            ax.annotate(f"{r['zones']}z", (r["ms"], r["error"]), fontsize=7, xytext=(4, 3),
                        textcoords="offset points")
        ax.set_xscale("log")
        _log_ticks(ax, [r["ms"] for r in mine])
        ax.set_xlabel("ms per frame, all zones (log scale)")
        ax.set_ylabel("mean |intensity - per-point Blinn|")
        ax.set_title(f"{name}: hollow = 1 zone, filled = more zones")
        ax.grid(True, which="both", alpha=0.3)
    wide = len(scenes) > 1
    fig.legend(handles=_legend_handles(), loc="lower center", ncol=6 if wide else 3,
               fontsize=8, title="colour: light model; marker: where it is evaluated; "
               "lower-left is better", title_fontsize=8)
    fig.tight_layout(rect=(0, 0.13 if wide else 0.2, 1, 1))  # room for the legend below
    return save_chart(fig, path, dpi=110)


def _legend_handles() -> list:
    """Proxy artists: one per light model (colour) and one per evaluation (marker)."""
    # deferred: matplotlib loads only when a chart is drawn
    from matplotlib.lines import Line2D

    models = [Line2D([], [], ls="", marker="o", color=c, label=f"{m} light")
              for m, c in MODEL_COLOURS.items()]
    evals = [Line2D([], [], ls="", marker=mk, color="black", mfc="none", label=f"per {e}")
             for e, mk in EVAL_MARKERS.items()]
    return models + evals


def _log_ticks(ax, values: list[float]) -> None:
    """Plain-number ticks on a log x axis, denser when the data span less than a decade."""
    # deferred: matplotlib loads only when a chart is drawn
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    positive = [v for v in values if v > 0]
    span = max(positive) / min(positive) if positive else 10.0
    subs = (1.0, 2.0, 5.0) if span >= 10 else (1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 7.0)
    ax.xaxis.set_major_locator(LogLocator(base=10, subs=subs))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())


def write(rows: list[dict], meta: dict, out: Path) -> list[Path]:
    """Write JSON (meta + rows), CSV (rows) and the chart; return the paths."""
    out.mkdir(parents=True, exist_ok=True)
    jpath, cpath, ppath = out / "light_bench.json", out / "light_bench.csv", out / "light_bench.png"
    jpath.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    write_csv(rows, cpath)
    chart(rows, ppath)
    return [jpath, cpath, ppath]


def light_scene_name(text: str) -> str:
    """An argparse type: ``sphere`` or a built-in scene name (canonical spelling)."""
    if text in SCENES:
        return text
    try:
        return scene_name(text)
    except argparse.ArgumentTypeError:
        known = ", ".join([*SCENES, *BUILTIN_SCENES])
        raise argparse.ArgumentTypeError(f"unknown scene {text!r}; known: {known}") from None


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """Command-line options (each value checked here: a bad one is a usage error)."""
    ap = argparse.ArgumentParser(prog="holo-bench light",
                                 description=plain_help(__doc__.splitlines()[0]),
                                 epilog=exit_rule_epilog())
    ap.add_argument("--out", metavar="DIR", type=Path, default=Path("bench-out/light"),
                    help="output folder")
    ap.add_argument("--scenes", metavar="NAME,...", type=comma_list(light_scene_name),
                    default="sphere,sphere-torus,game",
                    help="comma-separated: sphere or built-in scene names "
                    "(default: %(default)s)")
    ap.add_argument("--zones", metavar="N,...", type=comma_list(int_range(1, 64)), default="1,5",
                    help="comma-separated zone counts, 1-64 (default: %(default)s)")
    add_size_option(ap, (320, 240), "pixels per zone")
    ap.add_argument("--repeats", metavar="N", type=int_range(1), default=20,
                    help="timed runs per variant (median; default: %(default)s)")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, write its files and print a summary table."""
    args = parse_args(argv)
    size = args.size
    rows = []
    for name in args.scenes:
        for zones in args.zones:
            print(f"{name}, {zones_label(zones)}", file=sys.stderr, flush=True)
            rows += measure(name, zones, size, args.repeats)
    meta = {
        "what": "shade() ms per frame and mean |intensity error| vs per-point Blinn",
        "size": list(size),
        "repeats": args.repeats,
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "numba_threads": numba.get_num_threads(),
        "load_average": list(os.getloadavg()),
    }
    paths = write(rows, meta, args.out)
    head = ("scene", "Z", "model", "eval", "ms", "ms/zone", "cpu ms", "error")
    print("{:13s} {:>2s} {:7s} {:7s} {:>8s} {:>8s} {:>8s} {:>8s}".format(*head))
    for r in rows:
        print(f"{r['scene']:13s} {r['zones']:2d} {r['model']:7s} {r['evaluation']:7s} "
              f"{r['ms']:8.3f} {r['ms_per_zone']:8.3f} {r['cpu_ms']:8.3f} {r['error']:8.5f}")
    print("wrote", ", ".join(str(p) for p in paths))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
