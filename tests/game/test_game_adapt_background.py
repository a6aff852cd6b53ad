"""``make demo`` measures and plays while the service's background compile is pending.

The demo (a real ``holo-service``, simulated devices and ``holo-game --adapt``)
runs on a copy of the session's numba cache without the warm stamp and without
the plain scatter kernel, so that after its first frame's jobs (loaded from the
copy) its background compile has a kernel to compile.  The test holds every cache
folder's save lock (:data:`service.numba_patches.CACHE_LOCK`), so that compile
cannot finish, nor could any kernel the demo needed and lacked (in the service,
its workers or the game): the game must choose its look, play every mode and a
game over with the background compile still pending, which it can because that
compile runs at idle priority.  ``stats.json`` says so.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterator
from pathlib import Path

import pytest
from testkit import copy_numba_cache

pytestmark = pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="Linux's SCHED_IDLE")


@contextlib.contextmanager
def saves_locked(cache: Path) -> Iterator[None]:
    """Hold every cache folder's save lock: no process can add a kernel to ``cache``."""
    import fcntl

    from service.numba_patches import CACHE_LOCK

    fds = []
    try:
        for folder in sorted({p.parent for p in cache.rglob("*.nbi")}):
            fds.append(os.open(folder / CACHE_LOCK, os.O_RDWR | os.O_CREAT, 0o644))
            fcntl.flock(fds[-1], fcntl.LOCK_EX)
        yield
    finally:
        for fd in fds:
            os.close(fd)


@pytest.mark.timeout(400)
def test_the_demo_chooses_its_look_and_plays_before_the_background_compile_ends(
        tmp_path, monkeypatch, capsys):
    from game.commands import make_demo
    from game.run_folders import read_latest
    from service.kernel_cache import stamp_path

    cache = tmp_path / "numba-cache"
    copy_numba_cache(cache)
    (cache / stamp_path().name).unlink(missing_ok=True)  # not warm: a background compile
    for path in cache.rglob("scatter_bands.scatter_bands_plain-*"):
        path.unlink()  # ... with a kernel to compile
    # every process of the demo (service, its workers, the game) uses the locked copy
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(cache))
    monkeypatch.setenv("HOLO_LOD_CACHE", str(tmp_path / "lod"))
    root = tmp_path / "demo-out"
    with saves_locked(cache):
        rc = make_demo.main(["--out", str(root), "--seconds", "9", "--gives-up", "1.5",
                             "--headless"])
    err = capsys.readouterr().err
    assert rc == 0, err
    run = read_latest(root)
    stats = json.loads((run / "stats.json").read_text())
    # every mode, the film and a game over (the shatter's scene) drawn: no kernel was
    # missing, or the locked cache would have held it back
    assert stats["modes"] == ["autostereogram", "head", "strip", "zone"]
    assert stats["scores"] and stats["renders"] > 3
    for name in ("mode-zone.png", "mode-autostereogram.png", "film.png", "gameover.png"):
        assert (run / name).stat().st_size > 1000
    look = stats["look"]
    assert look["adapted"] and look["measured"]
    bg = look["background_compile"]
    assert bg["phase"] == "compiling" and bg["priority"] == "idle", bg
    assert bg["done"] < bg["total"], bg
    assert "background compile" in look["reason"] and "idle priority" in look["reason"]
    assert "in the background (idle CPU only)" in err
    assert "measuring once it is done" not in err  # the game never waited for it
    assert "background compile done" not in err  # it could not end: the saves were locked


def _choice():
    from game.adapt import LADDER, Choice

    return Choice(LADDER[0], ((LADDER[0], 20.0),), True, "blinn 240x180: 20.0 renders/s")


@pytest.mark.parametrize(("background", "said"), [
    (None, None),
    ({"phase": "none", "done": 0, "total": 0}, None),
    ({"phase": "compiling", "done": 3, "total": 23, "priority": "idle"},
     "measured beside the service's background compile (3 of 23 jobs) at idle priority"),
    ({"phase": "compiling", "done": 3, "total": 23, "priority": "nice 10"},
     "measured beside the service's background compile (3 of 23 jobs) at nice 10"),
    ({"phase": "done", "done": 23, "total": 23, "priority": "idle"},
     "the service's background compile had ended (done)"),
])
def test_the_choice_says_what_compiled_beside_the_measurement(background, said):
    from game.adapt import with_background

    choice = with_background(_choice(), background)
    out = choice.as_dict()
    if said is None:
        assert choice == _choice() and "background_compile" not in out
    else:
        assert said in out["reason"] and out["reason"].startswith(_choice().reason)
        assert out["background_compile"] == background
