"""Level of detail in the render service: ``--lod-error`` and ``set_display`` ``lod_error``."""

from __future__ import annotations

import pytest

from service.errors import ServiceError
from service.net.client import ServiceClient


def test_lod_error_turns_level_of_detail_on_and_off(service_factory, tmp_path, monkeypatch):
    monkeypatch.setenv("HOLO_LOD_CACHE", str(tmp_path))
    svc = service_factory(
        "--scene", "game", "--zones", "3", "--size", "32x24",
        "--workers", "0", "--refresh", "30", "--lod-error", "0.5",
    )  # fmt: skip
    with ServiceClient(svc.control, timeout_s=30) as c:
        header, _ = c.render_once()
        lod = header["stats"]["lod"]
        assert lod["error_px"] == 0.5 and len(lod["levels"]) == len(lod["predicted_px"]) == 7
        assert all(p <= 0.5 for p in lod["predicted_px"])
        polled = c.stats()["lod"]  # the last finished render's levels, without a render
        assert polled["render_id"] >= header["render_id"] and len(polled["levels"]) == 7
        assert c.set_display(lod_error=0.0)["lod_error"] == 0.0
        assert "lod" not in c.render_once()[0]["stats"]
        assert c.stats()["lod"] is None
        with pytest.raises(ServiceError) as info:
            c.set_display(lod_error=-1)
        assert info.value.code == "bad_message" and "lod_error" in str(info.value)


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
