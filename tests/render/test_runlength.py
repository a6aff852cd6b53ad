"""The thesis's run-length occlusion: its worked example, its cases, and the kernel."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.render.occlusion.runlength import SENTINEL, occluded


def linerow(*entries: int, cap: int = 20) -> list[int]:
    return list(entries) + [SENTINEL] * (cap - len(entries))


def used(row: list[int]) -> list[int]:
    return [v for v in row if v != SENTINEL]


def test_worked_example_section_2_3_1():
    # Thesis 2.3.1: row [1,5,7,8], point at step 10 -> new line [10,10], not occluded,
    # tracker set to 5.
    row = linerow(1, 5, 7, 8)
    hidden, tracker = occluded(row, 10, stepspace=1, tracker=0)
    assert hidden is False
    assert used(row) == [1, 5, 7, 8, 10, 10]
    assert tracker == 5


@pytest.mark.parametrize(
    ("row", "step", "hidden", "after"),
    [
        ((), 4, False, [4, 4]),  # empty linerow
        ((3, 6), 1, False, [1, 1, 3, 6]),  # before the first line: own line
        ((3, 6), 2, False, [2, 6]),  # extends the first line downward
        ((3, 6), 3, True, [3, 6]),  # equals the first entry
        ((1, 5, 7, 8), 4, True, [1, 5, 7, 8]),  # inside a line
        ((1, 5, 7, 8), 5, True, [1, 5, 7, 8]),  # ends a line
        ((1, 5, 7, 8), 7, True, [1, 5, 7, 8]),  # starts a line
        ((1, 5, 7, 8), 6, False, [1, 8]),  # fills the gap between two lines
        ((1, 5, 8, 9), 6, False, [1, 6, 8, 9]),  # extends a line upward
        ((1, 4, 7, 9), 6, False, [1, 4, 6, 9]),  # extends the next line downward
        ((1, 2, 7, 9), 4, False, [1, 2, 4, 4, 7, 9]),  # own line in a gap
        ((1, 2), 4, False, [1, 2, 4, 4]),  # own line after the last
        ((1, 2), 3, False, [1, 3]),  # extends the last line
    ],
)
def test_occluded_cases(row, step, hidden, after):
    r = linerow(*row)
    got, _ = occluded(r, step)
    assert got is hidden
    assert used(r) == after


def test_stepspace_other_than_one():
    r = linerow(0, 0, 4, 4)
    assert occluded(r, 2, stepspace=2)[0] is False
    assert used(r) == [0, 4]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 40), max_size=60))
def test_linerow_matches_a_set_of_filled_steps(steps):
    # The linerow is a run-length encoding of the steps drawn so far: a point is
    # occluded iff its step was drawn before, whatever order points arrive in.
    row = [SENTINEL] * 48
    filled: set[int] = set()
    for s in steps:
        hidden, _ = occluded(row, s)
        assert hidden == (s in filled)
        filled.add(s)
        runs = used(row)
        assert runs == sorted(runs)
        expanded = {v for a, b in zip(runs[::2], runs[1::2], strict=True) for v in range(a, b + 1)}
        assert expanded == filled
        # intervals are maximal: no two lines touch
        assert all(runs[i + 1] - runs[i] > 1 for i in range(1, len(runs) - 1, 2))


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 30), st.integers(0, 8)), max_size=30))
def test_tracker_spans_agree_with_fresh_search(spans):
    # Drawing left-to-right spans with the tracker gives the same answers as searching
    # from index 0 every time.
    a = [SENTINEL] * 80
    b = [SENTINEL] * 80
    for start, length in spans:
        tracker = 0
        for s in range(start, start + length + 1):
            h1, tracker = occluded(a, s, tracker=tracker)
            h2, _ = occluded(b, s, tracker=0)
            assert h1 == h2
    assert a == b


def test_numba_twin_matches_reference():
    from service.render.occlusion.runlength import _occluded

    rng = np.random.default_rng(1)
    for _ in range(50):
        a = [SENTINEL] * 70
        b = np.full(70, SENTINEL, np.int64)
        for _ in range(40):
            s0 = int(rng.integers(0, 60))
            ta = tb = 0
            for s in range(s0, s0 + int(rng.integers(1, 6))):
                ha, ta = occluded(a, s, tracker=ta)
                hb, tb = _occluded(b, s, tb)
                assert ha == hb and ta == tb
        assert a == b.tolist()
