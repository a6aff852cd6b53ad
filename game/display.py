"""The game's pygame-ce window: display modes, HUD, "reconnecting" and score screens.

Modes (:data:`MODES`):

=================  ================================================================
mode               shows
=================  ================================================================
``head``           the zone nearest the tracked head (:func:`zone_for_head`), so the
                   scene shows parallax as the player leans; the middle zone
                   without a tracker
``strip``          every zone side by side, zone 0 (leftmost viewer) leftmost
``zone``           one fixed zone (``[`` / ``]`` choose it)
``autostereogram`` a single-image random-dot stereogram of the frame's depth (the
                   service's ``autostereogram`` encoding, or the local renderer's,
                   ``docs/autostereogram.md``): look through the screen until the
                   dots fuse; the HUD gets a dark backing so it stays readable over
                   the dots
=================  ================================================================

A mode in :data:`UNAVAILABLE` (none now) shows a notice and keeps the current mode.

The HUD shows the score, the window's frames per second, the update (render) rate
against the refresh rate, and the latency from the input a render was made from
to the frame.  Runs headless with SDL's dummy video driver.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pygame

from service.display import DisplaySettings
from service.lookingglass import Interleaver
from service.render.frame import view_strip

#: Modes that can be shown, in the order the demo screenshots them.
MODES = ("head", "strip", "zone", "autostereogram")
#: Modes named but not available -> why (none: autostereogram landed with issue 12).
UNAVAILABLE: dict[str, str] = {}
#: HUD backing (RGBA) in modes whose picture is busy everywhere (random dots).
HUD_BACKING = (0, 0, 0, 190)
#: Modes whose HUD gets :data:`HUD_BACKING`.
BUSY_MODES = frozenset({"autostereogram"})
#: Assumed distance from the head to the display plane when mapping the tracker's
#: x (mm) to a viewing angle.
HEAD_DISTANCE_MM = 250.0
WINDOW = (960, 600)
HUD_COLOUR = (230, 230, 230)
BACKGROUND = (8, 8, 16)
#: SDL video drivers that show no window.
HEADLESS_DRIVERS = frozenset({"dummy", "offscreen"})
#: The environment variables naming SDL's video driver: SDL2's name and SDL3's.
VIDEO_DRIVER_VARS = ("SDL_VIDEODRIVER", "SDL_VIDEO_DRIVER")
SDL_HEADLESS = {
    "SDL_VIDEODRIVER": "dummy",
    "SDL_AUDIODRIVER": "dummy",
    "SDL_VIDEO_DRIVER": "dummy",
    "SDL_AUDIO_DRIVER": "dummy",
}


def headless_env(env: dict | None = None) -> dict:
    """``env`` (default ``os.environ``) with SDL's dummy video and audio drivers set."""
    out = dict(os.environ if env is None else env)
    out.update(SDL_HEADLESS)
    return out


def has_display(env: Mapping[str, str] | None = None) -> bool:
    """True when a window can be shown: an X11 or Wayland display, SDL not told otherwise.

    Parameters
    ----------
    env : mapping, optional
        The environment (default ``os.environ``).  Either of SDL2's ``SDL_VIDEODRIVER``
        and SDL3's ``SDL_VIDEO_DRIVER`` naming ``dummy`` (or ``offscreen``) means none.
    """
    env = os.environ if env is None else env
    drivers = {env.get(name, "").strip().lower() for name in VIDEO_DRIVER_VARS}
    if drivers & HEADLESS_DRIVERS:
        return False
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


def choose_mode(mode: str, current: str = MODES[0]) -> tuple[str, str]:
    """The mode to show when ``mode`` is asked for, and a notice saying why not.

    Parameters
    ----------
    mode : str
        The mode asked for.
    current : str
        What to keep showing when ``mode`` cannot be shown (an entry of :data:`MODES`).

    Returns
    -------
    mode : str
        ``mode`` when it is one of :data:`MODES`, else ``current``.
    notice : str
        ``""`` when ``mode`` is shown, else a line for the HUD or the command line.
    """
    if mode in MODES:
        return mode, ""
    why = UNAVAILABLE.get(mode, "there is no such display mode")
    return current, f"{mode} mode is not available ({why}); showing {current}"


def zone_for_head(
    x_mm: float, z_mm: float, display: DisplaySettings, distance_mm: float = HEAD_DISTANCE_MM
) -> int:
    """The view zone whose direction is nearest the head's.

    Parameters
    ----------
    x_mm, z_mm : float
        The tracker's head position (x to the right, z toward the display's viewer
        side, relative to the rest position).
    display : DisplaySettings
    distance_mm : float
        Rest distance from the display plane.
    """
    angle = math.degrees(math.atan2(x_mm, max(distance_mm + z_mm, 1.0)))
    centres = np.degrees(display.zone_angles())
    return int(np.argmin(np.abs(centres - angle)))


#: The HUD's line while the frame shown holds the last render (renders are late).
HELD_LINE = "held: renders late, last render shown as it was"


#: the picture's margins across and down (pixels), and its top (under the HUD lines)
PICTURE_MARGIN = (20, 90)
PICTURE_TOP = 80


def picture_area(size: tuple[int, int]) -> pygame.Rect:
    """Where the frame goes in a window of ``size``: below the HUD lines, with a margin.

    A window where the margins would leave the picture under a quarter of it (under
    120 px tall) gets the picture over all of it, the HUD on top, rather than a
    sliver or a negative size.
    """
    w, h = size
    if w - PICTURE_MARGIN[0] >= w // 4 and h - PICTURE_MARGIN[1] >= h // 4:
        return pygame.Rect(PICTURE_MARGIN[0] // 2, PICTURE_TOP, w - PICTURE_MARGIN[0],
                           h - PICTURE_MARGIN[1])
    return pygame.Rect(0, 0, w, h)


@dataclass
class Hud:
    """What the HUD shows.

    Attributes
    ----------
    score : int
    seconds : float
    fps : float
        Window frames per second.
    update_hz, refresh_hz : float
        Renders and refreshes per second seen in the frame stream.
    latency_ms : float or None
    mode : str
    zone : int
    lines : list of str
        Extra lines (pause, notices, attract mode).
    held : bool
        The frame shown holds the last render: none came within its use-by date,
        so it is shown as it was rather than extrapolated (docs/galilean.md).
    """

    score: int = 0
    seconds: float = 0.0
    fps: float = 0.0
    update_hz: float = 0.0
    refresh_hz: float = 0.0
    latency_ms: float | None = None
    mode: str = "head"
    zone: int = 0
    lines: list[str] = field(default_factory=list)
    held: bool = False

    def text(self) -> list[str]:
        """The HUD's lines."""
        lat = "-" if self.latency_ms is None else f"{self.latency_ms:.0f} ms"
        return [
            f"score {self.score}   time {self.seconds:5.1f} s",
            f"fps {self.fps:4.1f}   updates {self.update_hz:4.1f} Hz / refreshes "
            f"{self.refresh_hz:4.1f} Hz   latency {lat}",
            f"mode {self.mode} (zone {self.zone})",
            *([HELD_LINE] if self.held else []),
            *self.lines,
        ]


def _surface(rgb: np.ndarray) -> pygame.Surface:
    """A surface from an (R, C, 3) uint8 image."""
    return pygame.surfarray.make_surface(np.ascontiguousarray(rgb.swapaxes(0, 1)))


def _fit(size: tuple[int, int], box: pygame.Rect) -> pygame.Rect:
    """The largest rectangle of ``size``'s aspect centred in ``box``."""
    scale = min(box.width / size[0], box.height / size[1])
    rect = pygame.Rect(0, 0, int(size[0] * scale), int(size[1] * scale))
    rect.center = box.center
    return rect


#: mode -> the image it shows from a frame's colour (Z, R, C, 3) and the zone
#: (``autostereogram`` shows the frame's own stereogram when it has one: :meth:`GameWindow.draw`).
IMAGES = {
    "head": lambda colour, zone: colour[zone],
    "zone": lambda colour, zone: colour[zone],
    "strip": lambda colour, zone: view_strip(colour, sep=4, sep_value=40),
    "autostereogram": lambda colour, zone: colour[zone],
}


def _image(colour: np.ndarray, mode: str, zone: int, sird: np.ndarray | None) -> np.ndarray:
    """The (R, C, 3) picture of a mode; a grey stereogram (R, C) is shown as RGB."""
    if mode == "autostereogram" and sird is not None:
        return np.repeat(sird[:, :, None], 3, axis=2)
    # a frame may have fewer zones than the game's display (another client's set_display)
    return IMAGES[mode](colour, min(max(zone, 0), colour.shape[0] - 1))


class GameWindow:
    """The window (or an off-screen surface of the same size when headless).

    Parameters
    ----------
    size : tuple of int
    title : str
    """

    def __init__(self, size: tuple[int, int] = WINDOW, title: str = "holo-game",
                 panel: Interleaver | None = None) -> None:
        pygame.display.init()
        pygame.font.init()
        if panel is not None:  # the Looking Glass: full screen at the panel's resolution
            size = (panel.cal.screen_w, panel.cal.screen_h)
        flags = pygame.FULLSCREEN if panel is not None and has_display() else 0
        self.screen = pygame.display.set_mode(size, flags)
        pygame.display.set_caption(title)
        self.font = pygame.font.Font(None, 24)
        self.big = pygame.font.Font(None, 72)
        self.panel = panel
        self._panel_image = None if panel is None else np.zeros(panel.shape, np.uint8)

    def draw(self, colour: np.ndarray | None, mode: str, zone: int, hud: Hud,
             sird: np.ndarray | None = None) -> None:
        """The frame in the given mode with the HUD over it.

        ``sird`` is the frame's stereogram, (R, C) uint8, shown in ``autostereogram``
        mode (the zone's colour image stands in while none has arrived).  On a Looking
        Glass (``panel``) a frame with every view is interleaved onto the whole screen
        whatever the mode.
        """
        self.screen.fill(BACKGROUND)
        if self._draw_panel(colour):
            pass
        elif colour is not None:
            image = _surface(_image(colour, mode, zone, sird))
            rect = _fit(image.get_size(), picture_area(self.screen.get_size()))
            self.screen.blit(pygame.transform.scale(image, rect.size), rect)
        for k, line in enumerate(hud.text()):
            text = self.font.render(line, True, HUD_COLOUR)
            if mode in BUSY_MODES:
                backing = pygame.Surface(text.get_rect().inflate(8, 4).size, pygame.SRCALPHA)
                backing.fill(HUD_BACKING)
                self.screen.blit(backing, (6, 6 + 20 * k))
            self.screen.blit(text, (10, 8 + 20 * k))

    def _draw_panel(self, colour: np.ndarray | None) -> bool:
        """Interleave ``colour``'s views onto the screen; False when it is not for the panel."""
        if self.panel is None or colour is None or colour.shape[0] != self.panel.cal.views:
            return False
        image = self.panel(colour, self._panel_image)
        w, h = self.panel.cal.screen_w, self.panel.cal.screen_h
        self.screen.blit(pygame.image.frombuffer(image, (w, h), "RGB"), (0, 0))
        return True

    def banner(self, title: str, lines: list[str] = (), dim: bool = True) -> None:
        """A large centred title with lines under it, over a dimmed picture."""
        if dim:
            shade = pygame.Surface(self.screen.get_size(), pygame.SRCALPHA)
            shade.fill((0, 0, 0, 150))
            self.screen.blit(shade, (0, 0))
        centre = self.screen.get_rect().center
        text = self.big.render(title, True, (255, 220, 90))
        self.screen.blit(text, text.get_rect(center=(centre[0], centre[1] - 80)))
        for k, line in enumerate(lines):
            img = self.font.render(line, True, HUD_COLOUR)
            self.screen.blit(img, img.get_rect(center=(centre[0], centre[1] - 20 + 24 * k)))

    def flip(self) -> None:
        """Show what was drawn."""
        pygame.display.flip()

    def screenshot(self, path: str | Path) -> Path:
        """Save the window's picture as PNG."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        pygame.image.save(self.screen, str(path))
        return path

    def pixels(self) -> np.ndarray:
        """The window's picture, (H, W, 3) uint8."""
        return pygame.surfarray.array3d(self.screen).swapaxes(0, 1).copy()
