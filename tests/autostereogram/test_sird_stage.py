"""The autostereogram stage: hand-worked rows, constraints kept, decoding, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.autostereogram import (
    SirdSettings,
    SirdWorkspace,
    broken_constraints,
    default_eye_sep,
    random_dots,
    separation_map,
    stereogram,
)
from service.autostereogram.decode import (
    METHOD_CONVENTION,
    accuracy,
    decode,
    edge_free,
    streak_fraction,
)
from service.autostereogram.depth_scenes import seed_slope, sphere, steps
from service.autostereogram.interpolated import fixed_separation_map
from service.base.errors import HoloError, SettingsError

#: One grey pattern row 10, 20, 30, 40 (width s(0) = 4 for E = 8).
TINY_PATTERN = np.array([[[10], [20], [30], [40]]], np.uint8)


def _tiny_depth() -> np.ndarray:
    """One row of 12: empty (z = 0) except x = 5 on the near plane (z = 1)."""
    d = np.full((1, 12), np.inf, np.float32)
    d[0, 5] = 0.0
    return d


def _draw(method: str, depth: np.ndarray, eye_sep: float = 8.0, pattern=TINY_PATTERN):
    s = SirdSettings(method=method, eye_sep=eye_sep, mu=1 / 3, near=0.0, far=1.0)
    work = SirdWorkspace(depth.shape[0], depth.shape[1], pattern.shape[2])
    img, stats = stereogram(depth, s, pattern, work)
    return img.copy(), stats, s, work


def test_geometry_of_the_tiny_row():
    s = SirdSettings(eye_sep=8.0, mu=1 / 3, near=0.0, far=1.0)
    assert (s.max_sep, s.min_sep) == (4, 3)  # round(8/2), round((2/3) 8 / (5/3)) = round(3.2)
    assert separation_map(_tiny_depth(), s).tolist() == [[4] * 5 + [3] + [4] * 6]


def test_row_by_hand():
    # RandW = 4, h = 0 except h(5) = 1.  First loop, x = 11..8: out[x] = P[x mod 4]
    # -> 10 20 30 40.  Second loop, x = 7..0: out[x] = out[x + 4 - h(x)]:
    # x7 <- 11 (40), x6 <- 10 (30), x5 <- 8 (10, h = 1), x4 <- 8 (10), x3 <- 7 (40),
    # x2 <- 6 (30), x1 <- 5 (10), x0 <- 4 (10).
    img, stats, s, work = _draw("row", _tiny_depth())
    assert img[0, :, 0].tolist() == [10, 10, 30, 40, 10, 10, 30, 40, 10, 20, 30, 40]
    assert (stats.constraints, stats.hidden) == (8, 0)
    assert broken_constraints(img, s, work) == 0


def test_tiw_by_hand():
    # y = 0, s = 4 (left = x - 2) except x = 5: s = 3, left = 4, right = 7.  Links left to
    # right: 0->4, 1->5, 2->6, 4->7 (x = 5), x = 6 wants 4->8 but 4->7 exists: follow to 7,
    # 7->8; 5->9; 6->10; x = 9 wants 7->11: follow 7->8, 8->11.  Nothing is hidden (the
    # first sight-line step 0.75 (2 - 0) already clears z = 1).  Colours right to left:
    # free 11, 10, 9 take P[x mod 4] = 40, 30, 20; 8 <- 11, 7 <- 8, 6 <- 10, 5 <- 9,
    # 4 <- 7, 3 is free (P[3] = 40), 2 <- 6, 1 <- 5, 0 <- 4.
    img, stats, s, work = _draw("tiw", _tiny_depth())
    assert work.sep[0].tolist() == [4, 5, 6, 3, 7, 9, 10, 8, 11, 9, 10, 11]
    assert img[0, :, 0].tolist() == [40, 20, 30, 40, 40, 20, 30, 40, 40, 20, 30, 40]
    assert (stats.constraints, stats.hidden) == (8, 0)
    assert broken_constraints(img, s, work) == 0


def _seed_row_reference(sep: np.ndarray, randw: int, prow: np.ndarray) -> np.ndarray:
    """The seed's two loops, literally, on one row of separations."""
    w = sep.shape[0]
    out = np.zeros(w, np.int64)
    for x in range(w - 1, w - 1 - randw, -1):
        out[x] = prow[(x - (randw - sep[x])) % prow.shape[0]]
    for x in range(w - 1 - randw, -1, -1):
        out[x] = out[x + randw - (randw - sep[x])]
    return out


depth_maps = st.integers(1, 3).flatmap(lambda h: st.integers(40, 90).flatmap(
    lambda w: st.lists(st.sampled_from([np.inf, 0.0, 0.1, 0.35, 0.5, 0.8, 1.0, 2.0]),
                       min_size=h * w, max_size=h * w).map(
        lambda v: np.array(v, np.float32).reshape(h, w))))


@settings(max_examples=40, deadline=None)
@given(depth=depth_maps, eye_sep=st.sampled_from([8.0, 12.0, 17.0, 24.0]), seed=st.integers(0, 9))
def test_row_matches_the_seed_and_keeps_its_constraints(depth, eye_sep, seed):
    pattern = random_dots(int(np.floor(eye_sep / 2 + 0.5)), 8, seed=seed)
    img, _, s, work = _draw("row", depth, eye_sep, pattern)
    sep = separation_map(depth, s)
    for y in range(depth.shape[0]):
        ref = _seed_row_reference(sep[y], s.max_sep, pattern[y % 8, :, 0])
        assert img[y, :, 0].tolist() == ref.tolist()
        xs = np.arange(depth.shape[1] - s.max_sep)
        assert (img[y, xs, 0] == img[y, xs + sep[y, xs], 0]).all()


@settings(max_examples=40, deadline=None)
@given(depth=depth_maps, eye_sep=st.sampled_from([8.0, 12.0, 17.0, 24.0]),
       colour=st.booleans())
def test_tiw_links_are_kept_and_never_conflict(depth, eye_sep, colour):
    pattern = random_dots(int(np.floor(eye_sep / 2 + 0.5)), 8, colour=colour, seed=3)
    img, stats, s, work = _draw("tiw", depth, eye_sep, pattern)
    links = work.sep
    cols = np.arange(depth.shape[1])
    # one link per pixel, always to its right and inside the row
    assert ((links == cols) | ((links > cols) & (links < depth.shape[1]))).all()
    for y, x in zip(*np.nonzero(links != cols), strict=True):
        assert (img[y, x] == img[y, links[y, x]]).all()
    assert broken_constraints(img, s, work) == 0
    assert stats.constraints + stats.hidden <= depth.size


@pytest.mark.parametrize("method", ["row", "tiw"])
def test_decoder_recovers_the_sphere(method):
    depth = sphere(320, 240)
    s = SirdSettings(method=method, eye_sep=90.0, near=0.0, far=1.0)
    img, stats, s, work = _draw(method, depth, 90.0, random_dots(s.max_sep, seed=1))
    conv = METHOD_CONVENTION[method]
    expected = separation_map(depth, s)
    decoded = decode(img, s.min_sep - 2, s.max_sep + 2, convention=conv)
    mask = edge_free(expected, s.max_sep + 4, conv)
    assert mask.mean() > 0.5
    assert accuracy(decoded, expected, mask) >= 0.95
    assert broken_constraints(img, s, work) == 0
    if method == "tiw":
        assert stats.hidden > 0


@pytest.mark.parametrize("cols", [320, 640])
def test_streaks_on_the_seed_slope_interpolated_leaves_a_tenth_of_rows(cols):
    # the benchmark's sizes and default eye separations: 320 px -> E = 106 (the
    # separation there shrinks 10.6 px over the 11 px rise: the seed's left-read blend
    # stalled), 640 px -> E = 180
    eye = default_eye_sep(cols)
    s = SirdSettings(eye_sep=eye)
    depth = seed_slope(cols, 24, s.max_sep - s.min_sep)
    fractions = {}
    for method in ("row", "interpolated"):
        img = _draw(method, depth, eye, random_dots(s.max_sep, seed=2))[0]
        fractions[method] = streak_fraction(img)
    assert fractions["row"] > 0.3  # the seed's streaks
    assert fractions["interpolated"] <= fractions["row"] / 10


def _symmetric_partners(fsep_row: np.ndarray) -> np.ndarray:
    """``interpolated``'s constraints, literally: point x names L = round(x - sf/2)."""
    part = np.full(fsep_row.shape[0], -1, np.int64)
    for x, sf in enumerate(fsep_row.tolist()):
        left = (x * 256 - sf // 2 + 128) // 256
        if left >= 0 and (part[left] < 0 or left * 256 + sf < part[left]):
            part[left] = left * 256 + sf
    return part


@settings(max_examples=40, deadline=None)
@given(depth=depth_maps, eye_sep=st.sampled_from([8.0, 12.0, 18.0, 24.0]), seed=st.integers(0, 9))
def test_interpolated_keeps_its_symmetric_blends(depth, eye_sep, seed):
    # every left pixel a point names equals the blend at its floating-point partner;
    # no point names a free pixel, which shows the pattern at its own column
    pattern = random_dots(int(np.floor(eye_sep / 2 + 0.5)), 8, seed=seed)
    img, stats, s, work = _draw("interpolated", depth, eye_sep, pattern)
    w = depth.shape[1]
    fsep = np.zeros(depth.shape, np.int32)
    fixed_separation_map(depth, s.far, 1.0 / (s.far - s.near), s.eye_sep, s.mu, fsep)
    kept = 0
    for y in range(depth.shape[0]):
        row = img[y, :, 0].astype(np.int64)
        for left, r in enumerate(_symmetric_partners(fsep[y]).tolist()):
            i, f = divmod(r, 256)
            if r < 0:
                assert row[left] == pattern[y % 8, left % s.max_sep, 0]
            elif i + 1 < w:
                kept += 1
                assert row[left] == row[i] + (((row[i + 1] - row[i]) * f + 128) >> 8)
    assert kept == stats.constraints


def test_steps_decode_away_from_their_edges():
    depth = steps(320, 20, levels=2)  # bands 80 px wide
    s = SirdSettings(eye_sep=90.0)
    img, _, s, work = _draw("tiw", depth, 90.0, random_dots(s.max_sep, seed=4))
    expected = separation_map(depth, s)
    mask = edge_free(expected, s.max_sep // 2 + 4, "centre")
    decoded = decode(img, s.min_sep - 2, s.max_sep + 2, convention="centre")
    assert mask.any() and accuracy(decoded, expected, mask) >= 0.95


@pytest.mark.parametrize("depth, match", [
    (np.array([[np.nan] * 40], np.float32), "NaN"),
    (np.zeros((0, 0), np.float32), "non-empty"),
    (np.zeros((2, 7), np.float32), "half the width"),
])
def test_bad_depth_maps_get_clear_errors(depth, match):
    with pytest.raises(SettingsError, match=match):
        _draw("tiw", depth, 8.0)


@pytest.mark.parametrize("kwargs, match", [
    ({"mu": 0.6}, "do not fuse"),
    ({"eye_sep": 1.0}, "> 2 pixels"),
    ({"near": 2.0, "far": 1.0}, "near < far"),
    ({"method": "magic"}, None),
])
def test_bad_settings_get_clear_errors(kwargs, match):
    with pytest.raises(HoloError, match=match):
        s = SirdSettings(**kwargs)
        stereogram(np.zeros((4, 400), np.float32), s, random_dots(s.max_sep))
