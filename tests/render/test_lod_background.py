"""Level-of-detail chains built off the render path (``LodState(background=True)``).

Where it can fail: a frame that waits for a chain, a frame that draws anything but the
full mesh before the chain exists, a chain that never arrives, hysteresis carried over
from the stand-in, a damaged or torn cache file that is silently ignored or fatal.

A build is held back deterministically by holding its lock file, as another process
building the same chain would: nothing here sleeps or races a timer.
"""


import numpy as np
import pytest
from testkit import held_lock

from service.display import DisplaySettings
from service.engine.engine import Engine
from service.frame_settings import FrameSettings
from service.lod.builds import ChainBuilds
from service.lod.cache import build_chain, read_chain
from service.lod.chain import mesh_key
from service.lod.settings import LodCacheWarning, LodSettings
from service.lod.state import LodState
from service.primitives import torus
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import Scene, SceneObject, Transform

DISPLAY = DisplaySettings(zones=3, cols=64, rows=48)
LOD = RenderSettings(lod=LodSettings(error_px=0.5))
WAIT_S = 120  # a chain of the 2,300-triangle torus builds in well under a second quiet


@pytest.fixture(scope="module")
def ring():
    return torus(0.5, 0.15, 48, 24)


def _scene(mesh):
    places = [(-0.5, 0.0, 0.4), (0.5, 0.0, 0.25)]
    return Scene([SceneObject(mesh, transform=Transform(np.array([x, y, -2.0]), scale=s),
                              name=f"o{i}") for i, (x, y, s) in enumerate(places)])


def _renderer(cache):
    r = Renderer()
    r.lod = LodState(cache=cache, background=True)
    return r


def test_frames_draw_the_full_mesh_until_the_chain_is_built_then_use_it(ring, tmp_path):
    scene, renderer = _scene(ring), _renderer(tmp_path)
    exact = Renderer().render(scene, DISPLAY, RenderSettings())  # level of detail off
    with held_lock(tmp_path, mesh_key(ring, LodSettings().recipe)):
        for _ in range(2):  # neither frame waits for the build the lock holds back
            frame = renderer.render(scene, DISPLAY, LOD)
            lod = frame.stats["lod"]
            assert lod["chains"] == {"ready": 0, "building": 1, "failed": 0}
            assert lod["levels"] == [0, 0] and lod["triangles"] == lod["triangles_full"]
            np.testing.assert_array_equal(frame.colour, exact.colour)  # pixels: exact
            np.testing.assert_array_equal(frame.depth, exact.depth)
    assert renderer.lod.builds.wait_idle(WAIT_S)
    lod = renderer.render(scene, DISPLAY, LOD).stats["lod"]
    assert lod["chains"] == {"ready": 1, "building": 0, "failed": 0}
    # as a renderer that had the chain from the start would choose (no hysteresis
    # carried over from the stand-in)
    cold = Renderer()
    cold.lod = LodState(cache=tmp_path)
    assert lod["levels"] == cold.render(scene, DISPLAY, LOD).stats["lod"]["levels"]
    assert min(lod["levels"]) > 0 and lod["triangles"] < lod["triangles_full"]
    assert read_chain(tmp_path, mesh_key(ring, LodSettings().recipe), ring) is not None


def test_a_cached_chain_is_used_from_the_first_frame(ring, tmp_path):
    build_chain(ring, cache=tmp_path)
    lod = _renderer(tmp_path).render(_scene(ring), DISPLAY, LOD).stats["lod"]
    assert lod["chains"]["ready"] == 1 and min(lod["levels"]) > 0


@pytest.mark.parametrize("damage", ["truncate-npz", "no-header"])
def test_a_damaged_cache_is_reported_and_rebuilt_in_the_background(ring, tmp_path, damage):
    chain = build_chain(ring, cache=tmp_path)
    npz, js = tmp_path / f"{chain.key}.npz", tmp_path / f"{chain.key}.json"
    if damage == "truncate-npz":
        npz.write_bytes(npz.read_bytes()[:200])
    else:  # torn: the header (written last) never arrived
        js.unlink()
    scene, renderer = _scene(ring), _renderer(tmp_path)
    first = renderer.render(scene, DISPLAY, LOD).stats["lod"]
    assert first["levels"] == [0, 0]  # the full mesh, not a guess from a broken file
    assert renderer.lod.builds.wait_idle(WAIT_S)
    lod = renderer.render(scene, DISPLAY, LOD).stats["lod"]
    assert lod["chains"]["ready"] == 1 and min(lod["levels"]) > 0
    (note,) = lod["chains"]["notes"]
    assert chain.key in note and "damaged" in note and "rebuilding" in note
    assert read_chain(tmp_path, chain.key, ring) is not None  # rewritten whole


def test_a_torn_cache_warns_where_the_chain_is_built_in_the_frame(ring, tmp_path):
    chain = build_chain(ring, cache=tmp_path)
    (tmp_path / f"{chain.key}.json").unlink()
    with pytest.warns(LodCacheWarning, match=r"damaged \(.*json is missing\); rebuilding"):
        again = build_chain(ring, cache=tmp_path)
    assert again.build_ms > 0 and len(again.levels) == len(chain.levels)
    assert build_chain(ring, cache=tmp_path).build_ms == 0.0


def test_another_recipe_gets_its_own_chain(ring, tmp_path):
    state = LodState(cache=tmp_path)
    for recipe in (LodSettings(), LodSettings(fractions=(0.5,))):
        state.prepare(_scene(ring), recipe)
    assert state.wait(WAIT_S)
    full = state.chain(ring, LodSettings())
    half = state.chain(ring, LodSettings(fractions=(0.5,)))
    assert full.key != half.key and len(half.levels) == 2 < len(full.levels)
    assert state.chain(ring, LodSettings()).key == full.key


def test_a_loaded_scene_queues_its_chains_before_any_frame(ring, tmp_path, monkeypatch):
    """The engine's ``load_scene`` (the game's, and the service's handlers) starts builds.

    No frame is rendered until the chain is built: the build is the load's, not a
    frame's.  ``chains`` status says which mesh is building; a mesh two objects share
    is queued once, and loading the same scene again queues nothing.
    """
    monkeypatch.setenv("HOLO_LOD_CACHE", str(tmp_path))
    engine = Engine.local(FrameSettings(DISPLAY, LOD))  # threads not started: no frames
    scene, key = _scene(ring), mesh_key(ring, LodSettings().recipe)
    try:
        with held_lock(tmp_path, key):
            engine.load_scene(scene)
            status = engine.st.chains.status()
            assert status["queued"] + (status["building"] is not None) == 1
            assert engine.st.queue_chains() == 0  # known: not queued twice
        assert engine.st.chains.wait_idle(WAIT_S)
        status = engine.st.chains.status()
        assert status["built"] == 1 and status["building"] is None and status["failed"] == 0
        assert (tmp_path / f"{key}.json").is_file()
        assert engine.st.queue_chains() == 0  # cached: nothing to build
        lod = engine.scheduler.local().render(scene, DISPLAY, LOD).stats["lod"]
        assert lod["chains"] == {"ready": 1, "building": 0, "failed": 0}
        assert max(lod["levels"]) > 0  # the first frame already uses the chain
    finally:
        engine.stop()


def test_build_progress_is_followed_from_the_build_process(ring, tmp_path):
    """Each decimation the child reports reaches ``on_progress`` and ``status``."""
    builds, heard = ChainBuilds(tmp_path), []
    builds.on_progress = lambda name, done, planned: heard.append((name, done, planned))
    assert builds.submit_scene(_scene(ring), LodSettings()) == 1
    assert builds.wait_idle(WAIT_S)
    builds.close()
    assert heard[0] == (ring.name or "a mesh", 0, 0)  # started
    done = [d for _, d, n in heard[1:]]
    assert done == sorted(done) and done[-1] == heard[-1][2] >= 1  # every decimation
    assert builds.status()["built"] == 1 and builds.status()["progress"] is None


def test_a_bare_renderer_never_builds_a_chain_in_its_frame(ring, tmp_path, monkeypatch):
    """``Renderer()`` with nothing set: frames draw the full mesh while the chain builds
    in a child process; nothing in this process builds one; ``prepare`` waits for it.

    The build is held back by its lock file, so the frames provably did not wait for it.
    """
    import service.lod.cache
    import service.lod.state

    def no_build_here(*args, **kwargs):
        raise AssertionError("a chain was built in the rendering process")

    monkeypatch.setattr(service.lod.state, "build_chain", no_build_here)
    monkeypatch.setattr(service.lod.cache, "build_chain", no_build_here)
    monkeypatch.setenv("HOLO_LOD_CACHE", str(tmp_path))
    scene, renderer, key = _scene(ring), Renderer(), mesh_key(ring, LodSettings().recipe)
    exact = Renderer().render(scene, DISPLAY, RenderSettings())  # level of detail off
    with held_lock(tmp_path, key):
        for _ in range(2):
            frame = renderer.render(scene, DISPLAY, LOD)
            assert renderer.lod.builds.building(key)  # the frame returned mid-build
            lod = frame.stats["lod"]
            assert lod["chains"] == {"ready": 0, "building": 1, "failed": 0}
            assert lod["levels"] == [0, 0]
            np.testing.assert_array_equal(frame.colour, exact.colour)
        assert not renderer.prepare(scene, LOD.lod, timeout_s=0.0)  # still building
    assert renderer.prepare(scene, LOD.lod, timeout_s=WAIT_S)
    lod = renderer.render(scene, DISPLAY, LOD).stats["lod"]
    assert lod["chains"]["ready"] == 1 and min(lod["levels"]) > 0


def test_without_background_prepare_builds_here_and_a_frame_never(ring, tmp_path):
    """``LodState(background=False)`` (the warm-up job): ``prepare`` builds in this process;
    a mesh it did not prepare is drawn in full, with a note, and not built by the frame."""
    renderer = Renderer()
    renderer.lod = LodState(cache=tmp_path, background=False)
    scene = _scene(ring)
    lod = renderer.render(scene, DISPLAY, LOD).stats["lod"]
    assert lod["levels"] == [0, 0] and lod["triangles"] == lod["triangles_full"]
    assert "not prepared" in lod["chains"]["notes"][-1]
    assert not list(tmp_path.iterdir()) and renderer.lod.builds is None  # nothing built
    assert renderer.lod.prepare(scene, LOD.lod) == 1
    assert renderer.lod.prepare(scene, LOD.lod) == 0  # in memory now
    lod = renderer.render(scene, DISPLAY, LOD).stats["lod"]
    assert lod["chains"]["ready"] == 1 and min(lod["levels"]) > 0
