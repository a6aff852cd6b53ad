"""Galilean stage starved of renders: error against the time since the last render.

One render at t = 0, then no render for ``seconds``; at every refresh the stage's
frame is compared with the true render of that instant.  Three ways of filling the
gap, side by side on the same render:

* ``hold``: the stage as it runs (``GalileanSettings.hold``): propagated for the
  render's use-by (N_prop refreshes), then the render shown as it was;
* ``extrapolate``: ``hold=False``, propagated for as long as the gap lasts;
* ``render-only``: the render itself all along (sample and hold, G(0)).

``holo-bench galilean --starvation --out DIR`` writes ``galilean_starvation.json`` /
``.csv`` / ``.png``; ``--sweep`` writes them too.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from service.bench.charts import save_chart
from service.bench.rows import write_csv
from service.display import DisplaySettings
from service.galilean.motion_field import RenderedUpdate
from service.galilean.stage import GalileanSettings, GalileanStage
from service.render.scene import MotionState

#: The ways of filling a gap between renders, as charted (name -> stage ``hold``, None:
#: no stage, the render itself).
WAYS = {"hold": True, "extrapolate": False, "render-only": None}
#: Motions of :func:`service.bench.galilean_bench.bench_scene` starved (head-turn: the
#: viewer turns, its filtered motion handed to the stage at every refresh).
STARVED_MOTIONS = ("linear", "falling", "rotating-cube", "head-turn")


def starve(update: RenderedUpdate, truth: Callable[[int], np.ndarray], motion: str,
           display: DisplaySettings, refreshes: int, hz: float, score,
           viewer: Callable[[int], MotionState] | None = None) -> list[dict]:
    """Rows of one motion: per refresh after the render and per way, the error.

    Parameters
    ----------
    update : RenderedUpdate
        The one render (``render_with_motion`` at t = 0).
    truth : callable
        ``truth(k)``: the true render (Z, R, C, 3) uint8 ``k`` refreshes later.
    motion : str
        Its name, for the rows.
    display : DisplaySettings
    refreshes : int
        Refreshes without a render after the one that grafts it.
    hz : float
        Refresh rate.
    score : callable
        ``score(shown, truth) -> (psnr, pct_wrong)`` of two (Z, R, C, 3) uint8 images.
    viewer : callable, optional
        ``viewer(k)``: the filtered head motion handed to the stages before
        refresh ``k`` (the head-motion update; a held stage keeps it for later).

    Returns
    -------
    list of dict
        ``motion``, ``way``, ``refreshes``, ``seconds``, ``psnr``, ``pct_wrong``, ``held``.
    """
    stages = {}
    for way, hold in WAYS.items():
        if hold is None:
            continue
        st = GalileanStage(display, GalileanSettings(order=2, refresh_hz=hz, hold=hold))
        st.update(update, 0)
        st.refresh()
        stages[way] = st
    rows = []
    for k in range(1, refreshes + 1):
        true = truth(k)
        for way in WAYS:
            if way in stages and viewer is not None:
                stages[way].viewer(viewer(k))
            out = stages[way].refresh() if way in stages else None
            shown = update.frame.colour if out is None else out.colour
            ps, wrong = score(shown, true)
            rows.append({"motion": motion, "way": way, "refreshes": k,
                         "seconds": round(k / hz, 4), "psnr": round(ps, 3),
                         "pct_wrong": round(wrong, 3),
                         "held": bool(out is not None and out.flags["held"])})
    return rows


def chart(rows: list[dict], n_prop: int, hz: float, path: Path) -> None:
    """% of pixels wrong and PSNR against seconds without a render, a column per motion."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    motions = list(dict.fromkeys(r["motion"] for r in rows))
    fig, axes = plt.subplots(2, len(motions), figsize=(4.2 * len(motions), 6.4),
                             squeeze=False, sharex=True)
    styles = {"hold": "-", "extrapolate": "--", "render-only": ":"}
    for j, motion in enumerate(motions):
        for i, (key, label) in enumerate((("pct_wrong", "% pixels wrong"), ("psnr", "PSNR dB"))):
            ax = axes[i][j]
            for way in WAYS:
                pts = [(r["seconds"], r[key]) for r in rows
                       if r["motion"] == motion and r["way"] == way]
                ax.plot(*zip(*pts, strict=True), styles[way], label=way)
            ax.axvline(n_prop / hz, color="grey", lw=0.8)
            ax.set_ylabel(label)
            if i == 0:
                ax.set_title(f"{motion} (use-by: {n_prop} refreshes)")
            else:
                ax.set_xlabel("seconds since the last render")
    axes[0][0].legend(fontsize=8)
    fig.suptitle("Galilean stage starved of renders: error against the truth at each refresh")
    fig.tight_layout()
    save_chart(fig, path, dpi=90)


def summary(rows: list[dict]) -> list[dict]:
    """Per motion and way: mean % wrong and worst PSNR over the whole gap."""
    out = []
    keys = dict.fromkeys((r["motion"], r["way"]) for r in rows)
    for motion, way in keys:
        mine = [r for r in rows if r["motion"] == motion and r["way"] == way]
        out.append({"motion": motion, "way": way,
                    "mean_pct_wrong": round(float(np.mean([r["pct_wrong"] for r in mine])), 3),
                    "worst_pct_wrong": round(max(r["pct_wrong"] for r in mine), 3),
                    "worst_psnr": round(min(r["psnr"] for r in mine), 3)})
    return out


def write(rows: list[dict], n_prop: int, hz: float, out: Path) -> dict:
    """``galilean_starvation.json`` / ``.csv`` / ``.png`` in ``out``; returns the JSON."""
    doc = {"refresh_hz": hz, "n_prop": n_prop, "summary": summary(rows), "rows": rows}
    (out / "galilean_starvation.json").write_text(json.dumps(doc, indent=1))
    write_csv(rows, out / "galilean_starvation.csv")
    chart(rows, n_prop, hz, out / "galilean_starvation.png")
    return doc
