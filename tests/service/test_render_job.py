"""render_job in process: the arrays and stats of a band job (docs/protocol.md 1.5)."""

from __future__ import annotations

import numpy as np

from service.builtin_scenes import builtin_scene
from service.engine.jobs import StatsRenderer, render_job

DISPLAY = {"zones": 3, "angle_deg": 16.0, "cols": 32, "rows": 24, "width": 0.2}
JOB = {"display": DISPLAY, "rows": [0, 24], "t": 0.1, "refresh_hz": 60.0, "order": 1,
       "render": {"method": "zbuffer", "light_model": "blinn", "specular": "polygon"}}


def test_band_jobs_give_their_rows_galpixmap_and_stats():
    renderer = StatsRenderer()
    top, top_stats = render_job(renderer, {**JOB, "rows": [0, 12]}, builtin_scene("game"))
    low, low_stats = render_job(renderer, {**JOB, "rows": [12, 24]}, builtin_scene("game"))
    assert top["colour"].shape == (3, 12, 32, 3) and top["depth"].shape == (3, 12, 32)
    assert top["gp_motion"].shape[0] == 2 and top["gp_debris"].shape == (3, 12, 32)
    assert "points" in top and top["point_derivs"].shape[0] == 3
    assert "points" not in low and "point_derivs" not in low
    for stats, rows in ((top_stats, [0, 12]), (low_stats, [12, 24])):
        assert stats["rows"] == rows and stats["method"] == "zbuffer"
        ms = stats["ms"]
        assert {"motion", "galpixmap", "total"} <= set(ms)
        assert ms["total"] >= ms["motion"] >= 0 and ms["total"] >= ms["galpixmap"] >= 0
        assert all(v == round(v, 3) for v in ms.values())
        assert isinstance(stats["polygons"], dict) and stats["polygons"]
        assert isinstance(stats["inconsistent_pixels"], int)
    assert np.all(np.isfinite(top["depth"]) | np.isinf(top["depth"]))
