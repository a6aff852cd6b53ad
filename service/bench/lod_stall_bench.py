"""Render stalls while a level-of-detail chain builds (``holo-bench lod-stall``).

A renderer draws a small scene (three tori, the service test's 5 x 160 x 120 by
default) frame after frame while the bunny's chain is built beside it, no cache:

* ``thread``: :func:`service.lod.cache.build_chain` in a thread of this process at nice +5
  (how a build without a cache folder ran until the builds moved to a child; quadric
  decimation holds the GIL for 20-40 ms a call, so a frame waits for it);
* ``child``: :class:`service.lod.builds.ChainBuilds` (the build in a child process,
  the chain handed back through a temporary folder), as the service and the game do;
* ``idle``: no build, the frames alone.

The modes are interleaved (``--repeats`` rounds, the order alternating), in one run.
Per build: frames drawn, build seconds, frame ms p50 / p95 / max and frames over 20
and 40 ms.  Writes ``lod_stall.csv``, ``lod_stall.json`` and ``lod_stall.png`` (the
share of frames slower than x ms, per mode, log y).  Wall time on a shared machine
also measures the other processes: compare the modes of one run, not runs.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np

from service.base.cli_args import add_size_option, exit_rule_epilog, int_range
from service.bench.charts import save_chart
from service.bench.rows import write_csv
from service.display import DisplaySettings
from service.loaders import load_mesh
from service.lod.builds import ChainBuilds
from service.lod.cache import build_chain
from service.lod.chain import mesh_key
from service.lod.settings import BUILD_NICE, LodError, LodSettings
from service.primitives import torus
from service.render.mesh import Mesh
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import Scene, SceneObject, Transform

BUNNY = Path(__file__).resolve().parents[2] / ".." / "shared" / "fixtures" / "meshes" / "bunny.ply"
#: Frames of an ``idle`` round.
IDLE_FRAMES = 200
MODES = ("idle", "thread", "child")


def build_parser() -> argparse.ArgumentParser:
    """The options of ``holo-bench lod-stall``."""
    p = argparse.ArgumentParser(
        prog="holo-bench lod-stall",
        description="Frame times while a level-of-detail chain builds beside the renders: "
        "in a thread of the rendering process, in a child process, and with no build. "
        "Writes lod_stall.csv, lod_stall.json and lod_stall.png.",
        epilog=exit_rule_epilog(),
    )
    p.add_argument("--out", metavar="DIR", default="bench-out",
                   help="output folder (default bench-out)")
    p.add_argument("--mesh", metavar="FILE", default=str(BUNNY),
                   help="the mesh whose chain is built (default the bunny fixture)")
    add_size_option(p, (160, 120), "pixels per zone image")
    p.add_argument("--zones", metavar="N", type=int_range(1, 64), default=5,
                   help="view zones (default 5)")
    p.add_argument("--repeats", metavar="N", type=int_range(1, 50), default=3,
                   help="builds per mode (default 3)")
    return p


def _thread_build(mesh: Mesh, settings: LodSettings) -> None:
    """Build in this process, at a lower priority (Linux: per thread), as it used to."""
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, min(os.getpriority(os.PRIO_PROCESS, tid)
                                                 + BUILD_NICE, 19))
    except (AttributeError, OSError):
        pass
    build_chain(mesh, settings, cache=False)


def one_round(mode: str, mesh: Mesh, draw) -> dict:
    """Frame milliseconds of one mode: while one build runs, or ``IDLE_FRAMES`` frames."""
    settings, ms = LodSettings(), []
    t0 = time.perf_counter()
    if mode == "idle":
        ms = [draw() for _ in range(IDLE_FRAMES)]
    elif mode == "thread":
        th = threading.Thread(target=_thread_build, args=(mesh, settings), daemon=True)
        th.start()
        ms.append(draw())  # at least one frame, however quick the build
        while th.is_alive():
            ms.append(draw())
    else:
        builds = ChainBuilds(False)
        builds.submit(mesh_key(mesh, settings.recipe), mesh, settings)
        ms.append(draw())
        while not builds.wait_idle(0):
            ms.append(draw())
        if builds.failed:
            raise LodError(f"the build failed: {builds.notes[-1]}")
    a = np.asarray(ms)
    return {"mode": mode, "frames": a.size, "build_s": round(time.perf_counter() - t0, 2),
            "p50_ms": round(float(np.median(a)), 2),
            "p95_ms": round(float(np.percentile(a, 95)), 2),
            "max_ms": round(float(a.max()), 2), "over_20ms": int((a > 20).sum()),
            "over_40ms": int((a > 40).sum()), "_ms": a}


def chart(rows: list[dict], out: Path) -> None:
    """``lod_stall.png``: share of frames slower than x ms, per mode (all rounds)."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for mode in MODES:
        a = np.sort(np.concatenate([r["_ms"] for r in rows if r["mode"] == mode]))
        share = 1.0 - np.arange(a.size) / a.size
        ax.step(a, share, where="post", label=f"{mode} ({a.size} frames)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("frame ms")
    ax.set_ylabel("share of frames slower")
    ax.set_title("Frames while an LOD chain builds: in a thread, in a child, none")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    save_chart(fig, out / "lod_stall.png", dpi=110)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; write CSV, JSON and the chart."""
    args = build_parser().parse_args(argv)
    cols, rows_px = args.size
    display = DisplaySettings(zones=args.zones, cols=cols, rows=rows_px)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    mesh = load_mesh(Path(args.mesh))
    ring = torus(0.5, 0.15, 48, 24)
    scene = Scene([SceneObject(ring, transform=Transform(np.array([x, 0.0, -2.0]), scale=0.4),
                               name=f"ring{i}") for i, x in enumerate((-0.5, 0.0, 0.5))])
    renderer, settings = Renderer(), RenderSettings()

    def draw() -> float:
        t0 = time.perf_counter()
        renderer.render(scene, display, settings)
        return (time.perf_counter() - t0) * 1e3

    for _ in range(5):  # first calls, first touch of the buffers
        draw()
    _thread_build(mesh, LodSettings(fractions=(0.5,)))  # the build's kernels, loaded once
    rows = []
    for rep in range(args.repeats):
        for mode in MODES if rep % 2 else (MODES[0], *MODES[:0:-1]):
            rows.append({"round": rep, **one_round(mode, mesh, draw)})
            shown = {k: v for k, v in rows[-1].items() if not k.startswith("_")}
            print(" ".join(f"{k} {v}" for k, v in shown.items()), file=sys.stderr)
    table = [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]
    write_csv(table, out / "lod_stall.csv")
    (out / "lod_stall.json").write_text(json.dumps(
        {"display": [args.zones, cols, rows_px], "mesh": args.mesh, "rows": table}, indent=1))
    chart(rows, out)
    print(f"wrote {out / 'lod_stall.csv'}, lod_stall.json, lod_stall.png", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
