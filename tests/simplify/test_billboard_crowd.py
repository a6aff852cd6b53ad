"""holo-bench billboard part 5: a crowd of small objects as clouds and as quadric levels.

The crowd fits the display at the size asked, the error counts colour and coverage,
and each cloud is matched with the cheapest mesh level of no more error."""

import numpy as np

from service.bench.billboard_crowd import (
    COLOUR_LEVELS,
    crowd_places,
    crowd_rows,
    match_clouds,
    pixel_errors,
)
from service.display import DisplaySettings
from service.primitives import sphere
from service.render.frame import Frame

DISPLAY = DisplaySettings(zones=3, cols=96, rows=72)


def test_a_pixel_differs_past_32_levels_in_any_channel_or_by_coverage():
    depth = np.full((1, 2, 4), np.inf, np.float32)
    colour = np.zeros((1, 2, 4, 3), np.uint8)
    ref = Frame(colour.copy(), depth.copy())
    depth[0, 0, :] = 1.0  # 4 pixels only this frame covers (coverage; colour unchanged)
    colour[0, 1, 0, 1] = COLOUR_LEVELS  # at the limit: the same colour
    colour[0, 1, 1, 2] = COLOUR_LEVELS + 1  # past it in one channel
    err = pixel_errors(ref, Frame(colour, depth))
    assert err["coverage_pct"] == 50.0
    assert err["colour_pct"] == 12.5
    assert err["differs_pct"] == 62.5


def test_a_cloud_is_matched_with_the_cheapest_mesh_level_of_no_more_error():
    rows = [{"kind": "full", "level": 0, "cpu_ms": 9.0, "differs_pct": 0.0},
            {"kind": "quadric", "level": 1, "cpu_ms": 5.0, "differs_pct": 0.5},
            {"kind": "quadric", "level": 2, "cpu_ms": 2.0, "differs_pct": 1.5},
            {"kind": "cloud", "level": -1, "cpu_ms": 4.0, "differs_pct": 1.0},
            {"kind": "cloud", "level": -1, "cpu_ms": 3.0, "differs_pct": 0.1}]
    for r in rows:
        r["empty_ms"] = 1.0
    out = match_clouds(rows)
    assert (out[3]["matched_level"], out[3]["cloud_vs_mesh"]) == (1, 0.8)
    assert out[3]["above_empty_vs_mesh"] == 0.75
    assert (out[4]["matched_level"], out[4]["cloud_vs_mesh"]) == (0, 3.0 / 9.0)
    assert np.isnan(out[1]["cloud_vs_mesh"])


def test_the_crowd_spreads_over_the_display_at_the_size_asked():
    ball = sphere(0.5, 6, 12)
    places = crowd_places(ball, 30, 8.0, DISPLAY)
    diag = float(np.linalg.norm(ball.vertices.max(0) - ball.vertices.min(0)))
    assert len(places) == 30
    for p in places:
        assert np.isclose(p.scale * diag / DISPLAY.pixel_size, 8.0)
        centre = p.position  # the ball is centred on its origin
        assert abs(centre[0]) < DISPLAY.width / 2 and abs(centre[1]) < DISPLAY.height / 2
    xs = np.array([p.position[0] for p in places])
    assert xs.max() - xs.min() > 0.6 * DISPLAY.width


def test_a_small_crowd_runs_and_matches_its_cloud(tmp_path, monkeypatch):
    monkeypatch.setenv("HOLO_LOD_CACHE", str(tmp_path))
    ball = sphere(0.5, 10, 20)
    rows = crowd_rows(ball, "ball", DISPLAY, 6, [8.0], [5.0], [32], 1)
    assert rows[0]["kind"] == "full" and rows[0]["differs_pct"] == 0.0
    assert any(r["kind"] == "quadric" for r in rows)
    cloud = [r for r in rows if r["kind"] == "cloud"]
    assert len(cloud) == 1 and cloud[0]["quads"] > 0
    assert cloud[0]["matched_ms"] > 0 and np.isfinite(cloud[0]["cloud_vs_mesh"])
