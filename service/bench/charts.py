"""Saving the benchmarks' charts with tick labels that never overlap.

Matplotlib labels the minor ticks of a log axis that spans less than a decade
(``2.4x10^-1, 2.6x10^-1, ...``), and on a narrow panel those labels run into each
other: the report's cyclic-scene panel did.  :func:`save_chart` blanks every tick
label that would overlap one already kept (major labels first, then minor ones, in
order along the axis), then saves and closes the figure.  The blanking goes into
the axis's formatter, by tick value, so it holds however often the figure is drawn
again; :func:`overlapping_ticklabels` is the check (the tests use it).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from matplotlib.axis import Axis
    from matplotlib.figure import Figure
    from matplotlib.transforms import Bbox

#: Pixels of space kept around each tick label.
PAD_PX = 2.0


def _label_boxes(axis: Axis, renderer, minor: bool) -> list[tuple[float, str, Bbox]]:
    """(tick value, text, extent) of the axis's drawn, non-empty tick labels.

    Ticks outside the axis's view (which matplotlib does not draw) are left out.
    """
    ticks = axis.get_minor_ticks() if minor else axis.get_major_ticks()
    locs = axis.get_minorticklocs() if minor else axis.get_majorticklocs()
    lo, hi = sorted(axis.get_view_interval())
    slack = 1e-9 * max(abs(lo), abs(hi), 1e-300)
    out = []
    for tick, loc in zip(ticks, locs, strict=False):
        if not lo - slack <= loc <= hi + slack:
            continue
        for label in (tick.label1, tick.label2):
            if label.get_visible() and label.get_text():
                out.append((float(loc), label.get_text(), label.get_window_extent(renderer)))
    return out


def _drawn(fig: Figure):
    """Draw ``fig`` on an Agg canvas (a closed pyplot figure gets a new one); its renderer."""
    # deferred: matplotlib loads only when a chart is drawn
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def overlapping_ticklabels(fig: Figure) -> list[tuple[str, str, str]]:
    """Pairs of tick labels whose extents overlap: (axes title, label, label).

    Draws the figure first (tick labels are placed at draw time).
    """
    renderer = _drawn(fig)
    found = []
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            boxes = [b for minor in (False, True) for b in _label_boxes(axis, renderer, minor)]
            found += [(ax.get_title(), a[1], b[1]) for i, a in enumerate(boxes)
                      for b in boxes[i + 1:] if a[2].overlaps(b[2])]
    return found


def _blank(axis: Axis, minor: bool, values: set[float]) -> None:
    """Make the axis's major or minor formatter return "" at ``values``."""
    # deferred: matplotlib loads only when a chart is drawn
    from matplotlib.ticker import Formatter

    inner = axis.get_minor_formatter() if minor else axis.get_major_formatter()

    class Blanked(Formatter):
        def __call__(self, x, pos=None):
            return "" if float(x) in values else inner(x, pos)

        def format_ticks(self, locs):
            return ["" if float(x) in values else s
                    for x, s in zip(locs, inner.format_ticks(locs), strict=True)]

        def get_offset(self):
            return inner.get_offset()

        def set_locs(self, locs):
            inner.set_locs(locs)

    formatter = Blanked()
    formatter.set_axis(axis)
    (axis.set_minor_formatter if minor else axis.set_major_formatter)(formatter)


def thin_ticklabels(fig: Figure) -> int:
    """Blank each tick label that overlaps one kept before it; how many were blanked.

    Per axis, major labels are kept first (in order along the axis), then minor
    labels where they fit.
    """
    renderer = _drawn(fig)
    blanked = 0
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            kept: list[Bbox] = []
            for minor in (False, True):
                drop = set()
                for value, _, box in _label_boxes(axis, renderer, minor):
                    box = box.padded(PAD_PX)
                    if any(box.overlaps(k) for k in kept):
                        drop.add(value)
                    else:
                        kept.append(box)
                if drop:
                    _blank(axis, minor, drop)
                    blanked += len(drop)
    return blanked


def save_chart(fig: Figure, path: Path, dpi: int = 110) -> Figure:
    """Thin overlapping tick labels, save ``fig`` as ``path`` and close it.

    Returns
    -------
    Figure
        The figure (closed; it can still be drawn, for checks such as
        :func:`overlapping_ticklabels`).
    """
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    fig.set_dpi(dpi)  # the labels are measured at the size they are saved at
    thin_ticklabels(fig)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return fig
