"""Level-of-detail builds that fail: reported once, retried only when it may pass, nothing lost.

Where it can fail: a failure that is silent, reported every frame, or retried for ever;
a transient one (the build process killed, a full disk) never retried; a frame that
draws anything but the full mesh while its chain is missing; a build without a cache
folder run in the rendering process (its GIL stalls renders).

Every build here is a real child process (``python -m service.lod.builds``).  Faults
come from outside it: its environment (a ``fast_simplification`` module that cannot
be imported, or whose import raises OSError, put first on its ``PYTHONPATH``), a
signal, a cache path that is a file.  A build is held back by holding its lock file,
as another process building that chain would; nothing sleeps or races a timer.
"""

import os
import signal
import tempfile

import numpy as np
import pytest
from testkit import held_lock, posix_only, wait_until

from service.display import DisplaySettings
from service.lod.builds import ChainBuilds
from service.lod.chain import mesh_key
from service.lod.settings import LodSettings
from service.lod.state import LodState
from service.primitives import torus
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import Scene, SceneObject, Transform

DISPLAY = DisplaySettings(zones=2, cols=48, rows=32)
LOD = RenderSettings(lod=LodSettings(error_px=0.5))
WAIT_S = 120  # a build child starts and builds the small torus in ~1 s quiet
NO_WAIT = (0.0, 0.0)  # retries at once: the tests wait on conditions, not back-offs


@pytest.fixture(scope="module")
def ring():
    return torus(0.5, 0.15, 24, 12)


@pytest.fixture(scope="module")
def exact(ring):
    return Renderer().render(_scene(ring), DISPLAY, RenderSettings())  # LOD off


def _scene(mesh):
    return Scene([SceneObject(mesh, transform=Transform(np.array([x, 0.0, -2.0]), scale=0.4),
                              name=f"o{i}") for i, x in enumerate((-0.5, 0.5))])


def _renderer(cache, retry_s=NO_WAIT):
    r = Renderer()
    r.lod = LodState(cache=cache, background=True)
    r.lod.builds = ChainBuilds(cache, retry_s=retry_s)
    return r


def _shadow(tmp_path, monkeypatch, body):
    """Put a ``fast_simplification`` whose import runs ``body`` first on the children's path."""
    shadow = tmp_path / "shadow"
    shadow.mkdir()
    (shadow / "fast_simplification.py").write_text(body)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(
        [str(shadow), *filter(None, [os.environ.get("PYTHONPATH")])]))


def _frame_is_full(frame, exact):
    lod = frame.stats["lod"]
    assert lod["levels"] == [0, 0] and lod["triangles"] == lod["triangles_full"]
    np.testing.assert_array_equal(frame.colour, exact.colour)
    np.testing.assert_array_equal(frame.depth, exact.depth)
    return lod


def _new_child(builds, seen):
    """Wait for a build child not in ``seen``; its pid."""
    pid = wait_until(lambda: builds.child_pid not in (None, *seen) and builds.child_pid, WAIT_S)
    assert pid, f"no new build process (seen {seen})"
    return pid


@pytest.mark.parametrize("cache", ["folder", "none"])
def test_a_mesh_that_cannot_be_simplified_fails_once_and_is_drawn_in_full(
        ring, exact, tmp_path, monkeypatch, cache):
    # "none": had the build run in this process (a thread) it would have used the
    # simplifier this process already imported, and succeeded
    _shadow(tmp_path, monkeypatch, "raise ImportError('simplifier left out of this build')\n")
    folder = tmp_path / "cache" if cache == "folder" else False
    scene, renderer = _scene(ring), _renderer(folder)
    _frame_is_full(renderer.render(scene, DISPLAY, LOD), exact)
    assert renderer.lod.builds.wait_idle(WAIT_S)
    for _ in range(3):  # later frames: still the full mesh, and no build started again
        lod = _frame_is_full(renderer.render(scene, DISPLAY, LOD), exact)
        assert lod["chains"]["failed"] == 1 and lod["chains"]["ready"] == 0
        assert not renderer.lod.builds.building(mesh_key(ring, LodSettings().recipe))
    (note,) = lod["chains"]["notes"]  # reported once, in one line, with the reason
    assert "\n" not in note and "not built" in note and "simplifier left out" in note
    assert "after" not in note  # deterministic: tried once
    assert renderer.lod.builds.generation == 1
    (why,) = renderer.lod.builds.failed.values()
    assert "quadric simplifier" in why


@posix_only
def test_a_build_killed_mid_way_is_tried_again_and_its_chain_used(ring, exact, tmp_path):
    scene, renderer = _scene(ring), _renderer(tmp_path)
    builds = renderer.lod.builds
    with held_lock(tmp_path, mesh_key(ring, LodSettings().recipe)):
        _frame_is_full(renderer.render(scene, DISPLAY, LOD), exact)
        first = _new_child(builds, ())
        os.kill(first, signal.SIGKILL)
        _new_child(builds, (first,))  # tried again; it waits for the lock as the first did
        lod = _frame_is_full(renderer.render(scene, DISPLAY, LOD), exact)
        assert lod["chains"] == {"ready": 0, "building": 1, "failed": 0,
                                 "notes": lod["chains"]["notes"]}
        (note,) = lod["chains"]["notes"]
        assert "killed (SIGKILL)" in note and "trying again" in note and "try 2 of 3" in note
    assert builds.wait_idle(WAIT_S)
    lod = renderer.render(scene, DISPLAY, LOD).stats["lod"]
    assert lod["chains"]["ready"] == 1 and lod["chains"]["failed"] == 0
    assert min(lod["levels"]) > 0 and lod["triangles"] < lod["triangles_full"]


@posix_only
def test_a_build_killed_every_time_is_given_up_after_its_tries(ring, exact, tmp_path):
    scene, renderer = _scene(ring), _renderer(tmp_path, retry_s=(0.0,))
    builds = renderer.lod.builds
    with held_lock(tmp_path, mesh_key(ring, LodSettings().recipe)):
        renderer.render(scene, DISPLAY, LOD)
        seen: tuple = ()
        for _ in range(2):
            seen += (_new_child(builds, seen),)
            os.kill(seen[-1], signal.SIGKILL)
        assert builds.wait_idle(WAIT_S)
    lod = _frame_is_full(renderer.render(scene, DISPLAY, LOD), exact)
    assert lod["chains"]["failed"] == 1
    retry, given_up = lod["chains"]["notes"]
    assert "trying again" in retry
    assert "not built after 2 tries" in given_up and "SIGKILL" in given_up
    assert builds.child_pid is None and not builds.building(mesh_key(ring, LodSettings().recipe))


def test_a_failure_that_may_pass_is_retried_a_bounded_number_of_times(
        ring, exact, tmp_path, monkeypatch):
    _shadow(tmp_path, monkeypatch, "raise OSError(28, 'No space left on device')\n")
    scene, renderer = _scene(ring), _renderer(tmp_path / "cache")
    renderer.render(scene, DISPLAY, LOD)
    assert renderer.lod.builds.wait_idle(WAIT_S)
    lod = _frame_is_full(renderer.render(scene, DISPLAY, LOD), exact)
    assert lod["chains"]["failed"] == 1
    *retries, given_up = lod["chains"]["notes"]
    assert [("try 2 of 3" in retries[0]), ("try 3 of 3" in retries[1])] == [True, True]
    assert "not built after 3 tries" in given_up and "No space left on device" in given_up
    assert renderer.lod.builds.generation == 3


def test_without_a_cache_the_chain_is_built_in_a_child_and_nothing_is_left(
        ring, tmp_path, monkeypatch):
    monkeypatch.setenv("HOLO_LOD_CACHE", str(tmp_path / "user-cache"))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    scene, renderer = _scene(ring), _renderer(False)
    renderer.render(scene, DISPLAY, LOD)
    assert renderer.lod.builds.wait_idle(WAIT_S)
    lod = renderer.render(scene, DISPLAY, LOD).stats["lod"]
    assert lod["chains"] == {"ready": 1, "building": 0, "failed": 0}
    assert min(lod["levels"]) > 0
    assert not (tmp_path / "user-cache").exists()  # nothing cached
    assert not list(tmp_path.glob("holo-lod-*"))  # the hand-over folder is gone


def test_a_cache_path_that_cannot_be_a_folder_is_reported_and_the_chain_still_built(
        ring, tmp_path):
    blocked = tmp_path / "not-a-folder"
    blocked.write_text("a file where the cache folder should be")
    scene, renderer = _scene(ring), _renderer(blocked)
    renderer.render(scene, DISPLAY, LOD)
    assert renderer.lod.builds.wait_idle(WAIT_S)
    lod = renderer.render(scene, DISPLAY, LOD).stats["lod"]
    assert lod["chains"]["ready"] == 1 and min(lod["levels"]) > 0
    (note,) = lod["chains"]["notes"]
    assert "cache not written" in note and str(blocked) in note
    assert blocked.read_text().startswith("a file")  # untouched


def test_closing_ends_a_running_build(ring, tmp_path):
    renderer = _renderer(tmp_path)
    builds = renderer.lod.builds
    with held_lock(tmp_path, mesh_key(ring, LodSettings().recipe)):
        renderer.render(_scene(ring), DISPLAY, LOD)
        pid = _new_child(builds, ())
        builds.close()
        assert not builds.building(mesh_key(ring, LodSettings().recipe))
    assert builds.child_pid is None
    with pytest.raises(ProcessLookupError):  # ended and reaped
        os.kill(pid, 0)
