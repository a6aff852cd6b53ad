"""Galilean stage benchmark: thought experiments, and the order x interval x motion sweep.

``holo-bench galilean --case NAME --order N --interval K --frames F [--json]``
    Runs a thought experiment (``falling``, ``uniform``, ``rotating-square``,
    ``galcube``; see :mod:`service.bench.galilean_experiments`) or a rendered ``scene``
    (a spinning, drifting cube through the real stage) with an update every K
    refreshes, and prints per refresh the displayed position and its error
    against the exact motion (signed px for 1-D cases, the largest absolute px
    error over the control points otherwise).  ``--json`` prints one object
    ``{"case", "order", "interval", "errors", "ms_per_refresh"}``.

``holo-bench galilean --sweep --out DIR``
    For every motion (linear, falling, rotating cube, head turn from a simulated
    noisy tracker through the alpha-beta-gamma filter) x order (0..3) x update
    interval (1, 2, 4, 8, 16): PSNR and % of pixels wrong of every *extrapolated*
    refresh against the true render at that instant, and ms per refresh; the
    benefit of the out-of-view margin and of the obscuration cache; the thought
    experiments; and the 640x480 timing of one refresh per order against a render.
    Writes ``galilean_sweep.json``/``.csv``, ``galilean_timing.json``,
    ``galilean_complexity.json``/``.csv`` and PNG charts.

``holo-bench galilean --starvation --out DIR [--starve-seconds S]``
    The stage starved of renders (:mod:`service.bench.galilean_starvation`): one
    render, then none for S seconds (default 3); at every refresh the error against
    the true render, holding the last render past its use-by (the stage as it runs)
    against extrapolating on and against the render alone.  Writes
    ``galilean_starvation.json``/``.csv``/``.png`` (``--sweep`` writes them too).

``holo-bench galilean --complexity --out DIR [--complexity-counts 0,1000,...]``
    Against scene complexity (the rotating cube scene plus a grid of spinning,
    drifting spheres of growing tessellation, about 250 to 100,000 triangles):
    ms of ``Renderer.render``, of ``render_with_motion`` (what an update costs) and
    of one G(2) refresh at ``--time-size``, one zone, interleaved, median per step;
    and the smallest triangle count at which the refresh is >= 10x cheaper than
    each.  Writes ``galilean_complexity.json``/``.csv``/``.png`` and prints the JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from drivers.filters import AlphaBetaGammaSettings, run_filter
from service.base.cli_args import (
    add_size_option,
    exit_rule_epilog,
    float_range,
    int_range,
    plain_help,
)
from service.bench import galilean_starvation
from service.bench.charts import save_chart
from service.bench.galilean_experiments import (
    CASES,
    ONE_D,
    galcube_paper,
    radius_shown,
    run_case,
    run_tracker,
)
from service.bench.rows import write_csv
from service.display import DisplaySettings
from service.galilean.fixed_point import (
    FixedPoint,
    bit_budget,
    pixel_of,
    points_fixed,
    propagate_points,
)
from service.galilean.local_update import obscurers, render_local
from service.galilean.motion_field import render_with_motion, vertex_derivatives
from service.galilean.shadow import shadow_depth
from service.galilean.stage import GalileanSettings, GalileanStage, margin_display
from service.lod.settings import COLOUR_LEVELS
from service.primitives import cube, sphere
from service.render.light import LightSettings
from service.render.mesh import Mesh
from service.render.pipeline import Renderer, RenderSettings, warm_up
from service.render.scene import (
    Light,
    Material,
    MotionState,
    Scene,
    SceneObject,
    Transform,
    axis_angle_quaternion,
)
from service.scene_motion import advance_scene, control_points, view_scene
from sim_devices.motion import HeadTurn

if TYPE_CHECKING:
    from matplotlib.figure import Figure

ORDERS = (0, 1, 2, 3)
INTERVALS = (1, 2, 4, 8, 16)
MOTIONS = ("linear", "falling", "rotating-cube", "head-turn")
HZ = 60.0
#: A pixel is "wrong" when some channel differs from the true render by more than this
#: (the one threshold of every colour error: :data:`service.lod.settings.COLOUR_LEVELS`).
WRONG_LEVELS = COLOUR_LEVELS
#: Out-of-view margin of the variants, px on every side.
MARGIN = 16
#: Extra triangles (beyond the rotating cube scene's 252) of the complexity steps.
COMPLEXITY_COUNTS = (0, 300, 1000, 3000, 10000, 30000, 100000)
#: Centre spacing and radius (world units) of the complexity scene's spheres.
SPHERE_PITCH, SPHERE_RADIUS = 0.25, 0.1
#: Refreshes timed after each update (1-15, as :func:`timing` does).
REFRESHES_PER_UPDATE = 15


# ------------------------------------------------------------------ scenes
def _obj(mesh, pos, colour, ori=None, **motion) -> SceneObject:
    q = ori if ori is not None else axis_angle_quaternion([1, 1, 0], 0.5)
    return SceneObject(mesh, Material(colour=colour, ambient=0.35, diffuse=0.8, specular=0.4),
                       Transform(np.array(pos, float), q), MotionState(**motion))


def bench_scene(motion: str) -> Scene:
    """The sweep's scene for a motion: a moving cube before a far wall (and a near post)."""
    wall = SceneObject(cube(1.0), Material(colour=(0.35, 0.45, 0.6), ambient=0.6, diffuse=0.5),
                       Transform(np.array([0.0, 0.0, -3.0]), scale=4.0))
    kinds = {
        "linear": dict(pos=[-0.5, 0.1, -0.6], velocity=[0.9, 0.2, 0.0]),
        "falling": dict(pos=[0.0, 0.45, -0.6], acceleration=[0.0, -3.0, 0.0]),
        "rotating-cube": dict(pos=[0.0, 0.0, -0.6], angular_velocity=[0.0, 2.5, 0.8]),
        "head-turn": dict(pos=[0.2, 0.0, -0.4]),
    }
    k = dict(kinds[motion])
    pos = k.pop("pos")
    mover = _obj(cube(0.5), pos, (0.9, 0.55, 0.2), **k)
    post = _obj(cube(0.15), [-0.4, -0.2, 0.1], (0.2, 0.8, 0.3))
    return Scene([wall, *_studs(), mover, post],
                 lights=[Light(vector=np.array([0.4, 0.6, 1.0]))], ambient=1.0)


def _studs() -> list[SceneObject]:
    """Small coloured cubes on the wall, so that sliding images have texture."""
    xy = [(x, y) for x in (-1.5, -0.9, -0.3, 0.3, 0.9, 1.5) for y in (-0.5, 0.0, 0.5)]
    return [_obj(cube(0.2), [x, y, -0.92], (0.2 + 0.2 * (i % 4), 0.3 + 0.15 * (i % 3),
                                           0.9 - 0.2 * (i % 4)))
            for i, (x, y) in enumerate(xy)]


def bar_scene() -> Scene:
    """A thin near bar sweeping fast across the far wall (what the obscuration cache is for)."""
    c = cube(1.0)
    bar_mesh = Mesh(c.vertices * np.array([0.1, 1.6, 0.1]), c.polygons, c.counts, "bar")
    wall = bench_scene("head-turn").objects[0]
    bar = _obj(bar_mesh, [-0.8, 0.0, -0.3], (0.95, 0.9, 0.85), ori=np.array([1.0, 0, 0, 0]),
               velocity=[2.4, 0.0, 0.0])
    return Scene([wall, *_studs(), bar], lights=[Light(vector=np.array([0.4, 0.6, 1.0]))],
                 ambient=1.0)


def head_track(frames: int, noise_deg: float = 0.05, seed: int = 3):
    """True yaw (rad) per refresh, and filtered (yaw, rate, accel) per refresh, per second."""
    head = HeadTurn(amplitude=25.0, turn_s=1.0, hold_s=0.5)
    t = 0.25 + np.arange(frames) / HZ
    yaw = np.array([head.pose(float(x)).yaw for x in t])
    samples = np.zeros((frames, 6))
    samples[:, 3] = yaw + noise_deg * np.random.default_rng(seed).standard_normal(frames)
    p, v, a = run_filter("alpha-beta-gamma", t, samples, AlphaBetaGammaSettings.from_theta(0.5))
    return np.radians(yaw), np.radians(np.stack([p[:, 3], v[:, 3], a[:, 3]], 1))


def _viewer(yaw: float) -> Transform:
    return Transform(np.zeros(3), axis_angle_quaternion([0, 1, 0], yaw))


# ------------------------------------------------------------ measurements
def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB of two uint8 images (99 when identical)."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 99.0 if mse == 0 else 10.0 * math.log10(255.0**2 / mse)


def pct_wrong(a: np.ndarray, b: np.ndarray) -> float:
    """% of pixels whose largest channel difference exceeds :data:`WRONG_LEVELS`."""
    d = np.abs(a.astype(np.int16) - b.astype(np.int16)).max(axis=-1)
    return 100.0 * float((d > WRONG_LEVELS).mean())


def prepare(motion: str, display: DisplaySettings, frames: int, settings: RenderSettings,
            margin: int = 0):
    """Truth renders (F,) and updates (F,) of a motion: every refresh rendered both ways.

    With ``margin``, updates are rendered ``margin`` px wider on every side (full
    out-of-view buffering); truth stays the display's size.
    """
    scene, r = (bar_scene() if motion == "sweeping-bar" else bench_scene(motion)), Renderer()
    big = margin_display(display, margin)
    truth, updates, viewer = [], [], []
    track = head_track(frames) if motion == "head-turn" else None
    for k in range(frames):
        t = k / HZ
        if track is None:
            truth.append(r.render(advance_scene(scene, t), display, settings).colour)
            updates.append(render_with_motion(r, advance_scene(scene, t), big, 0.0, HZ,
                                              settings))
            continue
        yaw, est = track[0][k], track[1][k]
        truth.append(r.render(view_scene(scene, _viewer(yaw)), display, settings).colour)
        vm = MotionState(angular_velocity=[0, est[1], 0], angular_acceleration=[0, est[2], 0])
        viewer.append(vm)
        updates.append(render_with_motion(r, scene, big, 0.0, HZ, settings,
                                          viewer=_viewer(yaw), viewer_motion=vm))
    return truth, updates, viewer or None


def run_stage(truth, updates, display, gs: GalileanSettings, interval: int,
              viewer: list | None = None) -> dict:
    """Drive a stage with updates every ``interval``; score the extrapolated refreshes.

    ``viewer`` (per refresh) feeds the filtered head motion to the stage at every
    refresh between updates (the head-motion global update).
    """
    st = GalileanStage(display, gs)
    ps, wr, ms = [], [], []
    for k in range(len(truth)):
        if k % interval == 0:
            st.update(updates[k], k)
        elif viewer is not None:
            st.viewer(viewer[k])
        t0 = time.perf_counter()
        out = st.refresh()
        ms.append((time.perf_counter() - t0) * 1e3)
        if k % interval:
            ps.append(psnr(out.colour, truth[k]))
            wr.append(pct_wrong(out.colour, truth[k]))
    return {"psnr": float(np.mean(ps)) if ps else None,
            "pct_wrong": float(np.mean(wr)) if wr else None,
            "ms_per_refresh": float(np.median(ms)), "scored": len(ps)}


def sweep(display: DisplaySettings, frames: int, settings: RenderSettings,
          motions: tuple[str, ...] = MOTIONS, intervals: tuple[int, ...] = INTERVALS
          ) -> list[dict]:
    """Motions x orders x intervals (all of them unless ``motions`` / ``intervals`` say)."""
    rows = []
    for motion in motions:
        print(f"galilean sweep: {motion}", file=sys.stderr, flush=True)
        truth, updates, _ = prepare(motion, display, frames, settings)
        for order in ORDERS:
            for k in intervals:
                gs = GalileanSettings(order=order, refresh_hz=HZ)
                rows.append({"motion": motion, "order": order, "interval": k,
                             **run_stage(truth, updates, display, gs, k)})
    return rows


#: Variants: name -> (margin, margin rendered (full out-of-view buffering), cache,
#: head-motion update every refresh).
VARIANTS = {
    "plain": (0, False, False, False),
    "margin, cache-only": (MARGIN, False, False, False),
    "margin, full out-of-view": (MARGIN, True, False, False),
    "obscuration cache": (0, False, True, False),
    "head-motion update": (0, False, False, True),
    "all": (MARGIN, True, True, True),
}


def variants(display: DisplaySettings, frames: int, settings: RenderSettings) -> list[dict]:
    """The benefit of the out-of-view margin and of the obscuration cache (G(2), interval 8)."""
    rows = []
    for motion in ("head-turn", "sweeping-bar", "linear"):
        print(f"galilean variants: {motion}", file=sys.stderr, flush=True)
        truth, updates, viewer = prepare(motion, display, frames, settings)
        wide = prepare(motion, display, frames, settings, MARGIN)[1]
        for name, (margin, rendered, cache, head) in VARIANTS.items():
            if head and viewer is None:
                continue
            gs = GalileanSettings(order=2, refresh_hz=HZ, margin=margin, cache=cache)
            ups = wide if rendered else updates
            rows.append({"motion": motion, "variant": name, "order": 2, "interval": 8,
                         **run_stage(truth, ups, display, gs, 8, viewer if head else None)})
    return rows


def head_turn() -> MotionState:
    """A head turn for :func:`timing`: every galpixel moves (none is left in place)."""
    return MotionState(velocity=[0.1, 0.0, 0.0], angular_velocity=[0.0, 0.6, 0.0])


def _time_refreshes(st: GalileanStage, r: Renderer, scene: Scene, display: DisplaySettings,
                    settings: RenderSettings, repeats: int) -> tuple[list, list]:
    """Time ``repeats`` refreshes of ``st``, each followed by a (timed) render of ``scene``."""
    ms, mr = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        st.refresh()
        t1 = time.perf_counter()
        r.render(scene, display, settings)
        ms.append((t1 - t0) * 1e3)
        mr.append((time.perf_counter() - t1) * 1e3)
    return ms, mr


def timing(size: tuple[int, int], settings: RenderSettings, repeats: int = 15) -> dict:
    """Milliseconds of one refresh per order (Poisson and expansion on) vs a render, at ``size``.

    Renders and refreshes are interleaved, so that the ratio is measured side by
    side on a machine shared with other work.  The rotating cube leaves most of
    the frame (the wall) still, which a refresh need not rewrite; the
    ``-head-motion`` run adds a head turn after the update, so that every
    galpixel moves.
    """
    display = DisplaySettings(zones=1, cols=size[0], rows=size[1])
    scene, r = bench_scene("rotating-cube"), Renderer()
    r.render(scene, display, settings)
    up = render_with_motion(r, scene, display, 0.0, HZ, settings)
    updates = []
    for _ in range(5):  # the median of five: a single call once read 47 ms against 15
        t0 = time.perf_counter()
        render_with_motion(r, scene, display, 0.0, HZ, settings)
        updates.append((time.perf_counter() - t0) * 1e3)
    ms_update = float(np.median(updates))
    out = {"size": f"{size[0]}x{size[1]}", "render_with_motion_ms": ms_update, "orders": {}}
    runs = [(order, cm, 1, False) for order in ORDERS for cm in (True, False)]
    runs += [(2, True, 0, False), (2, True, 0, True)]
    for order, cm, threads, head in runs:
        st = GalileanStage(display, GalileanSettings(order=order, refresh_hz=HZ,
                                                     colour_motion=cm, threads=threads))
        st.update(up, 0)
        st.refresh()
        if head:  # after the graft: a viewer motion handed in before it is replaced by it
            st.viewer(head_turn())
            st.refresh()
        ms, mr = _time_refreshes(st, r, scene, display, settings, repeats)
        key = f"G{order}" + ("" if cm else "-no-colour-motion") + \
            ("-all-threads" if threads == 0 else "") + ("-head-motion" if head else "")
        med, rmed = float(np.median(ms)), float(np.median(mr))
        out["orders"][key] = {"ms_per_refresh": med, "ms_min": float(np.min(ms)),
                              "render_ms": rmed, "render_ratio": rmed / med,
                              "update_ratio": ms_update / med}
    return out


def shadow_timing(size: tuple[int, int], settings: RenderSettings, repeats: int = 7) -> dict:
    """Milliseconds of a local update's shadow render, depth only against the full renderer.

    Scene: the sweeping bar in front of the studded wall at ``size``; the local
    update re-renders the wall (object 0), whose obscurers (bar and studs) are
    shadow-rendered.  Interleaved, median of ``repeats``:

    * ``shadow_depth_ms``: :func:`service.galilean.shadow.shadow_depth` of the obscurers;
    * ``render_ms``: a full :meth:`Renderer.render` of the same obscurers;
    * ``render_with_motion_ms``: what the full path computed for them (colour,
      light, motion);
    * ``local_depth_ms`` / ``local_full_ms``: the whole ``render_local`` both ways.
    """
    display = DisplaySettings(zones=1, cols=size[0], rows=size[1])
    scene, r = bar_scene(), Renderer()
    fixed = FixedPoint.for_order(bit_budget(max(size), 16, 16), 2)
    ctl = control_points(scene, 0.0, display)
    second = obscurers(scene, [0], *ctl)
    sub = Scene([scene.objects[i] for i in second], list(scene.lights), scene.ambient)
    jobs = {
        "shadow_depth_ms": lambda: shadow_depth(scene, second, display, 0.0, settings.cull),
        "render_ms": lambda: r.render(sub, display, settings),
        "render_with_motion_ms": lambda: render_with_motion(r, sub, display, 0.0, HZ, settings),
        "local_depth_ms": lambda: render_local(r, scene, display, [0], 0.0, HZ, 2, fixed,
                                               settings=settings, control=ctl, shadow="depth"),
        "local_full_ms": lambda: render_local(r, scene, display, [0], 0.0, HZ, 2, fixed,
                                              settings=settings, control=ctl, shadow="full"),
    }
    times: dict[str, list[float]] = {k: [] for k in jobs}
    for f in jobs.values():
        f()
    for _ in range(repeats):
        for k, f in jobs.items():
            t0 = time.perf_counter()
            f()
            times[k].append((time.perf_counter() - t0) * 1e3)
    out = {"size": f"{size[0]}x{size[1]}", "obscurers": len(second)}
    out.update({k: float(np.median(v)) for k, v in times.items()})
    out["render_over_shadow"] = out["render_ms"] / out["shadow_depth_ms"]
    out["render_with_motion_over_shadow"] = out["render_with_motion_ms"] / out["shadow_depth_ms"]
    return out


def chart_timing(tm: dict, path: Path) -> Figure:
    """Bar chart: ms per refresh per order against the render of the same frame."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    keys = list(tm["orders"])
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.bar(keys, [tm["orders"][k]["ms_per_refresh"] for k in keys], label="refresh (median)")
    ren = float(np.median([tm["orders"][k]["render_ms"] for k in keys]))
    ax.axhline(ren, color="C3", label=f"render of the frame ({ren:.1f} ms)")
    ax.axhline(ren / 10, color="C3", ls="--", label="render / 10")
    if "shadow" in tm:
        ax.axhline(tm["shadow"]["shadow_depth_ms"], color="C2", ls=":",
                   label="depth-only shadow render of the obscurers")
    ax.set_ylabel(f"ms at {tm['size']}")
    ax.tick_params(axis="x", labelrotation=30)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_chart(fig, path, dpi=90)


def run_timing(out: Path, time_size: tuple[int, int]) -> dict:
    """``--timing``: refresh vs render and shadow vs full render; JSON, CSV and PNG."""
    out.mkdir(parents=True, exist_ok=True)
    settings = RenderSettings(light=LightSettings("blinn"))
    warm_up(settings)
    tm = timing(time_size, settings)
    tm["shadow"] = shadow_timing(time_size, settings)
    (out / "galilean_timing.json").write_text(json.dumps(tm, indent=1))
    write_csv([{"key": k, **v} for k, v in tm["orders"].items()], out / "galilean_timing.csv")
    chart_timing(tm, out / "galilean_timing.png")
    return tm


# -------------------------------------------------------- scene complexity
def sphere_grid(extra: int, display: DisplaySettings) -> list[SceneObject]:
    """Spinning, drifting spheres on a grid over the display, about ``extra`` triangles.

    Parameters
    ----------
    extra : int
        Triangles wanted in all; 0 (or less) gives no spheres.  Every sphere gets
        the same UV tessellation, chosen so that the total is near ``extra`` (at
        least 6 triangles a sphere).
    display : DisplaySettings
        The grid (pitch :data:`SPHERE_PITCH`) covers its display plane at z = -0.7,
        between the studded wall and the cube, so every sphere is in view.

    Returns
    -------
    list of SceneObject
    """
    if extra <= 0:
        return []
    nx = max(1, int(display.width / SPHERE_PITCH))
    ny = max(1, int(display.height / SPHERE_PITCH))
    per = extra / (nx * ny)
    bands = 1 + max(1, round(math.sqrt(per / 4)))
    mesh = sphere(SPHERE_RADIUS, bands, max(3, round(per / (2 * (bands - 1)))))
    x0, y0 = -(nx - 1) * SPHERE_PITCH / 2, -(ny - 1) * SPHERE_PITCH / 2
    return [_obj(mesh, [x0 + i * SPHERE_PITCH, y0 + j * SPHERE_PITCH, -0.7],
                 (0.3 + 0.12 * (i % 5), 0.5, 0.9 - 0.12 * (j % 5)),
                 velocity=[0.2 * (-1) ** (i + j), 0.1, 0.0], angular_velocity=[0.0, 2.0, 0.5])
            for i in range(nx) for j in range(ny)]


def complexity_scene(extra: int, display: DisplaySettings) -> Scene:
    """The rotating cube bench scene plus :func:`sphere_grid` of ``extra`` triangles."""
    base = bench_scene("rotating-cube")
    return Scene([*base.objects, *sphere_grid(extra, display)], lights=list(base.lights),
                 ambient=base.ambient)


def triangle_count(scene: Scene) -> int:
    """Triangles the renderer rasterises for ``scene`` (fan triangulation, before culling)."""
    return int(sum(len(o.mesh.triangles) for o in scene.objects))


def _complexity_step(r: Renderer, scene: Scene, display: DisplaySettings,
                     settings: RenderSettings, repeats: int) -> dict:
    """Median (and best) ms of a render, a G(2) refresh and the G(2) ``render_with_motion``.

    ``*_cpu_ms`` are the medians of the process's CPU time (all threads), which a
    machine shared with other work inflates far less than the wall time.

    The three are called in turn in every repeat (so each refresh follows a
    render, as in :func:`timing`); the stage is updated once per
    :data:`REFRESHES_PER_UPDATE` refreshes and the refresh grafting it is not
    timed.  ``refresh_expanded`` / ``refresh_clashes`` are the last timed
    refresh's counters: the part of a refresh's work that grows with what moves.
    """
    frame = r.render(scene, display, settings)
    up = render_with_motion(r, scene, display, 0.0, HZ, settings)
    st = GalileanStage(display, GalileanSettings(order=2, refresh_hz=HZ, order_guard=False))
    jobs = {"render_ms": lambda: r.render(scene, display, settings),
            "refresh_ms": st.refresh,
            "render_with_motion_ms": lambda: render_with_motion(r, scene, display, 0.0, HZ,
                                                                settings, order=2)}
    times: dict[str, list[float]] = {k: [] for k in jobs}
    cpu: dict[str, list[float]] = {k: [] for k in jobs}  # process CPU ms, all threads
    last: dict = {}
    for i in range(repeats):
        if i % REFRESHES_PER_UPDATE == 0:
            st.update(up)
            st.refresh()
        for k, f in jobs.items():
            c0, t0 = time.process_time(), time.perf_counter()
            last[k] = f()
            times[k].append((time.perf_counter() - t0) * 1e3)
            cpu[k].append((time.process_time() - c0) * 1e3)
    med = {k: float(np.median(v)) for k, v in times.items()}
    moving = np.any(np.abs(up.derivatives[0, :2]) > 1e-3, axis=0)  # px per refresh
    stats = last["refresh_ms"].stats
    return {"triangles": triangle_count(scene),
            "polygons_drawn": int(frame.stats["polygons"]["drawn"]),
            "moving_pct": 100.0 * float(moving.mean()), **med,
            "render_ratio": med["render_ms"] / med["refresh_ms"],
            "update_ratio": med["render_with_motion_ms"] / med["refresh_ms"],
            **{k.replace("_ms", "_ms_min"): float(np.min(v)) for k, v in times.items()},
            **{k.replace("_ms", "_cpu_ms"): float(np.median(v)) for k, v in cpu.items()},
            "refresh_expanded": int(stats.get("expanded", 0)),
            "refresh_clashes": int(stats.get("clashes", 0))}


def _crossover(steps: list[dict], key: str, factor: float = 10.0) -> int | None:
    """Triangle count of the first step whose ``key`` ratio is >= ``factor`` (None if none)."""
    return next((s["triangles"] for s in steps if s[key] >= factor), None)


def complexity_timing(size: tuple[int, int], settings: RenderSettings,
                      counts: tuple[int, ...] = COMPLEXITY_COUNTS, repeats: int = 15) -> dict:
    """Render, update and G(2) refresh ms against scene complexity, at ``size``, one zone.

    Parameters
    ----------
    size : tuple of int
        Display (cols, rows).
    settings : RenderSettings
        Render settings of the render and of ``render_with_motion``.
    counts : tuple of int
        Extra triangles per step (:func:`complexity_scene`); steps run in
        increasing order, and a step adding no triangles to the one before is skipped.
    repeats : int
        Interleaved calls of each per step; the medians are reported.

    Returns
    -------
    dict
        ``size``, ``repeats``, ``steps`` (per step: ``triangles``,
        ``polygons_drawn`` (polygons with a pixel in the render), ``moving_pct``
        (% of pixels the update moves by more than 0.001 px per refresh),
        ``render_ms``, ``refresh_ms``, ``render_with_motion_ms``, ``render_ratio``
        and ``update_ratio``, the last two over ``refresh_ms``; ``*_ms_min``, the
        best of each; ``refresh_expanded``, ``refresh_clashes``) and
        ``crossover_10x_render`` / ``crossover_10x_update``: the smallest triangle
        count whose ratio is >= 10, or None.
    """
    display = DisplaySettings(zones=1, cols=size[0], rows=size[1])
    r, steps = Renderer(), []
    for extra in sorted(set(counts)):
        scene = complexity_scene(extra, display)
        if steps and triangle_count(scene) <= steps[-1]["triangles"]:
            continue
        print(f"galilean complexity: {triangle_count(scene)} triangles", file=sys.stderr,
              flush=True)
        steps.append(_complexity_step(r, scene, display, settings, repeats))
    return {"size": f"{size[0]}x{size[1]}", "zones": 1, "order": 2, "refresh_hz": HZ,
            "repeats": repeats, "steps": steps,
            "crossover_10x_render": _crossover(steps, "render_ratio"),
            "crossover_10x_update": _crossover(steps, "update_ratio")}


def _crossing(triangles: int | None) -> str:
    """A 10x crossover for a chart title: where it is, or that none was measured."""
    return "not in the range" if triangles is None else f"from {triangles} triangles"


def chart_complexity(cx: dict, path: Path) -> Figure:
    """Log-log ms against triangles: render, ``render_with_motion``, refresh and 10x refresh.

    Parameters
    ----------
    cx : dict
        What :func:`complexity_timing` returns.
    path : Path
        PNG to write.
    """
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    tri = [s["triangles"] for s in cx["steps"]]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for key, label, style in (("render_ms", "Renderer.render", "o-"),
                              ("render_with_motion_ms", "render_with_motion (update)", "s-"),
                              ("refresh_ms", "G(2) refresh", "^-")):
        ax.plot(tri, [s[key] for s in cx["steps"]], style, label=label)
    ax.plot(tri, [10 * s["refresh_ms"] for s in cx["steps"]], "k--", label="10 x refresh")
    ax.set(xscale="log", yscale="log", xlabel="triangles in the scene",
           ylabel=f"ms at {cx['size']}, one zone (median)",
           title="refresh 10x cheaper than a render: "
                 + _crossing(cx["crossover_10x_render"]) + "; than an update: "
                 + _crossing(cx["crossover_10x_update"]))
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_chart(fig, path, dpi=90)


def run_complexity(out: Path, time_size: tuple[int, int],
                   counts: tuple[int, ...] = COMPLEXITY_COUNTS, repeats: int = 15) -> dict:
    """``--complexity``: :func:`complexity_timing` into JSON, CSV and PNG under ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    settings = RenderSettings(light=LightSettings("blinn"))
    warm_up(settings)
    cx = complexity_timing(time_size, settings, counts, repeats)
    (out / "galilean_complexity.json").write_text(json.dumps(cx, indent=1))
    write_csv(cx["steps"], out / "galilean_complexity.csv")
    chart_complexity(cx, out / "galilean_complexity.png")
    return cx


def thought_experiments() -> dict:
    """The paper's numbers, for the record and the charts."""
    fall = {f"G{o}_K{k}": run_case(CASES["falling"](), o, k, 10).errors(True).tolist()
            for o in (0, 1, 2) for k in (2, 3)}
    sq = {f"G{o}": radius_shown(run_case(CASES["rotating-square"](), o, 8, 32)).tolist()
          for o in (1, 2)}
    cube_err = {f"G{o}": float(run_case(CASES["galcube"](), o, 5, 5, subpixel=True)
                               .subpixel_errors()[4]) for o in range(3)}
    tracker = {f"{e}_G{o}": {str(k): float(run_tracker(e, o, k).max()) for k in (4, 8, 16)}
               for e in ("raw", "alpha-beta-gamma") for o in (2, 3)}
    return {"falling_errors": fall, "rotating_square_radius": sq,
            "galcube_measured_t4": cube_err,
            "galcube_paper": {f"G{k}": v for k, v in galcube_paper().items()},
            "tracker_max_error": tracker}


# ------------------------------------------------------------------ charts
def chart_sweep(rows: list[dict], path: Path) -> None:
    """PSNR vs interval (one panel per motion, a line per order) and PSNR vs ms."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    motions = [m for m in MOTIONS if any(r["motion"] == m for r in rows)]
    fig, axes = plt.subplots(1, len(motions) + 1, figsize=(4.2 * (len(motions) + 1), 3.8))
    for ax, motion in zip(axes, motions, strict=False):
        for order in ORDERS:
            pts = [(r["interval"], r["psnr"]) for r in rows
                   if r["motion"] == motion and r["order"] == order and r["psnr"] is not None]
            if pts:
                ax.plot(*zip(*pts, strict=True), marker="o", label=f"G({order})")
        ax.set_xscale("log", base=2)
        ax.set(title=motion, xlabel="update interval (refreshes)", ylabel="PSNR dB")
        ax.legend(fontsize=7)
    ax = axes[-1]
    for order in ORDERS:
        pts = [(r["ms_per_refresh"], r["psnr"]) for r in rows
               if r["order"] == order and r["psnr"] is not None]
        ax.scatter(*zip(*pts, strict=True), s=12, label=f"G({order})")
    ax.set(title="cost vs quality", xlabel="ms per refresh", ylabel="PSNR dB")
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_chart(fig, path, dpi=110)


def chart_thought(te: dict, path: Path) -> None:
    """Falling-object errors, rotating-square size, tracker errors."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    for key, errs in te["falling_errors"].items():
        if key.endswith("K3"):
            axes[0].plot(errs, marker="o", label=key)
    axes[0].set(title="falling object, update every 3", xlabel="refresh", ylabel="error px")
    for key, rad in te["rotating_square_radius"].items():
        axes[1].plot(rad, label=key)
    axes[1].set(title="rotating square: shown radius (true 100)", xlabel="refresh")
    for key, d in te["tracker_max_error"].items():
        axes[2].plot([int(k) for k in d], list(d.values()), marker="o", label=key)
    axes[2].set(title="head turn via tracker", xlabel="interval", ylabel="max error px",
                yscale="log")
    for ax in axes:
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_chart(fig, path, dpi=110)


# ------------------------------------------------------------------- cases
def thought_case(name: str, order: int, interval: int, frames: int) -> dict:
    """A thought experiment: displayed positions, exact positions and errors per refresh."""
    run_case(CASES[name](), order, interval, 1)  # compile / load the kernels first
    t0 = time.perf_counter()
    run = run_case(CASES[name](), order, interval, frames)
    ms = (time.perf_counter() - t0) * 1e3 / frames
    one_d = name in ONE_D
    return {"case": name, "order": order, "interval": interval,
            "errors": [float(e) for e in run.errors(one_d)], "ms_per_refresh": ms,
            "shown": run.shown[:, 0].tolist(), "exact": run.exact[:, 0].tolist(),
            "updated": run.updated.tolist()}


def _vertex_motion(scene: Scene, t: float, display: DisplaySettings, obj: int, h: float = 0.25):
    """Exact (V, 2) positions of object ``obj``'s vertices and (3, V, 2) derivatives.

    Positions are in pixel-index units (pixel ``c`` is centred on ``c``), as galpixels are.
    """
    projs = [control_points(scene, t + k * h / HZ, display) for k in (-2, -1, 0, 1, 2)]
    owner = projs[0][1] == obj
    p = np.stack([pr[0][0, owner, :2] for pr in projs]) - 0.5
    return p[2], vertex_derivatives(p[:, None], h)[:, 0]


def scene_case(order: int, interval: int, frames: int, size=(160, 120)) -> dict:
    """A drifting, spinning cube rendered and propagated by the real stage.

    Errors are the largest distance between the cube's control points as the
    galpixel arithmetic displays them and their exact projections; PSNR compares
    the stage's refreshes with true renders.
    """
    display = DisplaySettings(zones=1, cols=size[0], rows=size[1])
    scene = bench_scene("rotating-cube")
    i = len(scene.objects) - 2  # the cube (then the post)
    mover = scene.objects[i]
    scene.objects[i] = SceneObject(mover.mesh, mover.material, mover.transform,
                                   MotionState(velocity=[0.4, 0.1, 0.0],
                                               angular_velocity=[0.0, 2.5, 0.8]))
    settings = RenderSettings(light=LightSettings("blinn"))
    fixed = FixedPoint.for_order(bit_budget(max(size), 16, 16), order)
    st, r = GalileanStage(display, GalileanSettings(order=order, refresh_hz=HZ)), Renderer()
    errors, shown, exact, ps, ms = [], [], [], [], []
    for k in range(frames):
        if k % interval == 0:
            st.update(render_with_motion(r, scene, display, k / HZ, HZ, settings), k)
            pos, der = _vertex_motion(scene, k / HZ, display, i)
            x, v, a, j = points_fixed(pos, der, fixed, order)
            path = propagate_points(x, v, a, j, order, fixed.fp, fixed.fm, interval)
        t0 = time.perf_counter()
        out = st.refresh()
        ms.append((time.perf_counter() - t0) * 1e3)
        disp = pixel_of(path[k % interval], fixed.fp).astype(float)
        true = _vertex_motion(scene, k / HZ, display, i)[0]
        errors.append(float(np.abs(true - disp).max()))
        shown.append(disp[0].tolist())
        exact.append(true[0].tolist())
        ps.append(psnr(out.colour, r.render(advance_scene(scene, k / HZ), display,
                                            settings).colour))
    return {"case": "scene", "order": order, "interval": interval, "errors": errors,
            "ms_per_refresh": float(np.median(ms[1:] or ms)), "psnr": ps, "shown": shown,
            "exact": exact}


def print_case(res: dict) -> None:
    """Per refresh: displayed position, exact position, error."""
    print(f"case {res['case']}  G({res['order']})  update every {res['interval']} refreshes")
    print(f"{'refresh':>7}  {'displayed':>18}  {'exact':>22}  {'error px':>9}")
    for k, (s, e, err) in enumerate(zip(res["shown"], res["exact"], res["errors"], strict=True)):
        fs = " ".join(f"{v:7.1f}" for v in np.atleast_1d(s))
        fe = " ".join(f"{v:9.3f}" for v in np.atleast_1d(e))
        print(f"{k:7d}  {fs:>18}  {fe:>22}  {err:9.3f}")
    print(f"ms per refresh: {res['ms_per_refresh']:.4f}")


# -------------------------------------------------------------------- main
#: ``--sweep --quick``: the motions and intervals swept (no variants, 3 complexity repeats).
QUICK_MOTIONS, QUICK_INTERVALS = ("linear", "rotating-cube"), (1, 4, 16)
#: Seconds without a render of the starvation runs (issue 29: 3 s of refreshes).
STARVE_S = 3.0


def run_sweep(out: Path, size: tuple[int, int], frames: int, time_size: tuple[int, int],
              counts: tuple[int, ...] = COMPLEXITY_COUNTS, quick: bool = False) -> None:
    """Everything ``--sweep`` writes (``counts``: the complexity steps' extra triangles).

    ``quick`` sweeps :data:`QUICK_MOTIONS` x :data:`QUICK_INTERVALS` only, leaves the
    variants out and times 3 complexity repeats (for ``holo-bench report --quick``).
    """
    out.mkdir(parents=True, exist_ok=True)
    settings = RenderSettings(light=LightSettings("blinn"))
    warm_up(settings)
    display = DisplaySettings(zones=1, cols=size[0], rows=size[1])
    if quick:
        rows = sweep(display, frames, settings, QUICK_MOTIONS, QUICK_INTERVALS)
        var = []
    else:
        rows = sweep(display, frames, settings)
        var = variants(display, frames, settings)
    te = thought_experiments()
    print("galilean sweep: timing", file=sys.stderr, flush=True)
    tm = run_timing(out, time_size)
    cx = run_complexity(out, time_size, counts, 3 if quick else 15)
    sv = run_starvation(out, size, STARVE_S, QUICK_MOTIONS if quick else
                        galilean_starvation.STARVED_MOTIONS)
    doc = {"size": f"{size[0]}x{size[1]}", "frames": frames, "refresh_hz": HZ,
           "wrong_levels": WRONG_LEVELS, "rows": rows, "variants": var,
           "thought_experiments": te}
    (out / "galilean_sweep.json").write_text(json.dumps(doc, indent=1))
    write_csv(rows, out / "galilean_sweep.csv")
    if var:
        write_csv(var, out / "galilean_variants.csv")
    chart_sweep(rows, out / "galilean_sweep.png")
    chart_thought(te, out / "galilean_thought.png")
    print(json.dumps({"timing": tm, "complexity": cx, "variants": var,
                      "starvation": sv["summary"]}, indent=1))


def _starved(motion: str, display: DisplaySettings, settings: RenderSettings,
             refreshes: int) -> tuple:
    """The one render of a starvation run and ``truth(k)``, the true render k refreshes on."""
    scene, r = bench_scene(motion), Renderer()
    if motion != "head-turn":
        return (render_with_motion(r, scene, display, 0.0, HZ, settings),
                lambda k: r.render(advance_scene(scene, k / HZ), display, settings).colour)
    yaw, _ = head_track(refreshes + 1)
    up = render_with_motion(r, scene, display, 0.0, HZ, settings, viewer=_viewer(yaw[0]),
                            viewer_motion=_starved_viewer(refreshes)(0))
    return up, lambda k: r.render(view_scene(scene, _viewer(yaw[k])), display, settings).colour


def _starved_viewer(refreshes: int):
    """``viewer(k)``: the head turn's filtered motion at refresh k (as :func:`prepare`)."""
    _, est = head_track(refreshes + 1)
    return lambda k: MotionState(angular_velocity=[0, est[k][1], 0],
                                 angular_acceleration=[0, est[k][2], 0])


def run_starvation(out: Path, size: tuple[int, int], seconds: float,
                   motions: tuple[str, ...] = galilean_starvation.STARVED_MOTIONS) -> dict:
    """``galilean_starvation.*``: ``motions`` starved ``seconds`` at ``size``; returns the JSON."""
    out.mkdir(parents=True, exist_ok=True)
    settings = RenderSettings(light=LightSettings("blinn"))
    display = DisplaySettings(zones=1, cols=size[0], rows=size[1])
    refreshes = max(1, round(seconds * HZ))
    rows = []
    for motion in motions:
        print(f"galilean starvation: {motion}", file=sys.stderr, flush=True)
        rows += galilean_starvation.starve(
            *_starved(motion, display, settings, refreshes), motion, display, refreshes, HZ,
            lambda a, b: (psnr(a, b), pct_wrong(a, b)),
            _starved_viewer(refreshes) if motion == "head-turn" else None)
    return galilean_starvation.write(rows, GalileanSettings.n_prop, HZ, out)


def _counts(text: str) -> tuple[int, ...]:
    """Parse ``--complexity-counts``: comma-separated integers >= 0."""
    try:
        counts = tuple(int(c) for c in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"want integers like 0,1000,10000, got {text!r}") \
            from None
    if not counts or min(counts) < 0:
        raise argparse.ArgumentTypeError(f"counts must be >= 0, got {text!r}")
    return counts


def main(argv: list[str] | None = None) -> int:
    """``holo-bench galilean``; returns the exit status."""
    p = argparse.ArgumentParser(prog="holo-bench galilean", description=plain_help(__doc__),
                                epilog=exit_rule_epilog(),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--case", choices=[*CASES, "scene"], default="falling")
    p.add_argument("--order", type=int, default=2, choices=ORDERS)
    p.add_argument("--interval", metavar="N", type=int_range(1), default=2,
                   help="refreshes per update (default: %(default)s)")
    p.add_argument("--frames", metavar="N", type=int_range(1), default=10,
                   help="refreshes to run (default: %(default)s)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--sweep", action="store_true", help="run the full sweep into --out")
    p.add_argument("--quick", action="store_true",
                   help="with --sweep: two motions, intervals 1,4,16, no variants")
    p.add_argument("--timing", action="store_true",
                   help="only the --time-size timing (refresh, render, shadow) into --out")
    p.add_argument("--starvation", action="store_true",
                   help="only the starvation runs (one render, then none) into --out")
    p.add_argument("--starve-seconds", metavar="S", type=float_range(0.05, 60.0),
                   default=STARVE_S,
                   help="seconds without a render in the starvation runs (default: %(default)s)")
    p.add_argument("--complexity", action="store_true",
                   help="only the --time-size timing against scene complexity into --out")
    p.add_argument("--complexity-counts", metavar="N,...", type=_counts, default=COMPLEXITY_COUNTS,
                   help="extra triangles per complexity step, comma-separated "
                        "(default %(default)s)")
    p.add_argument("--complexity-repeats", metavar="N", type=int_range(1), default=15,
                   help="interleaved calls per complexity step (default: %(default)s)")
    p.add_argument("--out", metavar="DIR", default="bench-out",
                   help="output folder (default bench-out)")
    add_size_option(p, (160, 120), "sweep render size")
    p.add_argument("--sweep-frames", metavar="N", type=int_range(2), default=33,
                   help="refreshes per sweep run (default: %(default)s)")
    add_size_option(p, (640, 480), "size of the timing run", flag="--time-size")
    args = p.parse_args(argv)
    if args.complexity:
        print(json.dumps(run_complexity(Path(args.out), args.time_size,
                                        args.complexity_counts, args.complexity_repeats),
                         indent=1))
        return 0
    if args.starvation:
        doc = run_starvation(Path(args.out), args.size, args.starve_seconds)
        print(json.dumps(doc["summary"], indent=1))
        return 0
    if args.timing:
        print(json.dumps(run_timing(Path(args.out), args.time_size), indent=1))
        return 0
    if args.sweep:
        run_sweep(Path(args.out), args.size, args.sweep_frames, args.time_size,
                  args.complexity_counts, args.quick)
        return 0
    res = scene_case(args.order, args.interval, args.frames) if args.case == "scene" else \
        thought_case(args.case, args.order, args.interval, args.frames)
    if args.json:
        keys = ("case", "order", "interval", "errors", "ms_per_refresh")
        print(json.dumps({k: res[k] for k in keys}))
    else:
        print_case(res)
    return 0
