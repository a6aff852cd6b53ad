"""One folder per demo run, never deleting an earlier one, and ``latest`` pointing at it.

``make demo`` writes into ``demo-out/<time>/`` (:func:`new_run_folder`, e.g.
``demo-out/20261128-173005/``; a second run in the same second gets ``-2``), and
``demo-out/latest`` names the newest run (:func:`point_latest`): a symbolic link where
the file system has them, else a one-line text file holding the folder's name.  The
link is replaced atomically (a temporary link, then ``os.replace``), so a reader
never finds it missing.  Nothing in the root folder is ever removed.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from service.base.errors import HoloError

#: The name of the pointer at the newest run in the root folder.
LATEST = "latest"
#: The run folder's name: the local time the run started (sorts in time order).
STAMP = "%Y%m%d-%H%M%S"


class RunFolderError(HoloError):
    """A run folder or the ``latest`` pointer could not be made."""


def new_run_folder(root: str | Path, when: float | None = None) -> Path:
    """Make ``root/<time>`` (or ``<time>-2``, ``-3``... when taken); returns it.

    Parameters
    ----------
    root : str or Path
        Made (with its parents) when missing.
    when : float, optional
        Seconds since the epoch (default now).

    Raises
    ------
    RunFolderError
        ``root`` is not a folder that can be written.
    """
    root = Path(root)
    stamp = time.strftime(STAMP, time.localtime(time.time() if when is None else when))
    try:
        root.mkdir(parents=True, exist_ok=True)
        for n in range(1, 1000):
            folder = root / (stamp if n == 1 else f"{stamp}-{n}")
            try:
                folder.mkdir()
            except FileExistsError:
                continue
            return folder
    except OSError as exc:
        raise RunFolderError(f"cannot make a run folder in {root}/: {exc.strerror or exc}") from exc
    raise RunFolderError(f"{root}/ already has 999 runs started at {stamp}")


def point_latest(root: str | Path, folder: Path) -> Path:
    """Make ``root/latest`` name ``folder`` (a relative link, or a file where links fail).

    Returns
    -------
    Path
        ``root/latest``.

    Raises
    ------
    RunFolderError
        ``latest`` exists as a folder (it is left alone), or cannot be written.
    """
    root = Path(root)
    latest, temp = root / LATEST, root / f".{LATEST}.{os.getpid()}"
    if latest.is_dir() and not latest.is_symlink():
        raise RunFolderError(f"{latest} is a folder, not the demo's pointer: left as it is")
    try:
        temp.unlink(missing_ok=True)
        try:
            temp.symlink_to(folder.name, target_is_directory=True)
        except OSError:  # a file system without links (some network or FAT drives)
            temp.write_text(folder.name + "\n")
        os.replace(temp, latest)
    except OSError as exc:
        temp.unlink(missing_ok=True)
        raise RunFolderError(f"cannot point {latest} at {folder.name}: "
                             f"{exc.strerror or exc}") from exc
    return latest


def read_latest(root: str | Path) -> Path | None:
    """The folder ``root/latest`` names (link or file), None when there is none."""
    latest = Path(root) / LATEST
    if latest.is_symlink():
        return Path(root) / os.readlink(latest)
    if latest.is_file():
        return Path(root) / latest.read_text().strip()
    return None
