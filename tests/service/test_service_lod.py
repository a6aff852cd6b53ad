"""Level of detail in the render service: ``--lod-error`` and ``set_display`` ``lod_error``.

Chains are built in the background of the renderer that needs them (the worker, or the
service's render thread): renders draw full meshes until then, and no render waits.
"""

from __future__ import annotations

import fcntl
import os

import pytest
from testkit import HANG_S, shared_fixture, wait_until

from service.base.errors import ServiceError
from service.loaders import load_scene
from service.lod.chain import mesh_key
from service.lod.settings import LodSettings
from service.net.client import ServiceClient

BUNNY = shared_fixture("meshes/bunny.ply")
#: how long a chain may take to build on a loaded 2-core machine (the bunny: ~2 s quiet)
CHAIN_S = 120


def _chains_built(c: ServiceClient) -> dict | None:
    """The LOD report of a fresh render once every chain of the scene is built."""
    lod = c.render_once()[0]["stats"]["lod"]
    return lod if lod["chains"]["building"] == 0 else None


def test_lod_error_turns_level_of_detail_on_and_off(service_factory, tmp_path, monkeypatch):
    monkeypatch.setenv("HOLO_LOD_CACHE", str(tmp_path))
    svc = service_factory(
        "--scene", "game", "--zones", "3", "--size", "32x24",
        "--workers", "0", "--refresh", "30", "--lod-error", "0.5", "--lod-colour", "2",
    )  # fmt: skip
    with ServiceClient(svc.control, timeout_s=30) as c:
        header, _ = c.render_once()
        lod = header["stats"]["lod"]
        assert lod["error_px"] == 0.5 and len(lod["levels"]) == len(lod["predicted_px"]) == 7
        assert lod["colour_pct"] == 2.0  # --lod-colour
        assert c.set_display(lod_colour_pct=None)["lod_colour_pct"] is None  # not counted
        assert c.render_once()[0]["stats"]["lod"]["colour_pct"] is None
        with pytest.raises(ServiceError, match="lod_colour_pct"):
            c.set_display(lod_colour_pct=-1)
        assert c.set_display(lod_colour_pct=0.5)["lod_colour_pct"] == 0.5
        assert all(p <= 0.5 for p in lod["predicted_px"])
        polled = c.stats()["lod"]  # the last finished render's levels, without a render
        assert polled["render_id"] >= header["render_id"] and len(polled["levels"]) == 7
        assert c.set_display(lod_error=0.0)["lod_error"] == 0.0
        assert "lod" not in c.render_once()[0]["stats"]
        assert c.stats()["lod"] is None
        with pytest.raises(ServiceError) as info:
            c.set_display(lod_error=-1)
        assert info.value.code == "bad_message" and "lod_error" in str(info.value)


#: A ``fast_simplification`` that cannot be imported in a level-of-detail build process
#: (and is the real one everywhere else: the service's warm-up decimates too).
NO_SIMPLIFIER_IN_BUILDS = """
import importlib, os, sys
main = getattr(sys.modules.get("__main__"), "__spec__", None)
if main is not None and main.name == "service.lod.builds":
    raise ImportError("simplifier left out of the build process")
here = os.path.dirname(os.path.abspath(__file__))
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != here]
del sys.modules[__name__]
sys.modules[__name__] = importlib.import_module(__name__)
"""


def test_chains_that_cannot_be_built_are_reported_and_drawn_in_full(
        service_factory, tmp_path, monkeypatch):
    """Builds that fail for good: each said once, counted ``failed``; renders go on in full."""
    shadow = tmp_path / "shadow"
    shadow.mkdir()
    (shadow / "fast_simplification.py").write_text(NO_SIMPLIFIER_IN_BUILDS)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(
        [str(shadow), *filter(None, [os.environ.get("PYTHONPATH")])]))
    monkeypatch.setenv("HOLO_LOD_CACHE", str(tmp_path / "cache"))
    svc = service_factory(
        "--scene", "game", "--zones", "3", "--size", "32x24",
        "--workers", "0", "--refresh", "30", "--lod-error", "0.5",
    )  # fmt: skip
    with ServiceClient(svc.control, timeout_s=30) as c:
        lod = wait_until(lambda: _chains_built(c), CHAIN_S)
        assert lod, "the builds never ended"
        chains = lod["chains"]
        assert chains["ready"] == 0 and chains["failed"] >= 1, chains
        assert len(chains["notes"]) == min(chains["failed"], 4)  # one line each, no repeats
        for note in chains["notes"]:
            assert "not built" in note and "simplifier left out" in note and "after" not in note
        assert lod["levels"] == [0] * 7 and lod["triangles"] == lod["triangles_full"]
        again = c.render_once()[0]["stats"]["lod"]  # nothing tried again, nothing added
        assert again["chains"] == chains
        assert c.stats()["render_failures"] == 0
        for note in chains["notes"]:  # and the service's log has each once, in one line
            assert svc.output().count(note) == 1, svc.output()[-2000:]
            assert f"holo-service: {note}\n" in svc.output()
    assert not list((tmp_path / "cache").glob("*.json"))


def test_a_time_budget_degrades_through_the_measured_cost_model(service_factory, tmp_path,
                                                                 monkeypatch):
    """``--budget-ms`` (and ``set_display`` ``lod_budget_ms``) through a real service.

    A budget far under any render's cost: from the second render on (the first has
    nothing measured) every object is at its coarsest level, past the error budget,
    and the stats carry the cost model the renders measured and its prediction.
    """
    monkeypatch.setenv("HOLO_LOD_CACHE", str(tmp_path))
    svc = service_factory(
        "--scene", "game", "--zones", "3", "--size", "32x24",
        "--workers", "0", "--refresh", "30", "--budget-ms", "0.001",
    )  # fmt: skip
    with ServiceClient(svc.control, timeout_s=30) as c:
        assert wait_until(lambda: _chains_built(c), CHAIN_S)
        lods = [c.render_once()[0]["stats"]["lod"] for _ in range(3)]
        last = lods[-1]
        assert last["error_px"] == 0.5 and last["budget_ms"] == 0.001  # alone: LOD on
        assert last["cost_model"]["frames"] >= 1 and last["predicted_ms"] > 0.001
        assert last["over_error"] >= 1 and last["triangles"] < last["triangles_full"]
        assert len(last["levels"]) == len(last["predicted_px"]) == 7
        assert last["triangles"] <= min(x["triangles"] for x in lods)
        shown = c.set_display(lod_budget_ms=0.0, lod_error=0.5)
        assert shown["lod_budget_ms"] == 0.0 and shown["lod_error"] == 0.5
        free = c.render_once()[0]["stats"]["lod"]
        assert "budget_ms" not in free and free["over_error"] == 0
        assert all(p <= 0.5 for p in free["predicted_px"])
        assert c.set_display(lod_budget_ms=25)["lod_budget_ms"] == 25
        assert c.render_once()[0]["stats"]["lod"]["budget_ms"] == 25
        with pytest.raises(ServiceError) as info:
            c.set_display(lod_budget_ms=-1)
        assert info.value.code == "bad_message" and "lod_budget_ms" in str(info.value)


@pytest.mark.skipif(not BUNNY.is_file(), reason=f"needs the bunny fixture ({BUNNY})")
def test_a_new_mesh_renders_within_the_timeout_and_uses_its_chain_once_built(
        service_factory, tmp_path, monkeypatch):
    """A worker renders the bunny at once in full while its chain cannot be built.

    ``load_scene`` queues the chain's build in the service at once (``stats.chains``
    says which mesh is building).  The test holds the chain's build lock (as another
    process building it would), so the chain cannot be ready: every render must still
    come back within the render timeout, in full (level 0), without a resend.
    Released, the chain is built in the background and a later render draws coarser
    levels.  The cache starts torn (arrays without their header): that is said and
    rebuilt.
    """
    monkeypatch.setenv("HOLO_LOD_CACHE", str(tmp_path))
    key = mesh_key(load_scene(str(BUNNY)).objects[0].mesh, LodSettings().recipe)
    (tmp_path / f"{key}.npz").write_bytes(b"PK torn")
    svc = service_factory(
        "--zones", "3", "--size", "64x48", "--workers", "1", "--refresh", "30",
        "--lod-error", "0.5", "--render-timeout", "5",
    )  # fmt: skip
    with ServiceClient(svc.control, timeout_s=30, retries=0) as c, \
            open(tmp_path / f"{key}.lock", "ab") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # the chain cannot be built while this is held
        # renders run in process until the worker is up (docs/service.md, "Supervised
        # workers"): the bunny is for the worker's renderer, so it comes after
        assert wait_until(lambda: c.stats()["split"] == "frames", HANG_S), "no worker came up"
        assert c.stats()["chains"]["built"] == 0
        c.load_scene(path=str(BUNNY))
        building = wait_until(lambda: c.stats()["chains"]["building"], HANG_S)
        assert building == "bunny", c.stats()["chains"]  # queued by the load, not a frame
        c.update_objects([{"index": 0, "scale": 0.2}])  # small: coarse levels will do
        for _ in range(2):
            # within the render timeout: a render past it is resent (render_retries below);
            # the client's own wall clock is not asserted, a loaded machine stretches it
            lod = c.render_once()[0]["stats"]["lod"]
            assert lod["chains"] == {"ready": 0, "building": 1, "failed": 0}
            assert lod["levels"] == [0] and lod["triangles"] == lod["triangles_full"]
        assert c.stats()["render_retries"] == 0  # no render was resent
        fcntl.flock(lock, fcntl.LOCK_UN)
        lod = wait_until(lambda: _chains_built(c), CHAIN_S)
        assert lod and lod["chains"]["ready"] == 1
        assert lod["levels"][0] > 0 and lod["triangles"] < lod["triangles_full"]
        assert c.stats()["lod"]["chains"]["ready"] == 1
        assert c.stats()["render_retries"] == 0
        chains = wait_until(lambda: (s := c.stats()["chains"])["built"] == 1 and s, CHAIN_S)
        assert chains and chains["building"] is None and chains["queued"] == 0
        notes = chains["notes"]
        assert len(notes) == 1
        assert key in notes[0] and "json is missing" in notes[0] and "rebuilding" in notes[0]
    assert (tmp_path / f"{key}.json").is_file()  # cached whole for the next service
