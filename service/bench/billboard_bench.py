"""Billboard-cloud benchmark (``holo-bench billboard``): planes, build time, errors.

Where the error grows: close up and at grazing angles.

Part 1, build: the mesh (the bunny fixture by default) at each ``--eps`` (percent of
its bounding-box diagonal): billboards, texels, build wall and CPU seconds.

Part 2, viewing distance: the cloud at ``--view-eps`` against the full mesh, both
fitted to 1.6 world units like ``holo-render`` fits a lone mesh and then magnified by
each ``--zoom`` factor.  The zones are parallel projections, so coming closer means
more pixels per world unit (a bigger picture): the same world-space EPS covers more
pixels.  Per zoom: ``depth_diff_pct`` (% of covered pixels whose depth differs by
more than 2 EPS, coverage changes included), ``measured_px`` (how far a pixel covered
by one render lies from the other's cover, city-block pixels: the silhouette error
on screen), ``eps_px`` (EPS in pixels) and colour PSNR.

Part 3, grazing: the same cloud in ``--yaws`` orientations; every pixel where a
billboard and the mesh both show, binned by the angle between the zone's ray and the
billboard's normal: median and 95th percentile of ``|depth difference| / EPS`` and the
share beyond 2 EPS.  The depth of a point off its plane by ``d`` is off by
``d / cos(angle)`` along the ray, so errors grow toward 90 degrees.

Part 4, cost (:mod:`service.bench.billboard_cost`): CPU ms per frame of the full mesh,
its cloud and the quadric level LOD picks, at several on-screen sizes, for the
``holo-bench lod`` meshes (``--cost-meshes``; ``none`` skips it).

Part 5, crowd (:mod:`service.bench.billboard_crowd`): where seed 004 uses clouds,
many small objects far away: ``--crowd`` copies of ``--crowd-mesh`` at each
``--crowd-sizes``, as full meshes, as each quadric level of their chain and as clouds
(``--crowd-eps`` x ``--crowd-texture``): CPU ms and the % of all pixels differing from
the full meshes in colour (any channel > 32 levels) or coverage, each cloud against
the quadric level of the same error (``--crowd 0`` skips it).

Writes ``billboard_build.csv``, ``billboard_zoom.csv``, ``billboard_grazing.csv``,
``billboard_cost.csv``, ``billboard_crowd.csv``, ``billboard_bench.json``,
``billboard_bench.png`` (four panels) and ``billboard_crowd.png`` (one panel per
crowd size).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from service.base.cli_args import (
    add_size_option,
    comma_list,
    exit_rule_epilog,
    float_range,
    int_range,
)
from service.base.errors import HoloError
from service.bench import billboard_cost, billboard_crowd
from service.bench.charts import save_chart
from service.bench.lod_bench import BUNNY, LIGHTS, MATERIAL, image_error
from service.bench.rows import write_csv
from service.billboard_render import BillboardObject, draw_billboards
from service.display import DisplaySettings
from service.loaders import fit_transform, load_mesh
from service.render.light import LightSettings
from service.render.occlusion import Visibility
from service.render.pipeline import Renderer, RenderSettings, warm_up
from service.render.scene import Scene, SceneObject, Transform, euler_quaternion, quaternion_matrix
from service.simplify.billboard import build_cloud

SETTINGS = RenderSettings(method="zbuffer", light=LightSettings("blinn", "polygon"))
ANGLE_BINS = np.arange(0, 91, 10)


def build_rows(v: np.ndarray, f: np.ndarray, diag: float, args: argparse.Namespace) -> list:
    """Part 1: one row per EPS."""
    rows = []
    for pct in args.eps:
        c0 = time.process_time()
        cloud = build_cloud(v, f, pct / 100 * diag, args.texture_res)
        rows.append({"eps_pct": pct, "billboards": cloud.n_billboards,
                     "texels": int(cloud.rgba.shape[0]), "build_s": cloud.build_s,
                     "build_cpu_s": time.process_time() - c0})
        print(f"EPS {pct} %: {cloud.n_billboards} billboards, build {cloud.build_s:.2f} s "
              f"(CPU {rows[-1]['build_cpu_s']:.2f} s)", file=sys.stderr)
    return rows


def _placed(fit: Transform, zoom: float, yaw: float = 0.0) -> Transform:
    return Transform(position=fit.position * zoom, scale=fit.scale * zoom,
                     orientation=euler_quaternion(np.radians(yaw), 0.0, 0.0))


def _pair(mesh, cloud, t: Transform, display: DisplaySettings):
    r = Renderer()
    full = r.render(Scene([SceneObject(mesh, MATERIAL, t)], LIGHTS), display, SETTINGS)
    bb = r.render(Scene([], LIGHTS, billboards=[BillboardObject(cloud, MATERIAL, t)]),
                  display, SETTINGS)
    return full, bb


def zoom_rows(mesh, cloud, fit: Transform, display: DisplaySettings, args) -> list:
    """Part 2: one row per zoom factor."""
    rows = []
    for zoom in args.zoom:
        t = _placed(fit, zoom)
        eps_w = cloud.eps * t.scale
        err = image_error(*_pair(mesh, cloud, t, display), 2 * eps_w)
        rows.append({"zoom": zoom, "eps_world": eps_w, "eps_px": eps_w / display.pixel_size,
                     **err})
    return rows


def grazing_rows(mesh, cloud, fit: Transform, display: DisplaySettings, args) -> list:
    """Part 3: depth error against the angle between ray and billboard normal."""
    err_all, ang_all = [], []
    for yaw in args.yaws:
        t = _placed(fit, 1.0, yaw)
        full, _ = _pair(mesh, cloud, t, display)
        vis = Visibility.empty(display.zones, display.rows, display.cols)
        bp = draw_billboards([BillboardObject(cloud, MATERIAL, t)], display, vis, "zbuffer",
                             LIGHTS, 1.0, SETTINGS.light)
        both = (bp.quad > 0) & np.isfinite(full.depth)
        rot = _rotation(t)
        normals = cloud.planes[:, :3] @ rot.T
        rays = np.stack([display.shears(), np.zeros(display.zones), -np.ones(display.zones)], 1)
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        z_idx = np.nonzero(both)[0]
        q_idx = bp.quad[both] - 1
        cosang = np.abs(np.einsum("nd,nd->n", normals[q_idx], rays[z_idx]))
        ang_all.append(np.degrees(np.arccos(np.clip(cosang, 0, 1))))
        err_all.append(np.abs(vis.depth[both] - full.depth[both]) / (cloud.eps * t.scale))
    ang, err = np.concatenate(ang_all), np.concatenate(err_all)
    rows = []
    for lo, hi in zip(ANGLE_BINS[:-1], ANGLE_BINS[1:], strict=True):
        sel = err[(ang >= lo) & (ang < hi)]
        if sel.size:
            rows.append({"angle_lo": int(lo), "angle_hi": int(hi), "pixels": int(sel.size),
                         "median_err_eps": float(np.median(sel)),
                         "p95_err_eps": float(np.percentile(sel, 95)),
                         "beyond_2eps_pct": 100.0 * float((sel > 2).mean())})
    return rows


def _rotation(t: Transform) -> np.ndarray:

    return quaternion_matrix(t.orientation)


def charts(build: list, zoom: list, grazing: list, cost: list, out: Path) -> None:
    """Four panels: build, error vs zoom, error vs grazing angle, cost vs size."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 4, figsize=(20, 4.2))
    e = [r["eps_pct"] for r in build]
    ax[0].plot(e, [r["billboards"] for r in build], "o-", label="billboards")
    ax[0].axhline(50, ls=":", c="grey", label="target at 1 %: 50")
    ax[0].set(xlabel="EPS, % of bounding-box diagonal", ylabel="billboards",
              title="Build: billboards (left axis), CPU s (right)", xscale="log")
    tw = ax[0].twinx()
    tw.plot(e, [r["build_cpu_s"] for r in build], "s--", c="C1", label="build CPU s")
    tw.set_ylabel("build CPU s")
    ax[0].legend(loc="upper center")
    z = [r["zoom"] for r in zoom]
    ax[1].plot(z, [r["measured_px"] for r in zoom], "o-", label="silhouette error, px")
    ax[1].plot(z, [r["eps_px"] for r in zoom], ":", label="EPS in px")
    ax[1].plot(z, [r["depth_diff_pct"] for r in zoom], "s-", label="% pixels depth > 2 EPS")
    ax[1].set(xlabel="zoom (closer: more pixels per world unit)", xscale="log",
              title="Close up: the same EPS covers more pixels")
    ax[1].legend()
    a = [(r["angle_lo"] + r["angle_hi"]) / 2 for r in grazing]
    ax[2].plot(a, [r["median_err_eps"] for r in grazing], "o-", label="median |depth err| / EPS")
    ax[2].plot(a, [r["p95_err_eps"] for r in grazing], "s-", label="95th pct / EPS")
    ax[2].plot(a, [1 / max(np.cos(np.radians(x)), 1e-3) for x in a], ":", label="1 / cos")
    ax[2].set(xlabel="angle between ray and billboard normal, degrees", yscale="log",
              title="Grazing: depth error grows as 1 / cos")
    ax[2].legend()
    if cost:
        billboard_cost.chart(ax[3], cost)
    fig.tight_layout()
    save_chart(fig, out / "billboard_bench.png", dpi=110)


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``holo-bench billboard``."""
    p = argparse.ArgumentParser(prog="holo-bench billboard",
                                description="Billboard clouds: planes and build time vs "
                                "EPS; image error close up and at grazing angles.",
                                epilog=exit_rule_epilog())
    p.add_argument("--mesh", metavar="FILE", default=str(BUNNY),
                   help="mesh file (default: the bunny fixture)")
    p.add_argument("--eps", metavar="EPS,...", type=comma_list(float_range(0, 100, lo_open=True)),
                   default="0.5,1,2,4", help="EPS list, %% of the diagonal (0.5,1,2,4)")
    p.add_argument("--view-eps", metavar="EPS", type=float_range(0, 100, lo_open=True), default=1.0,
                   help="EPS of the cloud viewed in parts 2 and 3, %% (default 1)")
    p.add_argument("--zoom", metavar="X,...", type=comma_list(float_range(0, 64, lo_open=True)),
                   default="0.5,1,2,4", help="magnifications of part 2 (0.5,1,2,4)")
    p.add_argument("--yaws", metavar="DEG,...", type=comma_list(float_range(-360, 360)),
                   default="0,60,120",
                   help="orientations of part 3, degrees about y (0,60,120)")
    p.add_argument("--texture-res", metavar="N", type=int_range(1, 16384), default=512,
                   help="texels across the diagonal (default 512)")
    p.add_argument("--zones", metavar="N", type=int_range(1, 64), default=5,
                   help="view zones (default 5)")
    add_size_option(p, (320, 240), "pixels per zone image")
    p.add_argument("--cost-meshes", metavar="MESH,...", default="bunny,torus,spiky",
                   help="part 4's meshes (holo-bench lod's names, or none; bunny,torus,spiky)")
    p.add_argument("--cost-sizes", metavar="PX,...", type=comma_list(float_range(1, 8192)),
                   default="10,20,40,80,240",
                   help="part 4's on-screen sizes, px (10,20,40,80,240)")
    p.add_argument("--lod-error", metavar="PX", type=float_range(0, None, lo_open=True),
                   default=0.5,
                   help="part 4's LOD budget, px (0.5)")
    p.add_argument("--repeats", metavar="N", type=int_range(1, 100), default=7,
                   help="parts 4 and 5: renders per case (7; part 4 takes the best, "
                   "part 5 the median)")
    p.add_argument("--crowd", metavar="N", type=int_range(0, 10000), default=200,
                   help="part 5: objects in the crowd (200; 0 skips part 5)")
    p.add_argument("--crowd-mesh", metavar="MESH", default="bunny",
                   help="part 5's mesh: a holo-bench lod name or a mesh file (bunny)")
    p.add_argument("--crowd-sizes", metavar="PX,...", type=comma_list(float_range(1, 8192)),
                   default="5,10,20,40", help="part 5's on-screen sizes, px (5,10,20,40)")
    p.add_argument("--crowd-eps", metavar="EPS,...",
                   type=comma_list(float_range(0, 100, lo_open=True)), default="1,2",
                   help="part 5's cloud EPS list, %% of the diagonal (1,2)")
    p.add_argument("--crowd-texture", metavar="N,...", type=comma_list(int_range(1, 16384)),
                   default="256,64", help="part 5's cloud texture resolutions (256,64)")
    p.add_argument("--out", metavar="DIR", default="bench-out/billboard", help="output folder")
    return p


def _step(what: str) -> None:
    """One progress line on stderr (the rows go to stdout at the end)."""
    print(f"holo-bench billboard: {what}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; write CSV, JSON and the chart."""
    args = build_parser().parse_args(argv)
    names = [] if args.cost_meshes == "none" else args.cost_meshes.split(",")
    unknown = [n for n in names if n not in billboard_cost.MESHES]
    crowd_mesh = _crowd_mesh(args) if args.crowd else None
    if unknown:
        build_parser().error(f"--cost-meshes: unknown {unknown}; one of "
                             f"{sorted(billboard_cost.MESHES)} or none")
    cols, rows = args.size
    display = DisplaySettings(zones=args.zones, cols=cols, rows=rows)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    mesh = load_mesh(args.mesh)
    v, f = mesh.vertices, mesh.triangles
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    _step("warm-up (numba kernels; minutes on an empty cache)")
    warm_up(SETTINGS)
    _step(f"building clouds of {args.mesh}")
    build = build_rows(v, f, diag, args)
    cloud = build_cloud(v, f, args.view_eps / 100 * diag, args.texture_res)
    fit = fit_transform(mesh)
    _step("zoom and grazing-angle errors")
    zoom = zoom_rows(mesh, cloud, fit, display, args)
    grazing = grazing_rows(mesh, cloud, fit, display, args)
    _step(f"frame cost, meshes {names or 'none'}")
    cost = billboard_cost.cost_rows(display, names, args.cost_sizes, args.lod_error, args.repeats)
    crowd = crowd_part(crowd_mesh, display, args)
    for name, data in (("build", build), ("zoom", zoom), ("grazing", grazing), ("cost", cost),
                       ("crowd", crowd)):
        write_csv(data, out / f"billboard_{name}.csv")
    (out / "billboard_bench.json").write_text(json.dumps(
        {"mesh": args.mesh, "display": [args.zones, cols, rows], "view_eps_pct": args.view_eps,
         "build": build, "zoom": zoom, "grazing": grazing, "cost": cost, "crowd": crowd},
        indent=1))
    charts(build, zoom, grazing, cost, out)
    crowd_charts(crowd, out)
    for r in zoom:
        print(f"zoom {r['zoom']:4g}: EPS {r['eps_px']:.1f} px, silhouette "
              f"{r['measured_px']:.0f} px, {r['depth_diff_pct']:.1f} % pixels beyond 2 EPS, "
              f"PSNR {r['psnr_db']:.1f} dB")
    for r in grazing:
        print(f"{r['angle_lo']:2d}-{r['angle_hi']:2d} deg: median {r['median_err_eps']:.2f} EPS, "
              f"95th {r['p95_err_eps']:.2f} EPS, {r['beyond_2eps_pct']:.1f} % beyond 2 EPS")
    for r in cost:
        print(f"{r['mesh']} at {r['size_px']:g} px: full {r['full_ms']:.2f} ms, cloud "
              f"{r['cloud_ms']:.2f} ms ({r['cloud_predicted_px']:.2f} px), LOD's "
              f"{r['lod_mesh_triangles']}-triangle level {r['lod_mesh_ms']:.2f} ms "
              f"({r['lod_mesh_predicted_px']:.2f} px); LOD with clouds picks the "
              f"{'cloud' if r['lod_picks_cloud'] else 'mesh'}")
    for r in crowd:
        if r["kind"] == "cloud":
            print(f"crowd of {r['objects']} at {r['size_px']:g} px: cloud EPS {r['eps_pct']:g} %, "
                  f"texture {r['texture_res']}: {r['cpu_ms']:.1f} ms, {r['differs_pct']:.2f} % "
                  f"pixels differ ({r['colour_pct']:.2f} % colour); quadric level "
                  f"{r['matched_level']} of no more error {r['matched_ms']:.1f} ms: the cloud "
                  f"costs {r['cloud_vs_mesh']:.2f}x ({r['above_empty_vs_mesh']:.2f}x above an "
                  f"empty frame's {r['empty_ms']:.1f} ms)")
    return 0


def _crowd_mesh(args: argparse.Namespace):  # noqa: ANN202 (a Mesh)
    """Part 5's mesh: a ``holo-bench lod`` name or a mesh file (a clear error otherwise)."""
    name = args.crowd_mesh
    try:
        return billboard_cost.MESHES[name]() if name in billboard_cost.MESHES else load_mesh(name)
    except HoloError as exc:
        build_parser().error(f"--crowd-mesh: not one of {sorted(billboard_cost.MESHES)} "
                             f"nor a mesh file it can read: {exc}")


def crowd_part(mesh, display: DisplaySettings,  # noqa: ANN001 (a Mesh or None)
               args: argparse.Namespace) -> list[dict]:
    """Part 5 (:mod:`service.bench.billboard_crowd`), or nothing with ``--crowd 0``."""
    if mesh is None:
        return []
    _step(f"crowd of {args.crowd} x {args.crowd_mesh}: clouds against quadric levels")
    return billboard_crowd.crowd_rows(mesh, Path(args.crowd_mesh).stem, display, args.crowd,
                                      args.crowd_sizes, args.crowd_eps, args.crowd_texture,
                                      args.repeats)


def crowd_charts(crowd: list[dict], out: Path) -> None:
    """``billboard_crowd.png``: part 5, one panel per size (nothing without rows)."""
    if not crowd:
        return
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    n = len({r["size_px"] for r in crowd})
    fig = plt.figure(figsize=(5.5 * n, 4.5))
    billboard_crowd.chart(fig, crowd)
    fig.tight_layout()
    save_chart(fig, out / "billboard_crowd.png", dpi=110)


if __name__ == "__main__":
    sys.exit(main())
