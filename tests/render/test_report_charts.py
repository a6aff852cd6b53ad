"""The report's charts: no two tick labels overlap, titles in words.

Each chart function is the benchmark's own, fed rows shaped like its benchmark's
in the regime that made labels collide: a log axis spanning less than a decade
(matplotlib then labels its minor ticks, 2.4x10^-1, 2.6x10^-1, ..., every one of
them under 0.4 decade).  Overlap is
judged from the labels' extents as matplotlib draws them (``get_window_extent``).
"""

from __future__ import annotations

import itertools

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402

from service.bench import filters_bench, galilean_bench, light_bench, render_bench  # noqa: E402
from service.bench.charts import overlapping_ticklabels, save_chart  # noqa: E402

METHODS = ("runlength", "zbuffer", "bsp", "raycast", "runlength+frame", "runlength+pixel")


def spread(lo: float, hi: float, n: int) -> list[float]:
    return [lo + (hi - lo) * i / max(1, n - 1) for i in range(n)]


def visible_labels(axis) -> list[str]:
    return [t.get_text() for t in axis.get_ticklabels(which="both")
            if t.get_visible() and t.get_text()]


def test_a_log_axis_under_a_decade_overlaps_in_plain_matplotlib_and_not_once_saved(tmp_path):
    fig, ax = plt.subplots(figsize=(5, 4))
    ax.plot([0.23, 0.35], [0, 1])  # under 0.4 decade: every minor tick gets a label
    ax.set_xscale("log")
    assert overlapping_ticklabels(fig)  # the collision the report's cyclic panel had
    save_chart(fig, tmp_path / "x.png")
    assert overlapping_ticklabels(fig) == []
    assert len(visible_labels(ax.xaxis)) >= 2  # thinned, not emptied
    assert (tmp_path / "x.png").stat().st_size > 1000


def occlusion_rows(scene: str, lo: float, hi: float) -> list[dict]:
    ms = iter(spread(lo, hi, 2 * len(METHODS)))
    return [{"scene": scene, "zones": z, "method": m, "ms": next(ms),
             "pct_differ": 0.3 if m == "runlength" else 0.0}
            for m, z in itertools.product(METHODS, (1, 5))]


@pytest.mark.parametrize("ranges", [((0.23, 0.35), (1.5, 2.5)), ((0.1, 1.5), (0.6, 47.0))])
def test_the_occlusion_chart_labels_do_not_overlap(tmp_path, ranges):
    rows = occlusion_rows("cyclic", *ranges[0]) + occlusion_rows("game", *ranges[1])
    peers = [{"scene": "game", "zones": z, "peer": "llvmpipe", "peer_ms": 2.0 + z,
              "pct_differ": 0.0} for z in (1, 5)]
    fig = render_bench.chart_methods(rows, tmp_path / "m.png", peers)
    assert [ax.get_title() for ax in fig.axes] == ["cyclic", "game"]
    assert overlapping_ticklabels(fig) == []


def test_the_other_render_charts_labels_do_not_overlap(tmp_path):
    stages = ("flatten", "project", "cull", "sort", "occlusion", "light")
    cost = [{"scene": "game", "zones": z, "ms": 1.0 + 0.3 * z, "ratio": 1.0 + 0.3 * z,
             **{f"ms_{s}": (1.0 + 0.3 * z) / 6 for s in stages}} for z in (1, 2, 5, 9, 17, 33)]
    sweep = [{"angle_deg": a, "method": m, "pct_differ": 0.01 * a, "pct_differ_continuous":
              0.02 * a} for a in (4, 8, 16, 24, 32, 45, 60) for m in ("runlength", "zbuffer")]
    peers = [{"scene": s, "zones": z, "size": wh, "peer": p, "ratio": r}
             for (s, z, wh), (p, r) in itertools.product(
                 itertools.product(("game", "spheres-8k"), (1, 5), ("160x120", "320x240")),
                 (("llvmpipe", 0.8), ("embree", 1.3)))]
    for fig in (render_bench.chart_zone_cost(cost, tmp_path / "c.png"),
                render_bench.chart_sweep(sweep, "angle_deg", tmp_path / "s.png", "t"),
                render_bench.chart_peers(peers, tmp_path / "p.png")):
        assert overlapping_ticklabels(fig) == []


def test_the_galilean_and_light_charts_labels_do_not_overlap(tmp_path):
    steps = [{"triangles": t, "render_ms": r, "refresh_ms": 0.41 + 0.01 * i,
              "render_with_motion_ms": 17.0 + 20 * i}
             for i, (t, r) in enumerate(((252, 0.88), (3324, 1.2), (30204, 7.1)))]
    cx = {"size": "160x120", "steps": steps, "crossover_10x_render": None,
          "crossover_10x_update": 252}
    orders = {k: {"ms_per_refresh": 0.2 + 0.02 * i, "render_ms": 0.76}
              for i, k in enumerate(("G0", "G0-no-colour-motion", "G1", "G1-no-colour-motion",
                                     "G2", "G2-no-colour-motion", "G3"))}
    light = [{"scene": s, "zones": z, "model": m, "evaluation": e, "ms": 0.16 + 0.02 * i,
              "error": 0.005 * i}
             for i, (s, z, (m, e)) in enumerate(itertools.product(
                 ("sphere", "game"), (1, 5), (("ambient", "polygon"), ("phong", "vertex"),
                                              ("blinn", "point"))))]
    for fig in (galilean_bench.chart_complexity(cx, tmp_path / "cx.png"),
                galilean_bench.chart_timing({"size": "160x120", "orders": orders},
                                            tmp_path / "t.png"),
                light_bench.chart(light, tmp_path / "l.png")):
        assert overlapping_ticklabels(fig) == []


def filter_rows() -> list[dict]:
    rows = []
    for k, (line, params) in enumerate((("raw", "-"), ("alpha-beta", "theta=0.5"),
                                        ("alpha-beta", "theta=0.8"), ("one-euro", "beta=0.01"))):
        base = {"filter": line, "line": line, "params": params}
        rows += [{**base, "dataset": "still", "ang_rms_err": 0.15 - 0.02 * k,
                  "ang_vel_rms_err": 17.0 - 2 * k},
                 {**base, "dataset": "sway", "ang_lag_ms": 5.0 * k, "ang_vel_lag_ms": 7.0 * k},
                 {**base, "dataset": "turn", "ang_pred_rms_err": 3.9 - 0.1 * k},
                 {**base, "dataset": "capture", "ang_lag_ms": 4.0 * k,
                  "ang_vel_hf_jitter": 12.0 - k}]
    return rows


def test_the_pose_filter_charts_are_titled_in_words_and_labels_do_not_overlap(tmp_path):
    figs = (filters_bench.sim_chart(filter_rows(), tmp_path / "sim.png", 50.0),
            filters_bench.capture_chart(filter_rows(), tmp_path / "cap.png"))
    titles = [ax.get_title() for fig in figs for ax in fig.axes]
    assert len(titles) == 4
    for title in titles:  # words, not the results' column names (ang_rms_err vs ...)
        assert "_" not in title and len(title.split()) >= 5, title
    for fig in figs:
        assert overlapping_ticklabels(fig) == []
        whole = fig.bbox
        for ax in fig.axes:  # each title whole on the figure, none cut at its edge
            box = ax.title.get_window_extent()
            assert whole.x0 <= box.x0 and box.x1 <= whole.x1, ax.get_title()
