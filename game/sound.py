"""Starting pygame without the audio library's noise: one line when there is no sound device.

Where there is no sound card, ``pygame.init()`` and ``pygame.mixer.init()`` make
libasound (ALSA) write 8 lines each straight to file descriptor 2 ("ALSA lib
confmisc.c:855:(parse_card) cannot find card '0'", ...), 16 in a game, below
Python's ``sys.stderr``, so no Python setting silences them.  :func:`start_pygame`
points descriptor 2 at a temporary file while pygame opens its modules and the
mixer, passes on afterwards any line that is not such audio noise
(:data:`AUDIO_NOISE`), and says in one line that the beeps are muted.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator

import pygame

from game.gameover import Beeper

#: Line starts of what the audio libraries print when they find no device.
AUDIO_NOISE = ("ALSA lib ", "error: XDG_RUNTIME_DIR", "Cannot connect to server socket",
               "jack server is not running", "Home directory not accessible")


@contextlib.contextmanager
def fd2_lines(lines: list[str]) -> Iterator[None]:
    """Within the block, what anything writes on descriptor 2 is kept in ``lines`` instead.

    ``lines`` is filled when the block ends.  Where descriptor 2 cannot be duplicated
    (a closed stderr) the block runs with stderr as it is.
    """
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:
        yield
        return
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield
        finally:
            with contextlib.suppress(ValueError, OSError):
                sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            lines += sink.read().decode(errors="replace").splitlines()


def _open_mixer() -> str | None:
    """Open the mixer if pygame.init() did not; None, or why there is no sound."""
    if pygame.mixer.get_init():
        return None
    try:
        pygame.mixer.init()
    except pygame.error as exc:
        return str(exc) or "the mixer did not open"
    return None


def start_pygame(muted: bool) -> tuple[Beeper, str | None, list[str]]:
    """``pygame.init()`` and the beeper, the audio library's noise kept off stderr.

    Parameters
    ----------
    muted : bool
        Headless: the sound device is never opened.

    Returns
    -------
    beeper : Beeper
        Muted when ``muted`` or when no sound device opened.
    problem : str or None
        Why there is no sound (SDL's words), when a device was wanted and none opened.
    other : list of str
        Lines written to descriptor 2 meanwhile that are not audio noise (to pass on).
    """
    written: list[str] = []
    with fd2_lines(written):
        pygame.init()
        problem = None if muted else _open_mixer()
        beeper = Beeper(muted=muted or problem is not None)
    other = [ln for ln in written if ln.strip() and not ln.startswith(AUDIO_NOISE)]
    return beeper, problem, other
