"""Write a run's files beside its output folder, then move them into place at the end.

``holo-bench report`` runs for minutes; an interrupted run must leave the previous
page and its data together.  So the run writes into a *staging* folder beside the
output folder (same parent, so the same file system and a rename is a move), and
only when everything is written does :func:`move_into_place` swap the report's own
entries (the page, ``report.json``, one folder per benchmark) into the output
folder.  Files of the output folder that are not the report's (a chart of a
benchmark run by hand into the same ``bench-out``) stay.

The swap is a handful of renames in one folder, with SIGINT and SIGTERM held back
until it is done, so Ctrl-C cannot split it; only a power cut or SIGKILL inside
those milliseconds could.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

#: The file in which a report names its entries (the previous run's are replaced).
MANIFEST = "report.json"
#: Entries every report writes beside its benchmark folders.
PAGE_FILES = ("index.html", MANIFEST)


def staging_folder(out: Path) -> Path:
    """A new empty folder beside ``out``: ``OUT.partial-YYYYmmdd-HHMMSS[-N]``.

    Its parent (``out``'s) is made if missing.  Left in place (with what was written)
    when the run does not finish, so nothing is lost; the caller names it.
    """
    out.parent.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    for n in range(1000):
        work = out.with_name(f"{out.name}.partial-{stamp}" + (f"-{n}" if n else ""))
        with contextlib.suppress(FileExistsError):
            work.mkdir()
            return work
    raise FileExistsError(f"{out}.partial-{stamp}: 1000 staging folders already exist")


def owned_entries(out: Path) -> set[str]:
    """Names in ``out`` a previous report wrote: its page, manifest and benchmark folders.

    A manifest that cannot be read names only the page files.
    """
    names = set(PAGE_FILES)
    with contextlib.suppress(OSError, ValueError, AttributeError):
        names |= set(json.loads((out / MANIFEST).read_text()).get("benches", {}))
    return {n for n in names if n and "/" not in n and n not in (".", "..")}


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM wait until the block is done (where the platform allows)."""
    mask = getattr(signal, "pthread_sigmask", None)
    held = {signal.SIGINT, signal.SIGTERM}
    if mask is None:
        yield
        return
    old = mask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        mask(signal.SIG_SETMASK, old)


def move_into_place(work: Path, out: Path, replaced: Iterable[str] = ()) -> None:
    """Swap the entries of ``work`` into ``out``; ``work`` is removed after.

    Parameters
    ----------
    work : Path
        The finished staging folder (from :func:`staging_folder`).
    out : Path
        The output folder (made if missing).
    replaced : iterable of str
        Names in ``out`` that belong to the previous run (:func:`owned_entries`):
        they go even when this run did not write them again, so the folder holds
        one run's page and data.  Entries of ``work`` replace their namesakes too.
    """
    out.mkdir(parents=True, exist_ok=True)
    new = sorted(p.name for p in work.iterdir())
    trash = work / ".replaced"
    with signals_held():
        trash.mkdir()
        for name in sorted(set(replaced) | set(new)):
            if os.path.lexists(out / name):
                os.replace(out / name, trash / name)
        for name in new:
            os.replace(work / name, out / name)
    shutil.rmtree(work)
