"""Pictures of a run for ``--out DIR``: a screenshot per display mode, a film strip, a GIF.

:class:`Capture` is called after every tick.  It first tours the display modes
(:data:`game.display.MODES`; each shown for ``dwell_s`` and screenshotted as
``mode-<name>.png`` after three quarters of that, or as it ends if no tick fell
later), then returns to the mode the run asked for.  The tour starts
with the first frame: a service that starts slowly (a loaded machine) would
otherwise leave the first modes without a picture to screenshot.  It also saves
``gameover.png`` during the spectacular display, ``score.png`` on the score
screen and ``reconnecting.png`` when the service drops, and keeps a small frame
every ``film_every_s`` from the first render shown on for ``film.png`` (a grid of
frames) and ``demo.gif``; a tick that shows no render (a new game's black "GET
READY", a waiting or reconnecting banner) is left out of the film.
The GIF is written with Pillow, which matplotlib already depends on; without it
only the PNG strip is written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pygame

from game.display import MODES
from service.png import write_png

FILM_SIZE = (320, 200)
FILM_FRAMES = 40
FILM_COLUMNS = 4


class Capture:
    """Screenshots and film of a :class:`game.client_loop.GameClient` run.

    Parameters
    ----------
    out : str or Path
    start : float
        Clock reading when the run started.
    dwell_s : float
        Seconds each mode is shown during the tour.
    film_every_s : float
    tour : bool
        Tour the modes first.
    """

    def __init__(
        self,
        out: str | Path,
        start: float,
        dwell_s: float = 2.0,
        film_every_s: float = 0.5,
        tour: bool = True,
    ) -> None:
        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.start, self.dwell_s, self.film_every_s = start, dwell_s, film_every_s
        self.plan = list(MODES) if tour else []
        self.files: list[Path] = []
        self.film: list[np.ndarray] = []
        self._home: str | None = None
        self._tour_start: float | None = None
        self._showing: str | None = None
        self._next_film: float | None = None
        self._taken: set[str] = set()

    def __call__(self, client: Any) -> None:
        """Look at the client after a tick; save what is due."""
        now = client.clock()
        self._tour(client, now)
        over = client.over
        if over is not None and over.phase == "explode" and now - over.start > 2.0:
            self._once(client, "gameover")
        if over is not None and over.phase == "score":
            self._once(client, "score")
        if not client.backend.connected and now - self.start > 0.5:
            self._once(client, "reconnecting")
        if self._next_film is None and client.picture_shown:
            self._next_film = now  # the film starts with the first render shown
        if (self._next_film is not None and now >= self._next_film
                and len(self.film) < FILM_FRAMES and client.picture_shown):
            self._next_film = now + self.film_every_s
            small = pygame.transform.smoothscale(client.window.screen, FILM_SIZE)
            self.film.append(pygame.surfarray.array3d(small).swapaxes(0, 1).copy())

    def _tour(self, client: Any, now: float) -> None:
        """Show the next mode of the plan; screenshot the one the last tick drew.

        A mode is screenshotted after 3/4 of its dwell, or when its dwell is over
        without one (ticks slower than a quarter dwell on a loaded machine). The
        next mode comes once the current one is done, so a tick longer than a dwell
        (a loaded machine) delays the tour but never skips a mode.
        """
        if self._home is None:
            self._home = client.mode
        if not self.plan:
            return
        if self._showing is None:
            if client.colour is None:
                return  # no frame yet: nothing to show in any mode
            self._show(client, now)
            return
        into = now - self._tour_start
        if into > 0.75 * self.dwell_s:  # a tick since set_mode drew it
            self._once(client, f"mode-{self._showing}")
        if into >= self.dwell_s:
            self.plan = self.plan[1:]
            if self.plan:  # on the dwell grid: a late tour catches up a tick a mode
                self._show(client, self._tour_start + self.dwell_s)
            else:
                client.set_mode(self._home)
                self._showing = None

    def _show(self, client: Any, start: float) -> None:
        """Switch to the plan's first mode; its dwell starts at ``start``."""
        self._showing, self._tour_start = self.plan[0], start
        client.set_mode(self._showing)

    def _once(self, client: Any, name: str) -> None:
        if name not in self._taken and client.colour is not None:
            self._taken.add(name)
            self.files.append(client.window.screenshot(self.out / f"{name}.png"))

    def finish(self) -> list[Path]:
        """Write the film strip (and the GIF when Pillow is there); returns every file.

        A screenshot saved just as a signal stopped the run (before it was noted)
        is listed too.
        """
        for name in sorted(self._taken):
            path = self.out / f"{name}.png"
            if path not in self.files and path.is_file():
                self.files.append(path)
        if self.film:
            rows = -(-len(self.film) // FILM_COLUMNS)
            h, w = self.film[0].shape[:2]
            grid = np.zeros((rows * h, FILM_COLUMNS * w, 3), np.uint8)
            for k, img in enumerate(self.film):
                r, c = divmod(k, FILM_COLUMNS)
                grid[r * h : (r + 1) * h, c * w : (c + 1) * w] = img
            self.files.append(write_png(self.out / "film.png", grid))
            gif = _write_gif(self.out / "demo.gif", self.film, int(1000 * self.film_every_s))
            self.files += [gif] if gif is not None else []
        return self.files


def _write_gif(path: Path, frames: list[np.ndarray], ms: int) -> Path | None:
    """An animated GIF through Pillow (matplotlib's dependency); None without it."""
    try:
        from PIL import Image
    except ImportError:
        return None
    images = [Image.fromarray(f).convert("P", palette=Image.Palette.ADAPTIVE) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=ms, loop=0)
    return path
