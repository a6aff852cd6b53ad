"""Occlusion benchmark: milliseconds per update against % of pixels unlike ray casting.

For every scene x occlusion method x zone count, render the same frame, time the
whole update (median of several) and compare the polygon seen at every pixel of
every zone with the ray-cast reference.  A second sweep measures how the
run-length method's error (with its z-buffer fallback switched off) grows with the
viewing angle and the zone count, both at the zone centres and for a viewer anywhere
in the viewing angle (who is shown the image of the zone they stand in).  A third
measures what extra zones cost a whole render (flatten to light: z-buffer, Blinn per
polygon) on the game scene, stage by stage.  Writes ``render_bench.json``, ``.csv``,
``zone_cost.json``, ``.csv`` and PNG charts to the output folder.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from service.base.cli_args import add_size_option, comma_list, exit_rule_epilog, plain_help, size
from service.bench import peers as pr
from service.bench.charts import save_chart
from service.bench.peers import plot_peers
from service.bench.rows import write_rows, zones_label
from service.builtin_scenes import builtin_scene
from service.display import DisplaySettings
from service.render.light import LightSettings
from service.render.pipeline import METHOD_NAMES, Renderer, RenderSettings, StageClock, warm_up

if TYPE_CHECKING:
    from matplotlib.figure import Figure

ZONES = (1, 5, 9, 17, 33)
SCENE_NAMES = ("game", "sphere-torus", "cyclic")
ANGLES = (4, 8, 16, 24, 32, 45, 60)


def polygon_map(
    renderer: Renderer, arrays, display, settings, repeats: int
) -> tuple[np.ndarray, float, dict]:
    """Polygon seen at each pixel (Z, R, C) (-1 empty), median update ms and stats.

    The update is stages 1-4 (project, cull, sort, occlusion) of a flattened scene.
    """
    ms = []
    for _ in range(repeats):
        clock: dict[str, float] = {}
        vis, counts, _ = renderer.visibility(arrays, display, settings, StageClock(clock))
        ms.append(sum(clock.values()))
    poly = np.where(vis.triangle >= 0, arrays.triangle_polygon[np.maximum(vis.triangle, 0)], -1)
    return poly, float(np.median(ms)), {**vis.stats, **counts}


def measure(
    scene_name: str,
    zones: int,
    angle: float,
    methods,
    repeats: int,
    fallback="frame",
    size=(320, 240),
):
    """Rows of {scene, zones, angle, method, ms, pct_differ, ...} for one configuration."""
    arrays = builtin_scene(scene_name).flatten()
    display = DisplaySettings(zones=zones, angle_deg=angle, cols=size[0], rows=size[1])
    ref, ref_ms, _ = polygon_map(Renderer(), arrays, display, RenderSettings(method="raycast"), 1)
    rows = []
    for method in methods:
        settings = RenderSettings(
            method=method, painter_fallback=fallback, light=LightSettings("ambient")
        )
        renderer = Renderer()
        if method == "bsp":
            renderer.visibility(arrays, display, settings)  # build the tree once: static geometry
        poly, ms, stats = (
            (ref, ref_ms, {})
            if method == "raycast"
            else polygon_map(renderer, arrays, display, settings, repeats)
        )
        rows.append(
            {
                "scene": scene_name,
                "zones": zones,
                "angle_deg": angle,
                "method": method,
                "fallback": fallback,
                "ms": round(ms, 3),
                "pct_differ": round(100.0 * float(np.mean(poly != ref)), 4),
                "polygons": int(arrays.n_polygons),
                "inconsistent_pixels": int(stats.get("inconsistent_pixels", 0)),
                "fell_back": stats.get("fallback") is not None,
            }
        )
    return rows


ZONE_COST_ZONES = (1, 2, 5, 9)
STAGES = ("flatten", "project", "cull", "sort", "occlusion", "light")


def zone_cost(
    scene_name: str = "game",
    zones=ZONE_COST_ZONES,
    repeats: int = 9,
    rounds: int = 5,
    size=(320, 240),
) -> list[dict]:
    """Whole-render milliseconds per zone count, as ratios to one zone.

    Each round renders ``repeats`` frames at every zone count in turn (so a noisy
    machine slows all counts alike) and keeps each count's median; the rows hold
    the best round's medians.  ``ms`` is wall time around
    :meth:`service.render.pipeline.Renderer.render`; ``ms_<stage>`` are its stage clocks.

    Returns
    -------
    list of dict
        One row per zone count: ``scene, zones, ms, ratio, ms_flatten, ...``.
    """
    scene = builtin_scene(scene_name)
    renderer = Renderer()
    displays = {z: DisplaySettings(zones=z, cols=size[0], rows=size[1]) for z in zones}
    best: dict[int, dict] = {}
    for _ in range(rounds):
        for z, display in displays.items():
            walls, stages = [], []
            for _ in range(repeats):
                t0 = time.perf_counter()
                frame = renderer.render(scene, display)
                walls.append((time.perf_counter() - t0) * 1e3)
                stages.append(frame.stats["ms"])
            row = {"ms": float(np.median(walls))}
            row |= {f"ms_{k}": float(np.median([m.get(k, 0.0) for m in stages])) for k in STAGES}
            if z not in best or row["ms"] < best[z]["ms"]:
                best[z] = row
    base = best[zones[0]]["ms"]
    return [
        {
            "scene": scene_name,
            "zones": z,
            **{k: round(v, 3) for k, v in best[z].items()},
            "ratio": round(best[z]["ms"] / base, 3),
        }
        for z in zones
    ]


def chart_zone_cost(rows: list[dict], path: Path) -> Figure:
    """Stacked bars: milliseconds per stage against the zone count."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4))
    x = np.arange(len(rows))
    bottom = np.zeros(len(rows))
    for stage in STAGES:
        h = np.array([r[f"ms_{stage}"] for r in rows])
        ax.bar(x, h, bottom=bottom, label=stage)
        bottom += h
    ax.plot(x, [r["ms"] for r in rows], "ko-", label="wall")
    for xi, r in zip(x, rows, strict=True):
        ax.annotate(
            f"x{r['ratio']:.2f}",
            (xi, r["ms"]),
            textcoords="offset points",
            xytext=(0, 5),
            ha="center",
            fontsize=8,
        )
    ax.set_xticks(x, [str(r["zones"]) for r in rows])
    ax.set_xlabel("view zones")
    ax.set_ylabel("ms per render (labels: ratio to 1 zone)")
    ax.set_title(f"{rows[0]['scene']} scene: cost of extra zones")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_chart(fig, path, dpi=110)


FINE_ZONES = 64  # directions sampled across the viewing angle for the continuous error


def continuous_error(scene_name: str, zones: int, angle: float, size=(320, 240)) -> float:
    """% of pixels a viewer anywhere in the viewing angle sees wrong with N zones.

    The display shows zone k's image to every viewer inside zone k.  The truth for a
    viewer is the exact image for their own direction: here the z-buffer image for
    each of 64 directions spread evenly across the angle (the z-buffer equals ray
    casting on these scenes).  Each fine direction is compared with the run-length
    image of the zone it falls in, and the pixels showing another object (or
    background) are counted.
    """
    arrays = builtin_scene(scene_name).flatten()
    coarse = DisplaySettings(zones=zones, angle_deg=angle, cols=size[0], rows=size[1])
    fine = DisplaySettings(zones=FINE_ZONES, angle_deg=angle, cols=size[0], rows=size[1])
    shown, _, _ = polygon_map(
        Renderer(), arrays, coarse, RenderSettings("runlength", painter_fallback="off"), 1
    )
    truth, _, _ = polygon_map(Renderer(), arrays, fine, RenderSettings("zbuffer"), 1)
    zone_of = ((np.arange(FINE_ZONES) + 0.5) / FINE_ZONES * zones).astype(int)
    # compare objects, not polygons: a sub-pixel shift over a finely tessellated
    # surface changes the polygon seen but not what the viewer sees
    obj = np.append(arrays.polygon_object, -1)  # index -1 (empty) maps to -1
    return round(100.0 * float(np.mean(obj[shown[zone_of]] != obj[truth])), 4)


def chart_methods(rows: list[dict], path: Path, peer_rows: list[dict] = ()) -> Figure:
    """One panel per scene: ms per update (x, log) against % pixels differing (y).

    ``peer_rows`` (from :func:`service.bench.peers.compare`) add each peer as a dashed
    grey reference line.
    """
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    scenes = sorted({r["scene"] for r in rows})
    fig, axes = plt.subplots(1, len(scenes), figsize=(5 * len(scenes), 4.2), squeeze=False)
    names = (*METHOD_NAMES, "runlength+frame", "runlength+pixel")
    markers = dict(zip(names, "o^sDvx", strict=True))
    for ax, scene in zip(axes[0], scenes, strict=True):
        for method in names:
            pts = [r for r in rows if r["scene"] == scene and r["method"] == method]
            if not pts:
                continue
            ax.plot(
                [r["ms"] for r in pts],
                [r["pct_differ"] for r in pts],
                marker=markers[method],
                label=method,
            )
            for r in pts:
                ax.annotate(
                    str(r["zones"]),
                    (r["ms"], r["pct_differ"]),
                    fontsize=7,
                    textcoords="offset points",
                    xytext=(3, 3),
                )
        if peer_rows:

            plot_peers(ax, list(peer_rows), scene)
        ax.set_xscale("log")
        ax.set_xlabel("ms per update (labels: zones)")
        ax.set_ylabel("% pixels unlike ray casting")
        ax.set_title(scene)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    return save_chart(fig, path, dpi=110)


def chart_sweep(rows: list[dict], key: str, path: Path, title: str) -> Figure:
    """Run-length error (no fallback) against ``key`` (viewing angle or zones).

    Two errors on a log scale: at the zone centres (the sort's mistakes) and for a
    viewer anywhere in the angle (plus the zones' coarseness).
    """
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4))
    for method in ("runlength", "zbuffer"):
        pts = sorted((r[key], r["pct_differ"]) for r in rows if r["method"] == method)
        ax.plot(
            [p[0] for p in pts], [p[1] for p in pts], marker="o", label=f"{method}, zone centres"
        )
    pts = sorted((r[key], r["pct_differ_continuous"]) for r in rows if r["method"] == "runlength")
    ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="s", label="runlength, any viewer")
    ax.set_yscale("symlog", linthresh=1e-3)
    ax.set_xlabel(key.replace("_", " "))
    ax.set_ylabel("% pixels unlike the exact view")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return save_chart(fig, path, dpi=110)


def build_parser() -> argparse.ArgumentParser:
    """The ``holo-bench render`` command line."""
    p = argparse.ArgumentParser(prog="holo-bench render", description=plain_help(__doc__),
                                epilog=exit_rule_epilog(),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", metavar="DIR", default="bench-out", help="output folder")
    p.add_argument("--quick", action="store_true", help="zones 1 and 5 only, fewer repeats")
    p.add_argument("--scenes", metavar="NAME,...", default=",".join(SCENE_NAMES),
                   help="comma-separated scene names")
    p.add_argument(
        "--zone-cost", action="store_true", help="only the cost of extra zones (a few seconds)"
    )
    p.add_argument("--peers", action="store_true",
                   help="also time Open3D, llvmpipe (culling off and on) and embreex beside "
                        "our z-buffer (extra .[peers])")
    p.add_argument("--peers-only", action="store_true", help="only the peers (implies --peers)")
    p.add_argument("--peer-scenes", metavar="NAME,...", type=comma_list(str), default=None,
                   help="extra scenes for the peers only, from "
                        f"{','.join(pr.BIG_SCENES)} or the built-in scenes (default: all of "
                        "those sphere scenes; --quick: spheres-8k)")
    p.add_argument("--peer-sizes", metavar="WxH,...", type=comma_list(size), default=None,
                   help="sizes of the extra peer scenes (default: 320x240,640x480; "
                        "--quick: --size)")
    add_size_option(p, (320, 240), "pixels per zone image")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the occlusion benchmark; return the exit status."""
    args = build_parser().parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    warm_up(RenderSettings())
    if args.peers_only:
        run_peers(args, out, [])
        return 0
    cost = zone_cost(size=args.size)
    write_rows(cost, out / "zone_cost")
    chart_zone_cost(cost, out / "zone_cost.png")
    print_zone_cost(cost)
    if args.zone_cost:
        return 0
    zones = (1, 5) if args.quick else ZONES
    reps = 3 if args.quick else 7
    for m in METHOD_NAMES:
        warm_up(RenderSettings(method=m))
    rows = _methods(args.scenes.split(","), zones, reps, args.size)
    write_rows(rows, out / "render_bench")
    peer_rows = run_peers(args, out, rows) if args.peers else []
    chart_methods(rows, out / "render_bench.png", peer_rows)
    _runlength_sweep(zones, reps, args.size, args.quick, out)
    print_summary(rows)
    return 0


def _methods(scenes: list[str], zones: tuple, reps: int, size: tuple[int, int]) -> list[dict]:
    """Every method on every scene and zone count, runlength also with each fallback."""
    rows = []
    total = len(scenes) * len(zones)
    for i, (scene, z) in enumerate(((s, z) for s in scenes for z in zones), 1):
        print(f"[{i}/{total}] {scene}, {zones_label(z)}", file=sys.stderr, flush=True)
        rows += measure(scene, z, 16.0, METHOD_NAMES, reps, fallback="off", size=size)
        for mode in ("frame", "pixel"):
            rows += [
                dict(r, method=f"runlength+{mode}")
                for r in measure(scene, z, 16.0, ["runlength"], reps, fallback=mode, size=size)
            ]
    return rows


def _runlength_sweep(zones: tuple, reps: int, size: tuple[int, int], quick: bool,
                     out: Path) -> None:
    """Runlength's error against the z-buffer over viewing angles and zone counts; charts."""
    sweep = []
    for a in ANGLES if not quick else (8, 16, 32, 60):
        sweep += measure("game", 5, float(a), ("runlength", "zbuffer"), reps, fallback="off",
                         size=size)
    for z in zones:
        sweep += measure("game", z, 32.0, ("runlength", "zbuffer"), reps, fallback="off",
                         size=size)
    for r in sweep:
        r["pct_differ_continuous"] = continuous_error("game", r["zones"], r["angle_deg"], size)
    write_rows(sweep, out / "runlength_sweep")
    chart_sweep(
        [r for r in sweep if r["zones"] == 5],
        "angle_deg",
        out / "runlength_angle.png",
        "game scene, 5 zones: error vs viewing angle",
    )
    chart_sweep(
        [r for r in sweep if r["angle_deg"] == 32.0],
        "zones",
        out / "runlength_zones.png",
        "game scene, 32 degrees: error vs zone count",
    )


def run_peers(args, out: Path, rows: list[dict]) -> list[dict]:
    """Time the peers beside our z-buffer; write ``peers.json``/``.csv`` and ``peers.png``.

    The bench's scenes and zone counts at ``--size`` (against the ray cast too, for the
    chart's reference lines), then the big peer scenes at 1 and 5 zones and the peer
    sizes.  A peer that cannot start is named with its reason, and the rest go on.
    """
    started, reasons = pr.start_peers()
    for name, why in reasons.items():
        print(f"peer {name} not measured: {why}", file=sys.stderr)
    (out / "peers_status.json").write_text(json.dumps(
        {"started": {p.name: p.renderer for p in started}, "not_started": reasons,
         "tolerance": pr.TOLERANCE}, indent=1))
    if not started:
        return []
    quick = args.quick
    zones = (1, 5) if quick else ZONES
    big = args.peer_scenes or (["spheres-8k"] if quick else list(pr.BIG_SCENES))
    sizes = args.peer_sizes or ([args.size] if quick else [(320, 240), (640, 480)])
    configs = [(s, z, args.size, True) for s in args.scenes.split(",") for z in zones]
    configs += [(s, z, wh, False) for s in big for z in (1, 5) for wh in sizes]
    peer_rows = []
    for i, (scene, z, wh, ref) in enumerate(configs, 1):
        print(f"[peers {i}/{len(configs)}] {scene}, {zones_label(z)}, {wh[0]}x{wh[1]}",
              file=sys.stderr, flush=True)
        peer_rows += pr.compare(scene, z, wh, started,
                                pr.PeerRun(reference=ref, methods=tuple(pr.OUR_METHODS)))
    for p in started:
        p.close()
    write_rows(peer_rows, out / "peers")
    write_rows(pr.fastest_peers(peer_rows), out / "peers_fastest")
    chart_peers(peer_rows, out / "peers.png")
    chart_peer_scaling(peer_rows, out / "peers_scaling.png")
    print_peers(peer_rows)
    return peer_rows


def chart_peer_scaling(rows: list[dict], path: Path) -> Figure:
    """Chart ms against triangles (log-log), one panel per zones x size: ours and every peer.

    Each of our methods timed (black, the z-buffer thick;
    :data:`~service.bench.peers.OUR_METHODS` caps the slow ones' scene size).  The ray
    casters' BVH build is drawn twice: amortised over
    :data:`~service.bench.peers.AMORTISE_FRAMES` frames (static scene, solid) and paid
    every frame (moving scene, dotted).
    """
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    panels = sorted({(r["zones"], r["size"]) for r in rows})
    fig, axes = plt.subplots(1, max(1, len(panels)), figsize=(4.2 * max(1, len(panels)), 4),
                             squeeze=False)
    for ax, (z, wh) in zip(axes[0], panels, strict=True):
        sub = sorted((r for r in rows if r["zones"] == z and r["size"] == wh),
                     key=lambda r: r["triangles"])
        ours = {r["triangles"]: r["ours_ms"] for r in sub}
        ax.plot(list(ours), list(ours.values()), "k-o", lw=2, label="ours: zbuffer")
        for m, style in zip([m for m in pr.OUR_METHODS if m != "zbuffer"], ("--", "-.", ":"),
                            strict=True):
            mine = {r["triangles"]: r[f"{m}_ms"] for r in sub if f"{m}_ms" in r}
            if mine:
                ax.plot(list(mine), list(mine.values()), style, color="k", marker="o", ms=3,
                        lw=1, label=f"ours: {m}")
        for name in sorted({r["peer"] for r in sub}):
            pts = [r for r in sub if r["peer"] == name]
            tri = [r["triangles"] for r in pts]
            (line,) = ax.plot(tri, [r["static_ms"] for r in pts], "-", marker=".", label=name)
            ax.plot(tri, [r["moving_ms"] for r in pts], ":", color=line.get_color())
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{zones_label(z)}, {wh}", fontsize=9)
        ax.set_xlabel("triangles")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("ms per frame (dotted: peer's build paid every frame)")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    return save_chart(fig, path, dpi=110)


def chart_peers(rows: list[dict], path: Path) -> Figure:
    """Bars: our ms / the peer's ms per configuration (below 1: we are faster)."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    labels = sorted({(r["scene"], r["zones"], r["size"]) for r in rows},
                    key=lambda k: (k[0], k[2], k[1]))
    names = sorted({r["peer"] for r in rows})
    fig, ax = plt.subplots(figsize=(max(6.0, 0.45 * len(labels) + 2), 4.2))
    x = np.arange(len(labels))
    width = 0.8 / max(1, len(names))
    for i, name in enumerate(names):
        by = {(r["scene"], r["zones"], r["size"]): r["ratio"] for r in rows if r["peer"] == name}
        ax.bar(x + i * width, [by.get(k, np.nan) for k in labels], width, label=name)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_xticks(x + width * (len(names) - 1) / 2,
                  [f"{s} {z}z {wh}" for s, z, wh in labels], rotation=60, ha="right",
                  fontsize=7)
    ax.set_ylabel("our ms / peer ms (below 1: ours faster)")
    ax.set_title("depth, stages 1-4 (our z-buffer) against each peer")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_chart(fig, path, dpi=110)


def print_peers(rows: list[dict]) -> None:
    """One line per configuration and peer: ms each side, ratio, depth agreement."""
    print("\npeers: our z-buffer (stages 1-4) against each peer, timed in turn")
    for r in rows:
        print(f"  {r['scene']:13s} {r['zones']:3d} zones {r['size']:>8s} {r['peer']:9s}"
              f" ours {r['ours_ms']:8.2f} ms  peer {r['peer_ms']:8.2f} ms"
              f"  ours/peer {r['ratio']:6.3f}  depth agrees {r['pct_agree']:8.4f} %"
              f"  build {r['build_ms']:8.2f} ms")
    print(f"\nfastest peer per scene (its build amortised over {pr.AMORTISE_FRAMES} frames;"
          " moving: paid every frame)")
    for r in pr.fastest_peers(rows):
        print(f"  {r['scene']:13s} {r['zones']:3d} zones {r['size']:>8s} {r['peer']:13s}"
              f" static {r['static_ms']:8.2f} ms  moving {r['moving_ms']:8.2f} ms"
              f"  ours {r['ours_ms']:8.2f} ms  ours/peer {r['ratio']:6.3f}")


def print_zone_cost(rows: list[dict]) -> None:
    """One line per zone count: wall ms, ratio to one zone, stage ms."""
    print(f"{rows[0]['scene']}: whole render (z-buffer, Blinn per polygon)")
    for r in rows:
        stages = " ".join(f"{k} {r[f'ms_{k}']:.2f}" for k in STAGES)
        print(f"  {r['zones']:3d} zones {r['ms']:7.2f} ms  x{r['ratio']:5.2f}   ({stages})")


def print_summary(rows: list[dict]) -> None:
    """Table of ms and error, with ms as ratios to one zone with the z-buffer."""
    for scene in sorted({r["scene"] for r in rows}):
        base = next(
            r["ms"]
            for r in rows
            if r["scene"] == scene and r["zones"] == 1 and r["method"] == "zbuffer"
        )
        print(f"\n{scene}: ms per update (ratio to 1-zone z-buffer = {base:.2f} ms), % differ")
        for r in (r for r in rows if r["scene"] == scene):
            print(
                f"  {r['method']:20s} {r['zones']:3d} zones {r['ms']:9.2f} ms"
                f"  x{r['ms'] / base:6.2f}  {r['pct_differ']:8.4f} %"
            )


if __name__ == "__main__":
    sys.exit(main())
