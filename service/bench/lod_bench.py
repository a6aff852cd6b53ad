"""Level-of-detail benchmark (``holo-bench lod``): triangles vs image error vs frame time.

Part 1, per mesh (the bunny fixture, a torus and the game's spiky attacker at high
detail), fitted to 1.6 world units like ``holo-render`` fits a lone mesh: every level
of its LOD chain (:mod:`service.lod`: the full mesh and quadric levels) rendered in
``--zones`` zones at ``--size`` (z-buffer, Blinn per polygon), timed (wall ms the
median, CPU ms the best of ``--repeats`` whole renders), and compared with the full mesh's render:

* ``depth_diff_pct``: % of pixels (of those either render covers) whose depth
  differs by more than ``--depth-tol`` world units, coverage changes included;
* ``depth_diff_pct_all``: the same over every pixel of every zone;
* ``colour_diff_pct`` and ``colour_diff_pct_all``: % of pixels (of those either
  render covers; of all) whose colour differs by more than
  :data:`service.lod.settings.COLOUR_LEVELS` in any channel;
* ``coverage_diff_pct_all``: % of all pixels covered by one render only;
* ``psnr_db``: colour PSNR over every pixel;
* ``predicted_px``: the level's predicted screen error (error x scale x pixels/unit).

The chain's ``build_ms`` (decimation plus error measurement, no cache) is charted too.
Each chain here also gets a billboard cloud (issue 13B; EPS 1 % of the bounding-box
diagonal), drawn through ``Scene.billboards`` (stars on the charts): it shows why
clouds are off in the default chain (their drawing costs more than the triangles).

Part 2, a crowd of ``--crowd`` copies of one mesh, their depths (-z) spread over 10x
(0.1 to 1.0), rendered with LOD off and on (``--lod-error``, colour counted at the
default budget, :data:`service.lod.settings.DEFAULT_COLOUR_PCT`), and on at colour
budgets ``--colour-sweep`` (``geometric``: colour not counted): frame milliseconds
(median) and CPU milliseconds (median), the renders of one crowd interleaved (A, B,
C, A, B, C, ...) after a warm frame each, the same image errors over covered pixels
and over all pixels (the issue's "<= 1 % of pixels" read both ways; both are
printed), the LOD choice's and the whole LOD step's milliseconds (best of 50 calls
after the frames).  A last run adds a time budget (``--crowd-budget-ms``, by default half the
LOD-on frame's wall ms; timed alone after the others, its CPU ms the best of its
frames): the cost model's predicted milliseconds against the frame's measured ones,
and how many objects went past the error budget for it.  Two crowds, because the
zones are parallel projections and depth alone does not shrink an object here
(see :mod:`service.lod`): ``by-depth`` gives each copy a size proportional to
1 / depth (how a perspective picture of a crowd looks, composed for this display),
``uniform`` gives all the same size (about 20 px wide), so its gain comes only from
the copies being small on screen.  A third crowd, ``random`` (issue 31's), stands its
copies upright at random positions (depth 0.1-1.0), widths (0.05-0.3) and yaw: larger
objects that overlap.

Writes ``lod_levels.csv``, ``lod_crowd.csv``, ``lod_bench.json``, ``lod_levels.png``
(image error, PSNR and CPU ms against triangles, one line per mesh, log x; and the
measured silhouette error against the predicted one, ``measured_px``: how far a
pixel covered by one render only lies from the other's cover, between pixel centres),
``lod_build.png``, ``lod_crowd.png`` (CPU ms and % pixels differing, LOD off vs on)
and ``lod_colour.png`` (each crowd's CPU speed-up against the % of all pixels whose
colour differs, one point per colour budget).
Charts use CPU milliseconds (this process, all threads): on a shared machine wall
time mostly measures the other processes; both are in the CSV.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from service.base.cli_args import add_size_option, exit_rule_epilog, float_range, int_range
from service.bench.charts import save_chart
from service.bench.rows import write_csv
from service.billboard_render import BillboardObject
from service.display import DisplaySettings
from service.loaders import fit_transform, load_mesh
from service.lod.cache import build_chain
from service.lod.select import pixels_per_unit
from service.lod.settings import COLOUR_LEVELS, LodSettings
from service.primitives import attacker, torus
from service.render.light import LightSettings
from service.render.mesh import Mesh
from service.render.pipeline import Renderer, RenderSettings, warm_up
from service.render.scene import Light, Material, Scene, SceneObject, Transform, euler_quaternion

BUNNY = Path(__file__).resolve().parents[2] / ".." / "shared" / "fixtures" / "meshes" / "bunny.ply"
#: Built-in benchmark meshes by name (a path to a .ply/.obj works too).
MESHES = {
    "bunny": lambda: load_mesh(BUNNY),
    "torus": lambda: torus(0.5, 0.15, 96, 48),
    "spiky": lambda: attacker(24, radius=0.3, spike=0.9),
}
LIGHTS = [Light("directional", np.array([0.4, 0.6, 1.0]), (1.0, 1.0, 1.0), 0.9)]
MATERIAL = Material((0.8, 0.7, 0.55), 0.2, 0.7, 0.4, 5.0)
SETTINGS = RenderSettings(method="zbuffer", light=LightSettings("blinn", "polygon"))
#: LOD steps timed after a crowd's frames (their best is reported).
LOD_STEP_CALLS = 50


def _mesh(name: str) -> Mesh:
    if name in MESHES:
        return MESHES[name]()
    return load_mesh(name)


def _nearest(points: np.ndarray, targets: np.ndarray, chunk: int = 512) -> float:
    """Largest distance (px) from any of ``points`` (N, 2) to its nearest ``targets`` (M, 2)."""
    if points.shape[0] == 0:
        return 0.0
    if targets.shape[0] == 0:
        return float("inf")
    worst = 0
    t = targets.astype(np.int32)
    for start in range(0, points.shape[0], chunk):
        d = points[start:start + chunk, None, :].astype(np.int32) - t[None]
        worst = max(worst, int((d * d).sum(axis=2).min(axis=1).max()))
    return float(np.sqrt(worst))


def silhouette_px(a: np.ndarray, b: np.ndarray) -> float:
    """Measured screen error, px: the largest over both ways and all zones.

    How far (Euclidean, between pixel centres) a pixel covered by one render only lies
    from the nearest pixel the other render covers.  The nearest such pixel is always
    on that cover's edge (a pixel with an uncovered 4-neighbour), so only edges are
    searched.
    """
    worst = 0.0
    for one, other in ((a, b), (b, a)):
        for z in range(one.shape[0]):
            o = other[z]
            inner = o.copy()
            inner[1:] &= o[:-1]
            inner[:-1] &= o[1:]
            inner[:, 1:] &= o[:, :-1]
            inner[:, :-1] &= o[:, 1:]
            worst = max(worst, _nearest(np.argwhere(one[z] & ~o), np.argwhere(o & ~inner)))
    return worst


def image_error(full, other, depth_tol: float) -> dict:
    """Depth, coverage and colour difference of two frames (see the module doc)."""
    da, db = full.depth, other.depth
    fa, fb = np.isfinite(da), np.isfinite(db)
    with np.errstate(invalid="ignore"):
        differs = (fa != fb) | (fa & fb & (np.abs(da - db) > depth_tol))
    union = int((fa | fb).sum())
    delta = full.colour.astype(np.float64) - other.colour
    mse = float(np.mean(delta ** 2))
    colour = (np.abs(delta) > COLOUR_LEVELS).any(axis=-1)
    return {
        "depth_diff_pct": 100.0 * int(differs.sum()) / max(union, 1),
        "depth_diff_pct_all": 100.0 * float(differs.mean()),
        "colour_diff_pct": 100.0 * int(colour.sum()) / max(union, 1),
        "colour_diff_pct_all": 100.0 * float(colour.mean()),
        "coverage_diff_pct_all": 100.0 * float((fa != fb).mean()),
        "psnr_db": 99.0 if mse == 0 else 10.0 * math.log10(255.0**2 / mse),
        "measured_px": silhouette_px(fa, fb),
    }


def _timed(renderer: Renderer, scene: Scene, display: DisplaySettings,
           settings: RenderSettings, repeats: int):
    """The last frame, the median wall and the best CPU milliseconds of ``repeats`` renders.

    One render first, untimed: kernels compiled, static parts and LOD levels settled.

    CPU time (this process, all threads) is reported beside wall time because the
    benchmark often shares its cores; with one numba thread the two agree when idle.
    The best CPU time is the one least inflated by other processes (cache and memory
    contention raise CPU time too), so ratios are quoted from it.
    """
    wall, cpu = [], []
    frame = renderer.render(scene, display, settings)  # kernels compiled, caches built
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        frame = renderer.render(scene, display, settings)
        wall.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    if settings.lod is not None:
        frame.stats["lod_best_ms"] = lod_step_ms(renderer, scene, display, settings)
    return frame, float(np.median(wall)), float(np.min(cpu))


def lod_step_ms(renderer: Renderer, scene: Scene, display: DisplaySettings,
                settings: RenderSettings, calls: int = LOD_STEP_CALLS) -> list[float]:
    """Best of ``calls`` LOD steps after the frames: ``[choice ms, whole step ms]``.

    The choice is the report's ``select_ms`` (levels, hysteresis and budget); the
    whole step adds building the frame's scene.  Sub-millisecond figures on a shared
    machine: the best of many calls is what the step costs when not interrupted.
    """
    best = [np.inf, np.inf]
    for _ in range(calls):
        t0 = time.perf_counter()
        _, report = renderer.lod.apply(scene, display, settings.lod)
        best = [min(best[0], report["select_ms"]), min(best[1], (time.perf_counter() - t0) * 1e3)]
    return best


def level_rows(name: str, display: DisplaySettings, args: argparse.Namespace) -> list[dict]:
    """One row per level of one mesh's chain."""
    mesh = _mesh(name)
    t0 = time.perf_counter()
    chain = build_chain(mesh, LodSettings(cloud_eps=(0.01,)), cache=False)
    build_ms = (time.perf_counter() - t0) * 1e3
    place = fit_transform(mesh)
    place = Transform(place.position, euler_quaternion(0.4, 0.25, 0.0), place.scale)
    ppu = pixels_per_unit(display)
    frames = []
    for level, kind in zip(chain.levels, chain.kinds, strict=True):
        if kind == "billboard":
            scene = Scene([], LIGHTS, 1.0, billboards=[BillboardObject(level, MATERIAL, place)])
        else:
            scene = Scene([SceneObject(level, MATERIAL, place)], LIGHTS, 1.0)
        frames.append(_timed(Renderer(), scene, display, SETTINGS, args.repeats))
    rows = []
    for k, (frame, ms, cpu_ms) in enumerate(frames):
        rows.append({
            "mesh": name, "level": k, "kind": chain.kinds[k],
            "triangles": int(chain.triangles[k]), "error_world": float(chain.errors[k]),
            "predicted_px": float(chain.errors[k] * place.scale * ppu), "ms": ms,
            "cpu_ms": cpu_ms,
            **image_error(frames[0][0], frame, args.depth_tol), "build_ms": build_ms,
        })
    return rows


#: The crowds (README, Benchmarks): by depth, all one size, issue 31's random one.
CROWDS = ("by-depth", "uniform", "random")


def crowd_scene(mesh: Mesh, n: int, sized_by_depth: bool | str, seed: int = 0) -> Scene:
    """``n`` copies of ``mesh`` at depths 0.1 to 1.0, spread over the display.

    ``sized_by_depth`` True or ``"by-depth"``: width 0.25 x 0.1 / depth world units
    (0.25 nearest, 0.025 farthest); False or ``"uniform"``: 0.12 for every copy (about
    20 px at 320 columns); ``"random"``: upright, at random depths, widths 0.05-0.3
    and yaw (larger objects that overlap, issue 31's crowd).
    """
    kind = {True: "by-depth", False: "uniform"}.get(sized_by_depth, sized_by_depth)
    rng = np.random.default_rng(seed)
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    extent = float(np.max(hi - lo)) or 1.0
    depth = np.geomspace(0.1, 1.0, n)
    objs = []
    for i, d in enumerate(depth):
        if kind == "random":
            d, width = rng.uniform(0.1, 1.0), rng.uniform(0.05, 0.3)
            q = euler_quaternion(0.0, rng.uniform(-np.pi, np.pi), 0.0)
        else:
            width = 0.25 * 0.1 / d if kind == "by-depth" else 0.12
        s = width / extent
        pos = np.array([rng.uniform(-0.9, 0.9), rng.uniform(-0.65, 0.65), -d])
        if kind != "random":
            q = euler_quaternion(*rng.uniform(-np.pi, np.pi, 3))
        objs.append(SceneObject(mesh, MATERIAL, Transform(pos - (lo + hi) / 2 * s, q, s),
                                name=f"copy{i}"))
    return Scene(objs, LIGHTS, 1.0)


def _interleaved(runs: dict, scene: Scene, display: DisplaySettings, repeats: int) -> dict:
    """Each run's last frame, median wall ms and median CPU ms, renders interleaved.

    ``runs`` maps a name to ``(Renderer, RenderSettings)``.  One warm render each
    first (kernels, caches, chains); then ``repeats`` rounds of one render per run,
    so a change of the machine's load falls on every run alike.
    """
    frames = {k: r.render(scene, display, st) for k, (r, st) in runs.items()}
    wall = {k: [] for k in runs}
    cpu = {k: [] for k in runs}
    for _ in range(repeats):
        for k, (r, st) in runs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            frames[k] = r.render(scene, display, st)
            wall[k].append((time.perf_counter() - t0) * 1e3)
            cpu[k].append((time.process_time() - c0) * 1e3)
    for k, (r, st) in runs.items():
        if st.lod is not None:
            frames[k].stats["lod_best_ms"] = lod_step_ms(r, scene, display, st)
    return {k: (frames[k], float(np.median(wall[k])), float(np.median(cpu[k]))) for k in runs}


def _sweep_label(pct: float | None) -> str:
    return "geometric" if pct is None else f"colour {pct:g} %"


def crowd_rows(display: DisplaySettings, args: argparse.Namespace) -> list[dict]:
    """LOD off, on, on at each colour budget, and on with a time budget, per crowd."""
    mesh = _mesh(args.crowd_mesh)
    build_chain(mesh)  # into the cache, outside the timings

    def lod(**kw) -> RenderSettings:
        return RenderSettings(method="zbuffer", light=SETTINGS.light,
                              lod=LodSettings(error_px=args.lod_error, **kw))

    rows = []
    for crowd in args.crowds:
        scene = crowd_scene(mesh, args.crowd, crowd)
        runs = {"off": (Renderer(), SETTINGS), "on": (Renderer(), lod())}
        for pct in args.colour_sweep:
            runs[_sweep_label(pct)] = (Renderer(), lod(colour_pct=pct))
        got = _interleaved(runs, scene, display, args.repeats)
        budget = args.crowd_budget_ms or got["on"][1] / 2  # wall ms, as the cost model measures
        # a few frames more: the model fits a line once the triangle counts spread
        got["budget"] = _timed(Renderer(), scene, display, lod(budget_ms=budget),
                               max(args.repeats, 6))
        off, off_ms, off_cpu = got["off"]
        for mode, (frame, ms, cpu) in got.items():
            rows.append({
                "crowd": crowd, "lod": mode, "objects": args.crowd, "ms": ms, "cpu_ms": cpu,
                "triangles": int(frame.stats["polygons"]["in"]),
                "speedup": off_ms / ms, "cpu_speedup": off_cpu / cpu,
                **image_error(off, frame, args.depth_tol), **_lod_columns(frame),
            })
    return rows


def _lod_columns(frame) -> dict:
    """The LOD report's figures for a crowd row (zeros with LOD off)."""
    report = frame.stats.get("lod")
    if report is None:
        return {"select_ms": 0.0, "lod_ms": 0.0, "max_predicted_px": 0.0, "levels_used": "",
                "over_error": 0, "budget_ms": 0.0, "predicted_ms": 0.0, "measured_ms": 0.0}
    return {
        "select_ms": frame.stats["lod_best_ms"][0], "lod_ms": frame.stats["lod_best_ms"][1],
        "max_predicted_px": max(report["predicted_px"]),
        "levels_used": json.dumps(np.bincount(report["levels"]).tolist()),
        "over_error": report["over_error"], "budget_ms": report.get("budget_ms") or 0.0,
        "predicted_ms": report.get("predicted_ms") or 0.0,
        # what the cost model saw of this frame: its wall ms without the LOD step
        "measured_ms": frame.stats["ms"]["total"] - frame.stats["ms"]["lod"],
    }


def charts(levels: list[dict], crowd: list[dict], out: Path) -> None:
    """``lod_levels.png`` and ``lod_build.png`` (with level rows), ``lod_crowd.png``."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    if levels:
        level_charts(levels, out)
    if crowd:
        crowd_chart(crowd, out)
        colour_chart(crowd, out)


def level_charts(levels: list[dict], out: Path) -> None:
    """``lod_levels.png`` and ``lod_build.png``."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r["mesh"] for r in levels))
    fig, axes = plt.subplots(1, 4, figsize=(20, 4.5))
    for name in names:
        rs = [r for r in levels if r["mesh"] == name and r["kind"] != "billboard"]
        bb = [r for r in levels if r["mesh"] == name and r["kind"] == "billboard"]
        for group, style, label in ((rs, "o-", name), (bb, "*", f"{name} billboard cloud")):
            if not group:
                continue
            tri = [r["triangles"] for r in group]
            line = axes[0].plot(tri, [r["depth_diff_pct"] for r in group], style, ms=9,
                                label=label)[0]
            kw = {"color": line.get_color(), "ms": 9, "label": label}
            if group is bb:
                kw["color"] = axes[0].lines[-2].get_color() if rs else None
                line.set_color(kw["color"])
            axes[1].plot(tri, [min(r["psnr_db"], 60) for r in group], style, **kw)
            axes[2].plot(tri, [r["cpu_ms"] for r in group], style, **kw)
            axes[3].plot([r["predicted_px"] for r in group], [r["measured_px"] for r in group],
                         "*" if group is bb else "o", **kw)
    top = max([r["predicted_px"] for r in levels] + [1.0])
    axes[3].plot([0, top], [1, top + 1], "k--", lw=1, label="predicted + 1 px")
    axes[3].set_xlabel("predicted screen error, px")
    axes[3].set_ylabel("measured silhouette error, px")
    axes[3].grid(alpha=0.3)
    axes[3].legend()
    for ax, label in zip(axes[:3], ("% covered pixels whose depth differs", "colour PSNR, dB "
                                "(99 capped at 60)", "CPU ms per frame (all zones)"), strict=True):
        ax.set_xscale("log")
        ax.set_xlabel("triangles (log; a billboard cloud: 2 per quad)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle("LOD chain levels vs the full mesh: quadric edge collapse (o) and "
                 "billboard clouds at EPS 1 % of the diagonal (*)")
    fig.tight_layout()
    save_chart(fig, out / "lod_levels.png", dpi=110)
    fig, ax = plt.subplots(figsize=(6, 4))
    builds = [next(r["build_ms"] for r in levels if r["mesh"] == n) / 1e3 for n in names]
    ax.bar(names, builds)
    ax.set_ylabel("chain build, s (decimation + error, no cache)")
    fig.tight_layout()
    save_chart(fig, out / "lod_build.png", dpi=110)


def crowd_chart(crowd: list[dict], out: Path) -> None:
    """``lod_crowd.png``: CPU ms and % pixels differing, LOD off, on, on with a budget."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    kinds = list(dict.fromkeys(r["crowd"] for r in crowd))
    x = np.arange(len(kinds))
    for j, mode in enumerate(("off", "on", "budget")):
        rs = [next(r for r in crowd if r["crowd"] == k and r["lod"] == mode) for k in kinds]
        label = "LOD on + budget (half LOD on)" if mode == "budget" else f"LOD {mode}"
        colour = f"C{j}"
        axes[0].bar(x + 0.27 * j, [r["cpu_ms"] for r in rs], 0.27, label=label, color=colour)
        axes[1].bar(x + 0.27 * j, [r["depth_diff_pct"] for r in rs], 0.27,
                    label=f"{label}, of covered pixels", color=colour)
        axes[1].bar(x + 0.27 * j, [r["depth_diff_pct_all"] for r in rs], 0.27,
                    fill=False, hatch="//", edgecolor="k",
                    label="hatched: of all pixels" if j == 2 else None)
    axes[0].set_ylabel("CPU ms per frame (all zones)")
    axes[1].set_ylabel("% pixels differing from LOD off (hatched: of all pixels)")
    axes[1].axhline(1.0, color="r", ls="--", lw=1, label="1 % target")
    for ax in axes:
        ax.set_xticks(x + 0.27, kinds)
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_chart(fig, out / "lod_crowd.png", dpi=110)


def colour_chart(crowd: list[dict], out: Path) -> None:
    """``lod_colour.png``: CPU speed-up against % of all pixels whose colour differs."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for j, kind in enumerate(dict.fromkeys(r["crowd"] for r in crowd)):
        rs = sorted((r for r in crowd if r["crowd"] == kind and r["lod"] not in ("off", "budget")),
                    key=lambda r: r["colour_diff_pct_all"])
        ax.plot([r["colour_diff_pct_all"] for r in rs], [r["cpu_speedup"] for r in rs], "o-",
                color=f"C{j}", label=f"{kind}: colour")
        ax.plot([r["coverage_diff_pct_all"] for r in rs], [r["cpu_speedup"] for r in rs], "x:",
                color=f"C{j}", label=f"{kind}: coverage")
        for r in rs:
            ax.annotate(r["lod"], (r["colour_diff_pct_all"], r["cpu_speedup"]), fontsize=6)
    ax.axvline(1.0, color="r", ls="--", lw=1, label="1 % target")
    ax.axhline(5.0, color="k", ls="--", lw=1, label="5x target")
    ax.set_xlabel(f"% of all pixels differing from LOD off (colour: a channel > {COLOUR_LEVELS})")
    ax.set_ylabel("CPU speed-up over LOD off (median, interleaved)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_chart(fig, out / "lod_colour.png", dpi=110)


def _sweep(text: str) -> list[float | None]:
    """``--colour-sweep``: comma list of % budgets or ``geometric`` (colour not counted)."""
    out: list[float | None] = []
    for part in (p.strip() for p in text.split(",") if p.strip()):
        if part == "geometric":
            out.append(None)
            continue
        try:
            value = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{part!r} is not a % or 'geometric'") from None
        if not (np.isfinite(value) and value >= 0):
            raise argparse.ArgumentTypeError(f"colour budget {part} must be a % >= 0")
        out.append(value)
    return out


def _crowds(text: str) -> list[str]:
    """``--crowds``: comma list of :data:`CROWDS`."""
    out = [p.strip() for p in text.split(",") if p.strip()]
    bad = [p for p in out if p not in CROWDS]
    if bad or not out:
        raise argparse.ArgumentTypeError(f"crowds must be some of {', '.join(CROWDS)}")
    return out


def build_parser() -> argparse.ArgumentParser:
    """The options of ``holo-bench lod``."""
    p = argparse.ArgumentParser(
        prog="holo-bench lod",
        description="Level of detail: every LOD chain level of the bunny, a torus and the "
        "spiky attacker against the full mesh (triangles vs % pixels whose depth differs, "
        "colour PSNR, CPU ms per frame, build time), and crowds of 200 bunnies with LOD "
        "off and on, at several colour budgets (speed against % pixels whose colour "
        "differs). Writes lod_levels.csv, lod_crowd.csv, lod_bench.json and "
        "lod_levels.png, lod_build.png, lod_crowd.png, lod_colour.png (README, Benchmarks).",
        epilog=exit_rule_epilog(),
    )
    p.add_argument("--out", metavar="DIR", default="bench-out",
                   help="output folder (default bench-out)")
    p.add_argument("--meshes", metavar="MESH,...", default="bunny,torus,spiky",
                   help="comma list: bunny, torus, spiky or mesh files (default all three; "
                   "an empty string for the crowd only)")
    add_size_option(p, (320, 240), "pixels per zone image")
    p.add_argument("--zones", metavar="N", type=int_range(1, 64), default=5,
                   help="view zones (default 5)")
    p.add_argument("--repeats", metavar="N", type=int_range(1, 100), default=3,
                   help="renders timed (3)")
    p.add_argument("--crowd", metavar="N", type=int_range(0, 5000), default=200,
                   help="copies in the crowd scene, 0 to skip it (default 200)")
    p.add_argument("--crowd-mesh", metavar="MESH", default="bunny",
                   help="the crowd's mesh (default bunny)")
    p.add_argument("--crowds", metavar="NAME,...", type=_crowds, default=list(CROWDS),
                   help=f"crowds to render (default {','.join(CROWDS)})")
    p.add_argument("--colour-sweep", metavar="PCT,...", type=_sweep,
                   default=[None, 4.0, 2.0, 0.5],
                   help="LOD-on runs at these colour budgets, %% of all pixels, beside the "
                   "default's ('geometric': colour not counted; default geometric,4,2,0.5)")
    p.add_argument("--lod-error", type=float_range(0, None, lo_open=True), default=0.5,
                   metavar="PX", help="the crowd's LOD error budget, pixels (default 0.5)")
    p.add_argument("--crowd-budget-ms", type=float_range(0, None), default=0.0, metavar="MS",
                   help="the crowd's LOD time budget, wall ms (default 0: half the LOD-on "
                   "frame's)")
    p.add_argument("--depth-tol", metavar="D", type=float_range(0, None, lo_open=True),
                   default=0.01,
                   help="depth difference counted as a wrong pixel, world units (0.01)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; write CSV, JSON and charts."""
    args = build_parser().parse_args(argv)
    cols, rows = args.size
    display = DisplaySettings(zones=args.zones, cols=cols, rows=rows)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    warm_up(SETTINGS)
    levels = []
    for name in [n for n in args.meshes.split(",") if n]:
        levels += level_rows(name, display, args)
        print(f"{name}: {len(levels)} level rows so far", file=sys.stderr)
    crowd = crowd_rows(display, args) if args.crowd else []
    if levels:
        write_csv(levels, out / "lod_levels.csv")
    if crowd:
        write_csv(crowd, out / "lod_crowd.csv")
    (out / "lod_bench.json").write_text(json.dumps(
        {"display": [args.zones, cols, rows], "depth_tol": args.depth_tol,
         "lod_error": args.lod_error, "levels": levels, "crowd": crowd}, indent=1))
    charts(levels, crowd, out)
    for r in crowd:
        print(f"crowd {r['crowd']:8s} LOD {r['lod']:3s}: {r['ms']:8.1f} ms "
              f"x{r['speedup']:.1f} (CPU median {r['cpu_ms']:.1f} ms x{r['cpu_speedup']:.1f}), "
              f"{r['triangles']} triangles, "
              f"{r['depth_diff_pct']:.2f} % covered pixels differ "
              f"({r['depth_diff_pct_all']:.2f} % of all), PSNR {r['psnr_db']:.1f} dB")
    for r in (r for r in crowd if r["lod"] == "budget"):
        print(f"budget {r['crowd']:8s}: {r['budget_ms']:.1f} ms asked, model predicted "
              f"{r['predicted_ms']:.1f} ms, frame measured {r['measured_ms']:.1f} ms wall "
              f"({r['cpu_ms']:.1f} ms CPU), {r['triangles']} triangles, "
              f"{r['over_error']} objects past the error budget; LOD choice with the "
              f"budget {r['select_ms']:.3f} ms (best of {LOD_STEP_CALLS} calls)")
    for r in crowd:
        if r["lod"] != "off":
            print(f"colour {r['crowd']:8s} {r['lod']:12s}: x{r['cpu_speedup']:.2f} CPU, "
                  f"{r['colour_diff_pct_all']:.2f} % of all pixels differ in colour, "
                  f"{r['coverage_diff_pct_all']:.2f} % in coverage, "
                  f"{r['depth_diff_pct_all']:.2f} % in depth")
    for r in (r for r in crowd if r["lod"] == "on"):
        worst = max(r["colour_diff_pct_all"], r["depth_diff_pct_all"])
        print(f"target {r['crowd']:8s}: x{r['cpu_speedup']:.1f} CPU (>= 5: "
              f"{'met' if r['cpu_speedup'] >= 5 else 'NOT met'}), "
              f"{r['colour_diff_pct_all']:.2f} % of all pixels differ in colour, "
              f"{r['depth_diff_pct_all']:.2f} % in depth or coverage (<= 1: "
              f"{'met' if worst <= 1 else 'NOT met'}); LOD choice "
              f"{r['select_ms']:.3f} ms, whole LOD step {r['lod_ms']:.3f} ms "
              f"for {r['objects']} objects (best of {LOD_STEP_CALLS} calls)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
