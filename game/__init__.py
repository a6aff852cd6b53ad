"""The holo-video dodge game client (seed 000, chapter 5); see docs/game.md.

:mod:`.rules` (pure game state), :mod:`.scene` (the game's objects for the renderer),
:mod:`.bot` (attract mode), :mod:`.actions` and :mod:`.pads` (input), :mod:`.backends`
(frames from the service or in process), :mod:`.client_loop` (the loop),
:mod:`.display` (the pygame window), :mod:`.gameover`, :mod:`.highscores`,
:mod:`.capture` (screenshots, film); commands in :mod:`.commands`: ``holo-game``
and ``make demo``.
"""

import os

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
