"""Animation: dots stay put where depth did not change (a fixed, seeded pattern).

A static scene changes no pixel between frames; a small moving object changes only
pixels linked (through the old or the new frame's constraint chains) to a pixel whose
constraint changed.
"""

from __future__ import annotations

import numpy as np
import pytest

from service.autostereogram import SirdSettings, SirdWorkspace, random_dots, stereogram


def _ball(cols: int, rows: int, cx: float) -> np.ndarray:
    yy, xx = np.mgrid[0:rows, 0:cols]
    q = 12.0**2 - (xx - cx) ** 2 - (yy - rows / 2) ** 2
    d = np.full((rows, cols), np.inf, np.float32)
    d[q > 0] = 0.2
    return d


def _frame(method: str, depth: np.ndarray):
    s = SirdSettings(method=method, eye_sep=60.0, near=0.0, far=1.0)
    work = SirdWorkspace(*depth.shape, 1)
    img, _ = stereogram(depth, s, random_dots(s.max_sep, seed=7), work)
    cols = np.arange(depth.shape[1])
    if method == "tiw":
        links = work.sep.copy()
    else:  # row: x -> x + s(x) left of the right-most repetition, else a root
        links = np.where(cols < depth.shape[1] - s.max_sep, cols + work.sep, cols)
    return img[:, :, 0].copy(), links, work.sep.copy()


def _components(edges: list[tuple[int, int]], n: int) -> np.ndarray:
    parent = list(range(n))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in edges:
        parent[find(a)] = find(b)
    return np.array([find(a) for a in range(n)])


@pytest.mark.parametrize("method", ["row", "interpolated", "tiw"])
def test_a_static_scene_changes_nothing(method):
    depth = _ball(200, 40, 80.0)
    assert (_frame(method, depth)[0] == _frame(method, depth)[0]).all()


@pytest.mark.parametrize("method", ["row", "tiw"])
def test_a_moving_ball_changes_only_pixels_its_constraints_reach(method):
    a = _frame(method, _ball(200, 40, 80.0))
    b = _frame(method, _ball(200, 40, 83.0))
    changed = a[0] != b[0]
    assert changed.any()
    for y in range(40):
        touched = np.nonzero((a[1][y] != b[1][y]) | (a[2][y] != b[2][y]))[0]
        if touched.size == 0:
            assert not changed[y].any()
            continue
        cols = np.arange(200)
        edges = [(x, int(k)) for links in (a[1][y], b[1][y]) for x, k in zip(cols, links,
                                                                            strict=True)]
        comp = _components(edges, 200)
        reach = np.isin(comp, comp[touched])
        assert not (changed[y] & ~reach).any()
    # far fewer pixels change than with new random dots every frame (~255/256 of them)
    assert changed.mean() < 0.5
