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
        assert c.set_display(lod_error=0.0)["lod_error"] == 0.0
        assert "lod" not in c.render_once()[0]["stats"]
        with pytest.raises(ServiceError) as info:
            c.set_display(lod_error=-1)
        assert info.value.code == "bad_message" and "lod_error" in str(info.value)
