"""The holo-video dodge game client (seed 000, chapter 5); see docs/game.md."""

import os

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
