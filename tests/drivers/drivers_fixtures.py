"""Where the driver tests find the real Hatire capture (a fixture no one here wrote).

The file is ``hatire/opentrack-putty-capture.log`` in the fixtures folder: the
project's shared fixtures (``../shared/fixtures`` beside a worktree), or any folder
named by ``HOLO_FIXTURES``.  A plain clone has neither: the capture is opentrack's
``contrib/hatire-test-data/puttyLog1MIN.zip`` (unzipped; README, "Devices"), and the
tests that need it skip, saying so.
"""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
NAME = Path("hatire") / "opentrack-putty-capture.log"


def fixtures_dirs() -> list[Path]:
    """Folders searched, in order: ``$HOLO_FIXTURES``, ``../shared/fixtures``."""
    dirs = [Path(os.environ["HOLO_FIXTURES"])] if os.environ.get("HOLO_FIXTURES") else []
    return [*dirs, ROOT.parent / "shared" / "fixtures", Path("/work/shared/fixtures")]


def hatire_capture() -> Path:
    """The capture's path (the first folder that has it; the first candidate if none)."""
    found = [d / NAME for d in fixtures_dirs() if (d / NAME).is_file()]
    return found[0] if found else fixtures_dirs()[0] / NAME


#: The skip reason of a test that needs the capture.
MISSING = (
    f"real Hatire capture {NAME} not found in {', '.join(map(str, fixtures_dirs()))}: "
    "unzip opentrack's contrib/hatire-test-data/puttyLog1MIN.zip there, or set HOLO_FIXTURES"
)
