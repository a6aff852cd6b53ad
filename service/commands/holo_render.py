"""``holo-render``: render a scene into every view zone and write the images.

Examples
--------
holo-render model.ply --zones 5 --angle 16 --out out/
holo-render builtin:game --method runlength --json

``--json`` prints one object: the settings, the polygon counts, per-stage
milliseconds and the occlusion counters (:func:`occlusion_counters`).  Exit status:
0, 2 for bad options or a bad scene file, 130 / 143 on Ctrl-C / SIGTERM (the rule of
:mod:`service.base.signals`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from service.base.cli_args import (
    add_size_option,
    float_range,
    int_range,
    os_error_text,
    output_problem,
    plain_help,
)
from service.base.errors import HoloError, SettingsError
from service.base.signals import EXIT_RULE, interruptible
from service.builtin_scenes import SCENES, builtin_scene
from service.display import DisplaySettings
from service.loaders import MESH_LOADERS, SCENE_EXTENSIONS, load_scene
from service.lod.cost import CostModel
from service.lod.options import (
    add_lod_options,
    budget_frames,
    build_chains,
    lod_settings,
    lod_state,
)
from service.lookingglass import DEFAULT_VIEWS, Calibration, Interleaver, parse_display
from service.mesh_repair import MeshRepair, MeshRepairWarning
from service.png import write_png
from service.process import setup_frame_process
from service.quality import (
    MODES,
    QualityChooser,
    QualitySettings,
    parse_budget,
    render_auto,
)
from service.render.cull import CULLS, CullSettings
from service.render.frame import Frame, write_quilt, write_strip, write_zones
from service.render.light import EVALUATIONS, MODELS, LightSettings
from service.render.pipeline import METHOD_NAMES, Renderer, RenderSettings, warm_up
from service.render.scene import Scene


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``holo-render``."""
    p = argparse.ArgumentParser(
        prog="holo-render",
        description="Render a scene into N view zones of a multi-view display "
        "(thesis occlusion, cull and specular light) and write zone-NN.png, "
        "depth-NN.npy and strip.png.",
        epilog=f"SCENE is a .hobj (thesis object), .ply, .obj or .toml scene file, "
        f"or builtin:NAME with NAME one of {', '.join(SCENES)} (an underscore may stand for "
        f"a hyphen). {plain_help(EXIT_RULE)}",
    )
    p.add_argument("scene", metavar="SCENE", help="scene or mesh file, or builtin:NAME")
    _add_display_args(p)
    _add_method_args(p)
    p.add_argument(
        "--strict", action="store_true",
        help="refuse mesh files that would otherwise be repaired on load (non-planar or "
        "concave polygons, faces of under 3 corners, extra values on ascii PLY lines)",
    )
    add_lod_options(p)
    _add_quality_args(p)
    p.add_argument("--quilt", action="store_true", help="also write a Looking Glass quilt")
    p.add_argument(
        "--display", metavar="lookingglass:CALIBRATION.json", default=None,
        help="render for a Looking Glass: its calibration (the device's visual.json) sets "
        "the viewing angle (viewCone) and the panel; writes the quilt and the interleaved "
        "panel image lookingglass-WxH.png (--zones sets the view count, default 45)",
    )
    p.add_argument("--out", metavar="DIR", default="render-out",
                   help="output folder (default render-out)")
    p.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object with settings, counts and timings",
    )
    return p


def _add_display_args(p: argparse.ArgumentParser) -> None:
    """The display: view zones, viewing angle, zone image size."""
    p.add_argument("--zones", type=int_range(1, 64), default=None, metavar="N",
                   help="view zones, 1-64 (default 5; 45 with --display lookingglass:...)")
    p.add_argument(
        "--angle", type=float_range(0, 60), default=None, metavar="DEG",
        help="viewing angle in degrees, 0-60 (default 16; the calibration's viewCone with "
        "--display)",
    )
    add_size_option(p, (320, 240), "pixels per zone image")


def _add_method_args(p: argparse.ArgumentParser) -> None:
    """How the picture is made: occlusion method, light, cull, run-length fallback."""
    p.add_argument("--method", choices=METHOD_NAMES, default="zbuffer", help="occlusion method")
    p.add_argument("--light", choices=tuple(MODELS), default="blinn", help="light model")
    p.add_argument(
        "--specular",
        choices=tuple(EVALUATIONS),
        default="polygon",
        help="where light is evaluated: per polygon (thesis), vertex or point",
    )
    p.add_argument("--cull", choices=sorted(CULLS), default="modified", help="back-face cull")
    fallback = p.add_mutually_exclusive_group()
    fallback.add_argument(
        "--fallback",
        choices=("frame", "pixel", "off"),
        default=None,  # None, not "pixel": argparse lets a value equal to the default
        # slip past the mutually exclusive check (--fallback pixel --no-fallback)
        help="when the run-length depth order proves wrong: z-test just the wrong points "
        "(pixel, default: the z-buffer's picture), redraw the frame with the z-buffer "
        "(frame), or keep it (off)",
    )
    fallback.add_argument(
        "--no-fallback",
        action="store_true",
        help="keep a run-length frame even when its depth order proved wrong (--fallback off)",
    )


def _add_quality_args(p: argparse.ArgumentParser) -> None:
    """``--quality auto`` and its error budget and cost model."""
    p.add_argument(
        "--quality", choices=MODES, default=None,
        help="auto: pick the cheapest occlusion method and specular evaluation within "
        "--max-error (overrides --method, --specular and --fallback); default fixed, or "
        "the scene file's [quality] mode",
    )
    p.add_argument(
        "--max-error", type=_budget, default=None, metavar="BUDGET",
        help="error budget of --quality auto (giving it turns auto on): %% of pixels wrong "
        "(0.5 or 0.5%%) or a least PSNR (40dB); default 0.5%%, or the scene file's "
        "[quality] max_error",
    )
    p.add_argument(
        "--cost-model", default=None, metavar="PATH",
        help="cost model JSON of --quality auto (holo-bench quality --calibrate writes one; "
        "default: the one measured on the development machine)",
    )


def scene_problem(spec: str, first: tuple[str, ...] = ()) -> str | None:
    """Why ``spec`` names no scene this command reads (by its extension), or None.

    The loaders' own message names the mesh extensions only ("unknown mesh file
    extension '.png' (.hobj, .obj, .ply)"), not scene files nor ``builtin:``.
    ``first`` adds extensions the command reads besides scenes (holo-sird's ``.npy``).
    """
    if spec.startswith("builtin:"):
        return None
    known = (*first, *SCENE_EXTENSIONS, ".hbc", *sorted(MESH_LOADERS))
    if Path(spec).suffix.lower() in known:
        return None
    return (f"{spec}: not a file this reads: want {', '.join(known)} or builtin:NAME "
            f"({', '.join(SCENES)})")


def _billboard_words(report: dict) -> str:
    """``, 50 billboards`` when the frame drew billboard quads (a cloud has no polygons)."""
    quads = (report.get("billboards") or {}).get("quads", 0)
    return f", {quads} billboards" if quads else ""


def _load(spec: str, strict: bool = False,
          display: DisplaySettings | None = None) -> tuple[Scene, list[str]]:
    """The scene (a lone mesh fitted to ``display``), and its files' repair warnings."""
    if spec.startswith("builtin:"):
        return builtin_scene(spec.split(":", 1)[1]), []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", MeshRepairWarning)
        scene = load_scene(Path(spec), strict, display)
    for w in caught:
        if not issubclass(w.category, MeshRepairWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return scene, [str(w.message) for w in caught if issubclass(w.category, MeshRepairWarning)]


def mesh_report(scene: Scene, load_ms: float, strict: bool) -> dict:
    """The ``mesh`` block of ``--json``: what loading repaired, summed over the objects.

    Returns
    -------
    dict
        ``strict``, ``load_ms``, ``polygons`` and ``triangles`` (as rendered), then the
        counts of :class:`~service.mesh_repair.MeshRepair` (``faces_read``,
        ``non_planar``, ``concave``, ``triangles_added``, ``degenerate``,
        ``zero_area_triangles``, ``trailing_values``; faces read only counts meshes
        read from files).
    """
    total = MeshRepair()
    for obj in scene.objects:
        if obj.mesh.repair is not None:
            total.add(obj.mesh.repair)
    return {
        "strict": strict, "load_ms": round(load_ms, 3),
        "polygons": sum(o.mesh.n_polygons for o in scene.objects),
        "triangles": sum(int(o.mesh.triangles.shape[0]) for o in scene.objects),
        **total.as_dict(),
    }


def build_report(flatten_ms: float, scene: Scene) -> dict:
    """The one-off mesh build: ``flatten_ms`` and microseconds per triangle.

    The first render of a freshly loaded scene builds each mesh's triangles, polygon
    normals and closedness and the scene's polygon list (``Scene.flatten``); later
    frames only transform.
    """
    tris = sum(int(o.mesh.triangles.shape[0]) for o in scene.objects)
    return {"flatten_ms": round(flatten_ms, 3),
            "flatten_us_per_triangle": round(1e3 * flatten_ms / max(tris, 1), 4)}


def _budget(text: str):
    """The argparse type of ``--max-error``."""
    try:
        return parse_budget(text)
    except HoloError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _quality(args: argparse.Namespace, scene: Scene) -> QualitySettings:
    """Command line first, then the scene file's ``[quality]`` table, then fixed / 0.5%."""
    own = getattr(scene, "quality", {}) or {}
    if args.quality:
        mode = args.quality
    else:  # a budget given on the command line asks for auto, as --lod-error asks for LOD
        mode = "auto" if args.max_error is not None else own.get("mode", "fixed")
    budget = args.max_error or parse_budget(own.get("max_error", "0.5%"))
    return QualitySettings(mode, budget)


def _fallback(args: argparse.Namespace) -> str:
    """The painter fallback the flags ask for (``pixel`` unless told)."""
    return "off" if args.no_fallback else args.fallback or "pixel"


def _display(args: argparse.Namespace) -> tuple[DisplaySettings, Calibration | None]:
    """The display the arguments ask for, and the Looking Glass calibration if any.

    Fills in ``args.zones`` and ``args.angle`` (for the report).
    """
    cal = None
    if args.display is not None:
        if args.angle is not None:
            raise SettingsError("--angle: with --display the calibration's viewCone sets it")
        cal = parse_display(args.display, args.zones or DEFAULT_VIEWS)
        args.zones, args.angle = cal.views, cal.view_cone
    args.zones = args.zones or 5
    args.angle = 16.0 if args.angle is None else args.angle
    cols, rows = args.size
    return DisplaySettings(zones=args.zones, angle_deg=args.angle, cols=cols, rows=rows), cal


def write_lookingglass(frame: Frame, cal: Calibration, out: Path) -> Path:
    """Write the panel image of ``frame`` interleaved for ``cal``; returns its path."""
    panel = Interleaver(cal)(frame.colour)
    return write_png(out / f"lookingglass-{cal.screen_w}x{cal.screen_h}.png", panel)


def run(args: argparse.Namespace) -> dict:
    """Render as the parsed arguments say; return the JSON report."""
    display, cal = _display(args)
    settings = RenderSettings(
        lod=lod_settings(args),
        method=args.method,
        cull=CullSettings(args.cull),
        light=LightSettings(model=args.light, evaluation=args.specular),
        painter_fallback=_fallback(args),
    )
    start = time.perf_counter()
    scene, repairs = _load(args.scene, args.strict, display)
    load_ms = (time.perf_counter() - start) * 1e3
    for line in repairs:
        print(f"holo-render: warning: {line}", file=sys.stderr)
    quality = _quality(args, scene)
    chooser = (QualityChooser(quality, CostModel.load(args.cost_model))
               if quality.mode == "auto" else None)
    warm_up(settings)  # compile or load the numba kernels outside the timings
    renderer = _renderer()
    if settings.lod is not None:  # chains before the first frame, never inside it
        build_chains(renderer.lod, scene, settings.lod)
    if chooser is not None:
        frame, settings = _render_auto(args.light, renderer, chooser, scene, display, settings)
        flatten_ms = frame.stats["ms"]["flatten"]
    else:
        frame = renderer.render(scene, display, settings)
        flatten_ms = frame.stats["ms"]["flatten"]  # the one-off build, not a warm frame's
        frame = budget_frames(renderer, scene, display, settings, frame)
    renderer.lod.builds.on_progress.end()
    renderer.lod.close()
    for note in frame.stats.get("lod", {}).get("chains", {}).get("notes", []):
        print(f"holo-render: warning: {note}", file=sys.stderr)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_zones(frame, out)
    write_strip(frame, out / "strip.png")
    if args.quilt or cal is not None:
        write_quilt(frame, out)
    if cal is not None:
        write_lookingglass(frame, cal, out)
    return _report(args, settings, quality, frame, scene, (load_ms, flatten_ms), out)


def _render_auto(light: str, renderer: Renderer, chooser: QualityChooser, scene: Scene,
                 display: DisplaySettings,
                 settings: RenderSettings) -> tuple[Frame, RenderSettings]:
    """One frame with ``--quality auto``, and the settings the chooser picked."""
    lod_report, shown = None, scene
    if settings.lod is not None:  # levels first, then the methods for that scene
        shown, lod_report = renderer.lod.apply(scene, display, settings.lod, True,
                                               settings.method, settings.light.evaluation)
    frame = render_auto(renderer, chooser, shown, display, light, settings.cull)
    if lod_report is not None:
        frame.stats["lod"] = lod_report
    q = frame.stats["quality"]
    return frame, replace(settings, method=q["method"], painter_fallback="pixel",
                          light=LightSettings(light, q["specular"]))


def _report(args: argparse.Namespace, settings: RenderSettings, quality: QualitySettings,
            frame: Frame, scene: Scene, load_flatten_ms: tuple[float, float],
            out: Path) -> dict:
    """The JSON report of a render: settings used, mesh, timings, occlusion counters."""
    load_ms, flatten_ms = load_flatten_ms
    return {
        "scene": args.scene,
        "settings": {
            "zones": args.zones,
            "angle_deg": args.angle,
            "size": list(args.size),
            "method": settings.method,
            "light": args.light,
            "specular": settings.light.evaluation,
            "cull": args.cull,
            "painter_fallback": settings.painter_fallback,
            "quality": quality.mode,
            "max_error": quality.budget.as_dict(),
            "lod": "on" if settings.lod else "off",
        },
        "quality": frame.stats.get("quality"),
        "billboards": frame.stats.get("billboards"),
        "mesh": {
            **mesh_report(scene, load_ms, args.strict),
            **build_report(flatten_ms, scene),
        },
        "polygons": frame.stats["polygons"],
        "ms": {k: round(v, 3) for k, v in frame.stats["ms"].items()},
        "occlusion": occlusion_counters(frame.stats["occlusion"], frame.depth),
        **({"lod": frame.stats["lod"]} if "lod" in frame.stats else {}),
        "out": str(out),
    }


def _renderer() -> Renderer:
    """A renderer whose level-of-detail chain builds show their progress on stderr."""
    renderer = Renderer()
    renderer.lod = lod_state("holo-render")[0]
    return renderer


def occlusion_counters(stats: dict, depth: np.ndarray) -> dict:
    """The occlusion counters of ``--json``, the same keys for every method first.

    Parameters
    ----------
    stats : dict
        The method's own counters (``Frame.stats["occlusion"]``).
    depth : ndarray, shape (Z, R, C)
        The frame's depth, +inf where nothing is drawn.

    Returns
    -------
    dict
        ``covered_pixels`` (pixels showing a surface, all zones), ``covered_by_zone``
        (list of Z), ``fallback`` (``"zbuffer"`` when a run-length frame was redrawn,
        ``"pixel"`` when its wrong points were z-tested, else None), then the method's
        own counters (run-length: ``inconsistent_pixels``, ``inconsistent_by_zone``;
        bsp: ``nodes``, ``fragments``, ``splits``...; raycast: ``candidates``...),
        milliseconds rounded to microseconds.
    """
    covered = np.isfinite(depth).reshape(depth.shape[0], -1).sum(axis=1)
    out = {"covered_pixels": int(covered.sum()), "covered_by_zone": covered.tolist(),
           "fallback": stats.get("fallback")}
    for key, value in stats.items():
        out[key] = round(value, 3) if isinstance(value, float) else value
    return out


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit status."""
    args = build_parser().parse_args(argv)
    problem = scene_problem(args.scene)
    if not problem and args.quality == "fixed" and args.max_error is not None:
        problem = "--max-error is the budget of --quality auto; --quality fixed has none"
    if not problem and args.cost_model and not Path(args.cost_model).is_file():
        problem = (f"--cost-model {args.cost_model}: no such file (holo-bench quality "
                   "--calibrate --model PATH writes one)")
    if problem:
        print(f"holo-render: error: {problem}", file=sys.stderr)
        return 2
    problem = output_problem(args.out, folder=True)
    try:  # before the render, not after it
        if not problem:
            Path(args.out).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        problem = f"{args.out}: cannot make the folder: {exc.strerror}"
    if problem:
        print(f"holo-render: error: --out {problem}", file=sys.stderr)
        return 2
    setup_frame_process()  # heap reuse and one BLAS thread (service.process)
    return interruptible("holo-render", lambda: _main(args))


def _main(args: argparse.Namespace) -> int:
    try:
        report = run(args)
    except HoloError as exc:
        print(f"holo-render: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"holo-render: error: {os_error_text(exc)}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(report))
    else:
        p = report["polygons"]
        print(
            f"{p['in']} polygons, {p['culled']} culled, {p['kept']} kept, "
            f"{p['drawn']} seen in a zone{_billboard_words(report)}; "
            f"{report['ms']['total']:.1f} ms; wrote {report['out']}/"
        )
        q = report["quality"]
        if q:
            e = q["predicted_error"]
            print(f"quality auto: {q['method']} occlusion, {q['specular']} light; predicted "
                  f"{e['pct_wrong']:.3f}% of pixels wrong, {e['psnr']:.1f} dB ({q['reason']})")
        fb = report["occlusion"].get("fallback")
        if fb:
            how = "redrawn with the zbuffer" if fb == "zbuffer" else "z-tested per pixel"
            print(
                f"note: average-z order was inconsistent "
                f"({report['occlusion']['inconsistent_pixels']} pixels); {how}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
