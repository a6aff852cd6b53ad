"""``make render-demo``: render the built-in demo scene in 5 view zones and report timings.

Writes zone-NN.png, depth-NN.npy, strip.png and a quilt to the output folder, then
prints per-stage milliseconds for every occlusion method and how many pixels each
differs from the ray-cast reference.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from service.base.cli_args import int_range, plain_help
from service.base.signals import EXIT_RULE, interruptible
from service.builtin_scenes import builtin_scene, scene_name
from service.display import DisplaySettings
from service.process import setup_frame_process
from service.render.frame import write_quilt, write_strip, write_zones
from service.render.light import LightSettings
from service.render.pipeline import METHOD_NAMES, Renderer, RenderSettings, warm_up

STAGES = ("flatten", "project", "cull", "sort", "occlusion", "light", "total")


def _median_frame(renderer: Renderer, scene, display, settings, repeats: int):
    frames = [renderer.render(scene, display, settings) for _ in range(repeats)]
    ms = {k: float(np.median([f.stats["ms"].get(k, 0.0) for f in frames])) for k in STAGES}
    return frames[-1], ms


def main(argv: list[str] | None = None) -> int:
    """Render the demo scene; return the exit status."""
    p = argparse.ArgumentParser(prog="python -m service.commands.render_demo",
                                description=plain_help(__doc__),
                                epilog=EXIT_RULE)
    p.add_argument(
        "--out", default="render-demo-out", help="output folder (default render-demo-out)"
    )
    p.add_argument("--scene", default="demo", type=scene_name,
                   help="built-in scene name (default demo)")
    p.add_argument("--repeats", type=int_range(1), default=5, metavar="N",
                   help="renders per method for the median (default 5)")
    args = p.parse_args(argv)
    return interruptible("render-demo", lambda: _run(args))


def _run(args: argparse.Namespace) -> int:
    """Render, time and write as ``args`` say; return the exit status."""
    setup_frame_process()  # heap reuse and one BLAS thread (service.process)
    display = DisplaySettings(zones=5, angle_deg=16.0, cols=320, rows=240)
    scene = builtin_scene(args.scene)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(
        f"scene {args.scene!r}: {sum(o.mesh.n_polygons for o in scene.objects)} polygons in "
        f"{len(scene.objects)} objects; {display.zones} zones across {display.angle_deg} degrees, "
        f"{display.cols}x{display.rows} each"
    )
    reference = None
    rows = []
    for method in ("raycast", *[m for m in METHOD_NAMES if m != "raycast"]):
        settings = RenderSettings(method=method, light=LightSettings("blinn", "polygon"))
        warm_up(settings)
        frame, ms = _median_frame(
            Renderer(), scene, display, settings, 1 if method == "raycast" else args.repeats
        )
        if reference is None:
            reference = frame
        diff = 100.0 * np.mean(np.any(frame.colour != reference.colour, axis=-1))
        rows.append((method, ms, diff, frame))
    print(f"{'method':10s}" + "".join(f"{s:>10s}" for s in STAGES) + f"{'% differ':>10s}")
    for method, ms, diff, _ in rows:
        print(f"{method:10s}" + "".join(f"{ms[s]:10.2f}" for s in STAGES) + f"{diff:10.3f}")
    print("(milliseconds per update, median; '% differ' = pixels unlike the ray-cast reference)")
    frame = next(f for m, _, _, f in rows if m == "runlength")
    write_zones(frame, out)
    write_strip(frame, out / "strip.png")
    quilt = write_quilt(frame, out)
    c = frame.stats["polygons"]
    print(f"run-length frame: {c['in']} polygons, {c['culled']} culled, {c['kept']} kept, "
          f"{c['drawn']} seen in a zone")
    print(f"wrote {display.zones} zone images, depth maps, {out / 'strip.png'} and {quilt}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
