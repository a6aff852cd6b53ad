"""The level-of-detail options shared by ``holo-render``, ``holo-service`` and ``holo-game``.

``--lod on|off`` (off unless ``--lod-error`` or ``--budget-ms`` is given),
``--lod-error PX`` (default 0.5) and ``--budget-ms MS``; see :mod:`service.lod`.
"""

from __future__ import annotations

import argparse

from service.cli_args import float_range
from service.display import DisplaySettings
from service.frame import Frame
from service.lod import LodSettings
from service.pipeline import Renderer, RenderSettings
from service.scene import Scene

#: Frames ``holo-render`` draws when given ``--budget-ms``: a render with nothing
#: measured is chosen by error alone, so the first ones measure the renderer's cost
#: model (:class:`service.lod.FrameCost`) and the last one is written.
BUDGET_FRAMES = 3


def add_lod_options(p: argparse.ArgumentParser, budget: bool = True) -> None:
    """Add ``--lod``, ``--lod-error`` and (with ``budget``) ``--budget-ms`` to a parser."""
    p.add_argument(
        "--lod", choices=("on", "off"), default=None,
        help="level of detail per object: each frame every object is drawn with the "
        "cheapest of its simplified meshes whose predicted screen error stays under "
        "--lod-error (chains cached in $HOLO_LOD_CACHE or ~/.cache/holo-realizer/lod); "
        "off unless --lod-error" + (" or --budget-ms" if budget else "") + " is given",
    )
    p.add_argument(
        "--lod-error", type=float_range(0, None, lo_open=True), default=None, metavar="PX",
        help="largest predicted screen error of a level of detail, pixels > 0 (default 0.5)",
    )
    if not budget:
        p.set_defaults(budget_ms=None)
        return
    p.add_argument(
        "--budget-ms", type=float_range(0, None, lo_open=True), default=None, metavar="MS",
        help="with --lod: frame-time budget; objects go coarser than --lod-error allows, "
        "smallest and farthest first, to meet it",
    )


def lod_settings(args: argparse.Namespace) -> LodSettings | None:
    """The LOD settings the parsed options ask for, or None when LOD is off."""
    wanted = args.lod == "on" or (
        args.lod is None and (args.lod_error is not None or args.budget_ms is not None)
    )
    if not wanted:
        return None
    return LodSettings(
        error_px=0.5 if args.lod_error is None else args.lod_error, budget_ms=args.budget_ms
    )


def budget_frames(renderer: Renderer, scene: Scene, display: DisplaySettings,
                  settings: RenderSettings, frame: Frame) -> Frame:
    """The frame to write: ``frame`` again after :data:`BUDGET_FRAMES` renders in all.

    Only with a time budget (``settings.lod.budget_ms``): the frames before the last
    measure the cost model the budget is predicted with.  ``renderer`` is the
    :class:`service.pipeline.Renderer` that drew ``frame`` (its first).
    """
    lod = settings.lod
    if lod is None or not lod.enabled or lod.budget_ms is None:
        return frame
    for _ in range(BUDGET_FRAMES - 1):
        frame = renderer.render(scene, display, settings)
    frame.stats["lod"]["frames_measured"] = BUDGET_FRAMES - 1
    return frame
