"""``holo-bench quality``: calibrate ``--quality auto``'s cost model, and check its budget.

``--calibrate`` measures (a short run, about a minute on two cores): stages 1-4 of
each occlusion method and the light stage of each evaluation on the built-in scenes
at a few zone counts and sizes, BSP build times, and the Galilean order x interval
sweep at a small size; fits :class:`service.lod.cost.CostModel` and writes it
(``--model PATH``, default ``OUT/quality_model.json``).  Copy it over
``service/lod/cost_model.json`` to make it the default.

Without ``--calibrate`` it renders each scene with ``--quality auto`` for a few
frames at each budget and writes what was picked, the predicted error and the error
measured against ray casting with per-point light (``quality_auto.json`` / ``.csv``):
the measured error must stay within the budget.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from service.base.cli_args import add_size_option, exit_rule_epilog
from service.base.errors import SettingsError
from service.bench import peers
from service.bench.charts import save_chart
from service.bench.galilean_bench import sweep
from service.bench.rows import write_rows
from service.builtin_scenes import builtin_scene
from service.display import DisplaySettings
from service.galilean.motion_field import render_with_motion
from service.lod.cost import (
    OCCLUSION,
    SPECULAR,
    CostModel,
    fit,
    light_features,
    occlusion_features,
)
from service.quality import (
    QualityChooser,
    QualitySettings,
    cheapest_occlusion,
    parse_budget,
    pct_wrong,
    psnr,
    render_auto,
)
from service.render.light import LightSettings, shade
from service.render.pipeline import Renderer, RenderSettings, StageClock, warm_up

CAL_SCENES = ("sphere-torus", "game", "demo", "cyclic")
CAL_ZONES = (1, 3, 5)
CAL_SIZES = ((80, 60), (160, 120))
#: Scenes of 1k to 1M triangles (the peers' sphere grids): the occlusion fit covers
#: them, at these zone counts and one size, each method up to its
#: :data:`service.bench.peers.OUR_METHODS` size (BSP to 100k triangles).
SCALING_SCENES = tuple(peers.BIG_SCENES)
SCALING_ZONES = (1, 5)
SCALING_SIZE = (160, 120)
CHECK_SCENES = ("game", "sphere-torus", "cyclic", "threaded", "demo")
BUDGETS = ("0.1%", "2%", "30dB")


def _best_ms(fn, repeats: int) -> tuple[float, object]:
    """Best milliseconds of ``repeats`` calls after one warm-up, and the last result.

    The best, not the median: on a shared machine the median measures the
    neighbours (memory-bound passes suffer most), the best what the work costs.
    """
    out, ms = fn(), []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        ms.append((time.perf_counter() - t0) * 1e3)
    return float(np.min(ms)), out


def _time_occlusion(arrays, display: DisplaySettings, method: str, repeats: int):
    """(best stages 1-4 ms, first Visibility (BSP: with its build), projection)."""
    r, s = Renderer(), RenderSettings(method, painter_fallback="pixel")
    first, _, proj = r.visibility(arrays, display, s)  # a BSP tree is built here
    ms, _ = _best_ms(lambda: r.visibility(arrays, display, s, StageClock({})), repeats)
    return ms, first, proj


def _time_light(scene, arrays, proj, vis, display: DisplaySettings, evaluation: str,
                repeats: int) -> float:
    """Best light-stage ms of one evaluation (Blinn)."""
    st = LightSettings("blinn", evaluation)
    return _best_ms(lambda: shade(arrays, proj, vis, display, scene.lights, scene.ambient, st),
                      repeats)[0]


def calibrate(repeats: int = 5, galilean_frames: int = 17,
              galilean: list[dict] | None = None) -> CostModel:
    """Measure and fit the cost model (see the module notes).

    ``galilean``: a sweep table to keep (from an earlier model) instead of running
    the sweep again (most of the calibration's time).
    """
    occ: dict[str, list] = {m: [] for m in OCCLUSION}
    light: dict[str, list] = {e: [] for e in SPECULAR}
    build = []
    for name in CAL_SCENES:
        scene = builtin_scene(name)
        arrays = scene.flatten()
        t = arrays.triangles.shape[0]
        for z in CAL_ZONES:
            for cols, rows in CAL_SIZES:
                d = DisplaySettings(zones=z, cols=cols, rows=rows)
                for m in OCCLUSION:
                    ms, vis, proj = _time_occlusion(arrays, d, m, repeats)
                    if m == "bsp":
                        build.append((np.array([1.0, t / 1e3]), vis.stats["build_ms"]))
                    bad = int(vis.stats.get("inconsistent_pixels", 0))
                    occ[m].append((occlusion_features(t, z, rows * cols, bad), ms))
                covered = int(np.isfinite(vis.depth).sum())
                for e in SPECULAR:
                    ms = _time_light(scene, arrays, proj, vis, d, e, repeats)
                    light[e].append((light_features(t, covered), ms))
    for row in scaling(repeats):  # the fit covers 1k to 1M triangles
        for m in OCCLUSION:
            if f"{m}_ms" in row:
                feats = occlusion_features(row["triangles"], row["zones"], row["pixels"],
                                           row["bad"] if m == "runlength" else 0)
                occ[m].append((feats, row[f"{m}_ms"]))
    return CostModel(
        update_factor=update_factor(repeats),
        occlusion={m: fit(rows) for m, rows in occ.items()},
        bsp_build=fit(build)[:2],
        light={e: fit(rows) for e, rows in light.items()},
        galilean=galilean if galilean is not None else galilean_table(galilean_frames),
        meta={"measured": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
              "machine": platform.platform(), "processor": platform.machine(),
              "load_average": [round(v, 2) for v in os.getloadavg()],
              "scenes": list(CAL_SCENES) + list(SCALING_SCENES), "zones": list(CAL_ZONES),
              "sizes": [list(s) for s in CAL_SIZES], "repeats": repeats,
              "units": "ms; occlusion: 1, k triangles, k triangle-zones, M pixel-zones, "
                       "k bad points; "
                       "light: 1, k triangles, M covered pixels; bsp_build: 1, k triangles"},
    )


def scaling(repeats: int, scenes=SCALING_SCENES, zones=SCALING_ZONES,
            size: tuple[int, int] = SCALING_SIZE) -> list[dict]:
    """Stages 1-4 ms of every exact method on scenes of 1k to 1M triangles.

    Per scene and zone count, the methods are timed in turn (best of ``repeats``
    after one untimed call each, as :func:`_best_ms` times); BSP's tree is built in that
    call and reused (a static scene's), its build reported apart.

    Returns
    -------
    list of dict
        ``scene, triangles, zones, size, pixels, bad`` (points the run-length sort got
        wrong), ``<method>_ms`` of each method timed and ``bsp_build_ms``.
    """
    out = []
    for name in scenes:
        arrays = peers.peer_scene(name).flatten()
        t = int(arrays.triangles.shape[0])
        methods = [m for m in OCCLUSION if t <= peers.OUR_METHODS[m]]
        for z in zones:
            d = DisplaySettings(zones=z, cols=size[0], rows=size[1])
            r = {m: Renderer() for m in methods}
            s = {m: RenderSettings(m, painter_fallback="pixel") for m in methods}
            first = {m: r[m].visibility(arrays, d, s[m])[0] for m in methods}
            ms: dict[str, list[float]] = {m: [] for m in methods}
            for _ in range(repeats):  # in turn, so a busy moment hits every method
                for m in methods:
                    t0 = time.perf_counter()
                    r[m].visibility(arrays, d, s[m])
                    ms[m].append((time.perf_counter() - t0) * 1e3)
            row = {"scene": name, "triangles": t, "zones": z, "size": f"{size[0]}x{size[1]}",
                   "pixels": size[0] * size[1],
                   "bad": int(first["runlength"].stats.get("inconsistent_pixels", 0)),
                   **{f"{m}_ms": round(min(v), 3) for m, v in ms.items()}}
            if "bsp" in first:
                row["bsp_build_ms"] = round(float(first["bsp"].stats["build_ms"]), 3)
            out.append(row)
            print(f"[scaling] {name}, {z} zones: " + ", ".join(
                f"{m} {row[f'{m}_ms']:.1f} ms" for m in methods), file=sys.stderr, flush=True)
    return out


def scaling_check(model: CostModel, rows: list[dict]) -> list[dict]:
    """Per :func:`scaling` row: what auto picks by the model and what measured fastest.

    ``moving_pick`` / ``moving_fastest``: without BSP (a moving scene rebuilds its
    tree); ``static_pick`` / ``static_fastest``: with BSP, its build shared by
    :data:`service.bench.peers.AMORTISE_FRAMES` frames (methods not timed, BSP past
    100k triangles, are left out of both).  ``<method>_predicted_ms``: the model's.
    """
    out = []
    for row in rows:
        t, z, px, bad = row["triangles"], row["zones"], row["pixels"], row["bad"]
        timed = [m for m in OCCLUSION if f"{m}_ms" in row]
        _, pred = cheapest_occlusion(model, t, z, px, bad, 1, True)
        moving = [m for m in timed if m != "bsp"]
        static = {m: row[f"{m}_ms"] for m in timed}
        if "bsp" in static:
            static["bsp"] += row["bsp_build_ms"] / peers.AMORTISE_FRAMES
        _, spred = cheapest_occlusion(model, t, z, px, bad, peers.AMORTISE_FRAMES)
        out.append({**row, **{f"{m}_predicted_ms": round(pred[m], 3) for m in timed},
                    "moving_pick": min(moving, key=pred.__getitem__),
                    "moving_fastest": min(moving, key=lambda m: row[f"{m}_ms"]),
                    "static_pick": min(timed, key=spred.__getitem__),
                    "static_fastest": min(static, key=static.__getitem__)})
    return out


def chart_scaling(rows: list[dict], path: Path):
    """Measured (solid) and predicted (dashed) ms against triangles, one panel per zone count."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    zones = sorted({r["zones"] for r in rows})
    fig, axes = plt.subplots(1, len(zones), figsize=(4.4 * len(zones), 4), squeeze=False)
    for ax, z in zip(axes[0], zones, strict=True):
        sub = sorted((r for r in rows if r["zones"] == z), key=lambda r: r["triangles"])
        for m in OCCLUSION:
            pts = [r for r in sub if f"{m}_ms" in r]
            tri = [r["triangles"] for r in pts]
            (line,) = ax.plot(tri, [r[f"{m}_ms"] for r in pts], "-o", ms=3, label=m)
            ax.plot(tri, [r[f"{m}_predicted_ms"] for r in pts], "--", color=line.get_color())
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{z} zone{'s' * (z > 1)}, {sub[0]['size']}", fontsize=9)
        ax.set_xlabel("triangles")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("stages 1-4 ms (dashed: cost model)")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    return save_chart(fig, path, dpi=110)


def update_factor(repeats: int, size: tuple[int, int] = (160, 120)) -> float:
    """How many renders' time an update for the Galilean stage costs (render_with_motion)."""
    scene, d, r = builtin_scene("game"), DisplaySettings(zones=1, cols=size[0], rows=size[1]), \
        Renderer()
    plain, full = [], []
    for _ in range(repeats + 2):  # interleaved, so a busy moment hits both
        plain.append(_best_ms(lambda: r.render(scene, d), 1)[0])
        full.append(_best_ms(lambda: render_with_motion(r, scene, d, 0.0, 60.0), 1)[0])
    return round(min(full) / min(plain), 3)


def galilean_table(frames: int, size: tuple[int, int] = (64, 48)) -> list[dict]:
    """The Galilean benchmark's order x interval sweep at a small size, one zone."""
    d = DisplaySettings(zones=1, cols=size[0], rows=size[1])
    rows = sweep(d, frames, RenderSettings(light=LightSettings("blinn")))
    return [{**r, "pixels": size[0] * size[1]} for r in rows]


def reference(scene, display: DisplaySettings, model: str = "blinn") -> np.ndarray:
    """Ray-cast occlusion with per-point light: the colour every auto frame is scored on."""
    s = RenderSettings("raycast", light=LightSettings(model, "point"))
    return Renderer().render(scene, display, s).colour


def check(model: CostModel, size: tuple[int, int], zones: int = 5, frames: int = 3,
          scenes=CHECK_SCENES, budgets=BUDGETS) -> list[dict]:
    """Per scene and budget: what auto picked each frame, predicted and measured error."""
    display = DisplaySettings(zones=zones, cols=size[0], rows=size[1])
    out = []
    for name in scenes:
        scene = builtin_scene(name)
        ref = reference(scene, display)
        for text in budgets:
            budget = parse_budget(text)
            chooser, r = QualityChooser(QualitySettings("auto", budget), model), Renderer()
            for k in range(frames):  # the same scene again: static from the 2nd frame
                frame = render_auto(r, chooser, scene, display)
                q = frame.stats["quality"]
                wrong, db = pct_wrong(frame.colour, ref), psnr(frame.colour, ref)
                out.append({
                    "scene": name, "budget": text, "frame": k, "method": q["method"],
                    "specular": q["specular"],
                    "predicted_pct_wrong": q["predicted_error"]["pct_wrong"],
                    "predicted_psnr": q["predicted_error"]["psnr"],
                    "measured_pct_wrong": round(wrong, 4), "measured_psnr": round(db, 2),
                    "within_budget": budget.allows(wrong, db),
                    "predicted_ms": q["predicted_ms"]["total"],
                    "ms": round(frame.stats["ms"]["total"], 3),
                    "inconsistent_pixels": frame.stats["occlusion"].get("inconsistent_pixels"),
                    "galilean_order": (q["galilean"] or {}).get("order"),
                    "galilean_interval": (q["galilean"] or {}).get("interval"),
                })
    return out


def galilean_from(path: str) -> list[dict]:
    """The Galilean sweep table of a cost model file (of any occlusion layout)."""
    try:
        table = json.loads(Path(path).read_text())["galilean"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SettingsError(f"--galilean-from {path}: no Galilean table ({exc})") from exc
    if not isinstance(table, list):
        raise SettingsError(f"--galilean-from {path}: the Galilean table is not a list")
    return table


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The options of ``holo-bench quality``."""
    p = argparse.ArgumentParser(
        prog="holo-bench quality",
        description="Calibrate --quality auto's cost model (--calibrate), or check that "
        "auto's frames stay within their error budgets.",
        epilog=exit_rule_epilog("a frame went over its error budget."),
    )
    p.add_argument("--calibrate", action="store_true", help="measure and write the cost model")
    p.add_argument("--scaling", action="store_true",
                   help="only time the exact occlusion methods on scenes of 1k to 1M triangles "
                   "and say whether auto picks the fastest (quality_scaling.json/.csv/.png)")
    p.add_argument("--model", metavar="FILE", default=None, help="cost model JSON to write or read")
    p.add_argument("--galilean-from", default=None, metavar="PATH",
                   help="--calibrate: keep this model's Galilean sweep table instead of "
                   "running the sweep again")
    p.add_argument("--out", metavar="DIR", default="bench-out",
                   help="output folder (default bench-out)")
    add_size_option(p, (160, 120), "pixels per zone image of the budget check")
    p.add_argument("--quick", action="store_true", help="fewer repeats and frames")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Calibrate, or check the budget; 1 when a frame went over its budget."""
    args = parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    warm_up(RenderSettings("runlength"))
    if args.scaling:
        rows = scaling_check(CostModel.load(args.model), scaling(3 if args.quick else 5))
        write_rows(rows, out / "quality_scaling")
        chart_scaling(rows, out / "quality_scaling.png")
        for r in rows:
            print(f"{r['scene']:13s} {r['zones']} zones: moving picks {r['moving_pick']:9s} "
                  f"fastest {r['moving_fastest']:9s} static picks {r['static_pick']:9s} "
                  f"fastest {r['static_fastest']}", file=sys.stderr)
        return 0
    if args.calibrate:
        kept = galilean_from(args.galilean_from) if args.galilean_from else None
        model = calibrate(repeats=3 if args.quick else 5,
                          galilean_frames=9 if args.quick else 17, galilean=kept)
        path = Path(args.model) if args.model else out / "quality_model.json"
        path.write_text(model.to_json())
        print(f"wrote {path}")
        return 0
    rows = check(CostModel.load(args.model), args.size, frames=2 if args.quick else 3)
    write_rows(rows, out / "quality_auto")
    for r in rows:
        print(f"{r['scene']:13s} {r['budget']:5s} frame {r['frame']}: {r['method']:9s} "
              f"{r['specular']:7s} predicted {r['predicted_pct_wrong']:.3f}% "
              f"measured {r['measured_pct_wrong']:.3f}% / {r['measured_psnr']:.1f} dB "
              f"{'ok' if r['within_budget'] else 'OVER BUDGET'}", file=sys.stderr)
    return 0 if all(r["within_budget"] for r in rows) else 1
