"""The LOD cache keeps no ``<key>.lock`` files, and removing them races with no builder.

A builder removes its lock file while it still holds it; a process that opened the
file before that and got the lock after must notice that the path no longer names
its file and lock the one there now, or two builders would hold "the" lock at once.
"""

from __future__ import annotations

import fcntl
import os
import sys
import threading
from pathlib import Path

import pytest
from testkit import held_lock, wait_for

from service.lod.cache import _build_lock, build_chain, write_chain
from service.lod.chain import mesh_key
from service.lod.settings import LodSettings
from service.primitives import torus

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="flock and /proc/locks (Linux)")


@pytest.fixture(scope="module")
def ring():
    return torus(0.5, 0.15, 16, 8)


def locks(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.glob("*.lock"))


def blocked_on(path: Path) -> bool:
    """Whether some process waits for a flock on the file at ``path`` (/proc/locks)."""
    inode = os.stat(path).st_ino
    for line in Path("/proc/locks").read_text().splitlines():
        fields = line.split()
        if "->" in fields and "FLOCK" in fields and any(
                f.endswith(f":{inode}") for f in fields):
            return True
    return False


def test_a_build_leaves_no_lock_file(ring, tmp_path):
    chain = build_chain(ring, cache=tmp_path)
    assert chain.build_ms > 0 and (tmp_path / f"{chain.key}.json").is_file()
    assert locks(tmp_path) == []


def test_a_stale_lock_beside_a_cached_chain_is_removed_unless_held(ring, tmp_path):
    key = build_chain(ring, cache=tmp_path).key
    with held_lock(tmp_path, key):  # a process building it now: its file stays
        assert build_chain(ring, cache=tmp_path).build_ms == 0.0
        assert locks(tmp_path) == [f"{key}.lock"]
    # a file a dead builder (or an older version) left: the next reader removes it
    assert build_chain(ring, cache=tmp_path).build_ms == 0.0
    assert locks(tmp_path) == []


def test_a_waiter_ends_up_holding_the_file_at_the_path(ring, tmp_path):
    key = mesh_key(ring, LodSettings().recipe)
    path = tmp_path / f"{key}.lock"
    inside, leave = threading.Event(), threading.Event()
    seen: list[bool] = []

    def second_builder() -> None:
        with _build_lock(tmp_path, key):
            inside.set()
            leave.wait(30)

    with _build_lock(tmp_path, key):
        waiter = threading.Thread(target=second_builder, daemon=True)
        waiter.start()
        wait_for(lambda: blocked_on(path), 30, "the second builder waiting for the lock")
    # the first removed its file; the second must now hold the file at the path
    wait_for(inside.is_set, 30, "the second builder getting the lock")
    try:
        with open(path, "ab") as third:
            with pytest.raises(BlockingIOError):
                fcntl.flock(third, fcntl.LOCK_EX | fcntl.LOCK_NB)
            seen.append(True)
    finally:
        leave.set()
        waiter.join(30)
    assert seen == [True] and locks(tmp_path) == []


def test_a_chain_built_while_waiting_for_the_lock_is_read_not_built(ring, tmp_path):
    key = mesh_key(ring, LodSettings().recipe)
    got: list = []
    waiter = threading.Thread(target=lambda: got.append(build_chain(ring, cache=tmp_path)),
                              daemon=True)
    with _build_lock(tmp_path, key):
        waiter.start()
        wait_for(lambda: blocked_on(tmp_path / f"{key}.lock"), 30,
                 "the builder waiting for the lock")
        write_chain(tmp_path, build_chain(ring, cache=False))  # another process's build
    waiter.join(30)
    assert len(got) == 1 and got[0].build_ms == 0.0 and got[0].key == key
    assert locks(tmp_path) == []


def test_no_cache_builds_and_writes_nothing(ring, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    chain = build_chain(ring, cache=False)
    assert chain.build_ms > 0 and len(chain.levels) > 1
    assert list(tmp_path.iterdir()) == []
