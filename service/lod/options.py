"""The level-of-detail options shared by ``holo-render``, ``holo-service`` and ``holo-game``.

``--lod on|off`` (off unless ``--lod-error``, ``--lod-colour`` or ``--budget-ms`` is
given), ``--lod-error PX`` (default 0.5), ``--lod-colour PCT|off`` (default 1) and
``--budget-ms MS``; see :mod:`service.lod`.
"""

from __future__ import annotations

import argparse
import sys
from typing import TextIO

from service.base.cli_args import float_range
from service.display import DisplaySettings
from service.lod.builds import ChainBuilds
from service.lod.cache import cache_dir
from service.lod.settings import COLOUR_LEVELS, COLOUR_PCT_MAX, DEFAULT_COLOUR_PCT, LodSettings
from service.lod.state import LodState
from service.render.frame import Frame
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import Scene

#: Frames ``holo-render`` draws when given ``--budget-ms``: a render with nothing
#: measured is chosen by error alone, so the first ones measure the renderer's cost
#: model (:class:`service.lod.cost.FrameCost`) and the last one is written.
BUDGET_FRAMES = 3


#: ``--lod-colour``'s word for "colour not counted" (``LodSettings.colour_pct`` None).
COLOUR_OFF = "off"


def colour_pct(text: str) -> float | str:
    """An argparse type: a colour budget, % from 0 to 100, or :data:`COLOUR_OFF`."""
    if text.strip().lower() == COLOUR_OFF:
        return COLOUR_OFF
    return float_range(0, COLOUR_PCT_MAX)(text)


colour_pct.__name__ = "colour budget"


def add_colour_option(p: argparse.ArgumentParser) -> None:
    """Add ``--lod-colour PCT|off`` (:attr:`LodSettings.colour_pct`) to a parser."""
    p.add_argument(
        "--lod-colour", type=colour_pct, default=None, metavar="PCT|off",
        help="level of detail's colour budget: objects are drawn finer until at most PCT "
        f"%% of the display's pixels are predicted to change colour by more than "
        f"{COLOUR_LEVELS} levels, 0 to {COLOUR_PCT_MAX:g} (default: {DEFAULT_COLOUR_PCT:g}); "
        "off: levels by the screen error alone (faster, colours change more)",
    )


def colour_given(args: argparse.Namespace) -> bool:
    """Whether ``--lod-colour`` was given (which turns level of detail on)."""
    return args.lod_colour is not None


def colour_budget(args: argparse.Namespace) -> float | None:
    """``LodSettings.colour_pct`` from ``--lod-colour``: its default when not given."""
    if args.lod_colour is None:
        return DEFAULT_COLOUR_PCT
    return None if args.lod_colour == COLOUR_OFF else float(args.lod_colour)


def add_lod_options(p: argparse.ArgumentParser, budget: bool = True) -> None:
    """Add ``--lod``, ``--lod-error``, ``--lod-colour`` and (``budget``) ``--budget-ms``."""
    p.add_argument(
        "--lod", choices=("on", "off"), default=None,
        help="level of detail per object: each frame every object is drawn with the "
        "cheapest of its simplified meshes whose predicted screen error stays under "
        "--lod-error (chains cached in $HOLO_LOD_CACHE or ~/.cache/holo-realizer/lod); "
        "off unless --lod-error, --lod-colour" + (" or --budget-ms" if budget else "")
        + " is given",
    )
    p.add_argument(
        "--lod-error", type=float_range(0, None, lo_open=True), default=None, metavar="PX",
        help="largest predicted screen error of a level of detail, pixels > 0 (default 0.5)",
    )
    add_colour_option(p)
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
    wanted = args.lod == "on" or (args.lod is None and (
        args.lod_error is not None or args.budget_ms is not None or colour_given(args)))
    if not wanted:
        return None
    return LodSettings(
        error_px=LodSettings.error_px if args.lod_error is None else args.lod_error,
        budget_ms=args.budget_ms, colour_pct=colour_budget(args),
    )


def budget_frames(renderer: Renderer, scene: Scene, display: DisplaySettings,
                  settings: RenderSettings, frame: Frame) -> Frame:
    """The frame to write: ``frame`` again after :data:`BUDGET_FRAMES` renders in all.

    Only with a time budget (``settings.lod.budget_ms``): the frames before the last
    measure the cost model the budget is predicted with.  ``renderer`` is the
    :class:`service.render.pipeline.Renderer` that drew ``frame`` (its first).
    """
    lod = settings.lod
    if lod is None or not lod.enabled or lod.budget_ms is None:
        return frame
    for _ in range(BUDGET_FRAMES - 1):
        frame = renderer.render(scene, display, settings)
    frame.stats["lod"]["frames_measured"] = BUDGET_FRAMES - 1
    return frame


class ChainProgress:
    """Tells stderr that a level-of-detail chain is being built, and how far it got.

    A build (the bunny: 2 s quiet, 5-9 s on a loaded machine) happens once per mesh,
    when its scene is loaded (:func:`build_chains`); then it is read from the cache.  One line when
    a build starts; on a terminal it is updated in place (decimations done of those
    planned) and ended when the next line is printed (:meth:`end`).
    """

    def __init__(self, prog: str, stream: TextIO | None = None) -> None:
        self.prog = prog
        self.stream = stream if stream is not None else sys.stderr
        self._open = False
        self._name: str | None = None

    def __call__(self, name: str, done: int, planned: int) -> None:
        """``progress`` of :class:`~service.lod.state.LodState`: ``done`` of ``planned``."""
        tty = self.stream.isatty()
        if name != self._name or done <= 1:
            self.end()
            self._name = name
            line = (f"{self.prog}: building the level-of-detail chain of {name or 'a mesh'} "
                    f"(once; cached in {cache_dir()})")
            if not tty:
                print(line, file=self.stream, flush=True)
                return
            self._line = line
        if tty and planned:
            print(f"\r{self._line}: {done}/{planned}", end="", file=self.stream, flush=True)
            self._open = True

    def end(self) -> None:
        """End an in-place progress line (call before printing anything else)."""
        if self._open:
            print(file=self.stream, flush=True)
            self._open = False


def lod_state(prog: str) -> tuple[LodState, ChainProgress]:
    """A renderer's LOD state for a command that renders a few frames, with its progress.

    Chains are built in the background (a child process each), never inside a
    frame; :func:`build_chains` builds a scene's before its first frame and shows
    the builds on stderr.  Call ``progress.end()`` after the render and
    ``state.close()`` at the end.
    """
    progress = ChainProgress(prog)
    state = LodState(background=True)
    state.builds = ChainBuilds(state.cache)
    state.builds.on_progress = progress
    return state, progress


def build_chains(state: LodState, scene: Scene, settings: LodSettings,
                 poll_s: float = 0.5) -> int:
    """Build the chains ``scene``'s meshes lack before its first frame; how many were built.

    Waits in steps of ``poll_s`` so that Ctrl-C stops it.  A chain that cannot be
    built is drawn in full; its reason is in the next frame's ``lod.chains.notes``.
    """
    queued = state.prepare(scene, settings)
    while queued and not state.builds.wait_idle(poll_s):
        pass
    return queued
