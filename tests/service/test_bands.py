"""service.base.bands: a kernel over bands on several threads, without parfor."""

from __future__ import annotations

import os
import threading

import numba as nb
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from service.base.bands import chunks, run_bands


@given(st.integers(0, 300), st.integers(1, 17))
def test_chunks_cover_every_band_once_in_order(bands, parts):
    runs = chunks(bands, parts)
    covered = [b for first, stop in runs for b in range(first, stop)]
    assert covered == list(range(bands))
    assert len(runs) == min(bands, parts)
    sizes = [stop - first for first, stop in runs]
    assert not sizes or max(sizes) - min(sizes) <= 1


@nb.njit(cache=True, nogil=True)
def _square_rows(first, stop, src, out):
    for b in range(first, stop):
        for c in range(src.shape[1]):
            out[b, c] = src[b, c] * src[b, c]


@pytest.mark.parametrize("threads", [1, 2, 3, 8])
def test_a_compiled_kernel_gives_the_serial_result(threads):
    src = np.arange(37 * 5, dtype=np.float64).reshape(37, 5)
    out = np.full_like(src, np.nan)
    run_bands(_square_rows, src.shape[0], src, out, threads=threads)
    np.testing.assert_array_equal(out, src * src)


def test_runs_go_to_distinct_threads_the_callers_first():
    seen: list[tuple[int, int, int]] = []
    lock = threading.Lock()
    started = threading.Barrier(3, timeout=10)

    def kernel(first, stop):
        assert isinstance(first, np.int64) and isinstance(stop, np.int64)
        started.wait()  # all three runs are in flight at once, or this times out
        with lock:
            seen.append((int(first), int(stop), threading.get_ident()))

    run_bands(kernel, 7, threads=3)
    assert sorted(s[:2] for s in seen) == [(0, 2), (2, 4), (4, 7)]
    assert len({s[2] for s in seen}) == 3
    assert [s[2] for s in seen if s[0] == 0] == [threading.get_ident()]


def test_the_default_thread_count_is_numbas_for_this_thread():
    idents: set[int] = set()
    before = nb.get_num_threads()
    nb.set_num_threads(1)
    try:
        run_bands(lambda a, b: idents.add(threading.get_ident()), 10)
    finally:
        nb.set_num_threads(before)
    assert idents == {threading.get_ident()}


def test_no_bands_calls_nothing():
    calls = []
    run_bands(lambda a, b: calls.append((a, b)), 0, threads=4)
    assert calls == []


def test_an_error_in_any_run_is_raised_after_all_runs_end():
    done = []

    def kernel(first, stop):
        if first == 2:
            raise ValueError("band 2 is bad")
        done.append(int(first))

    with pytest.raises(ValueError, match="band 2 is bad"):
        run_bands(kernel, 4, threads=4)
    assert sorted(done) == [0, 1, 3]


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs fork")
def test_a_forked_child_makes_its_own_threads():
    run_bands(lambda a, b: None, 4, threads=2)  # the parent's pool exists
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: the parent's pool thread is not here
        try:
            out = np.zeros(4)

            def kernel(first, stop):
                out[first:stop] = 1

            run_bands(kernel, 4, threads=2)
            os.write(w, b"ok" if out.sum() == 4 else b"bad")
        finally:
            os._exit(0)
    os.close(w)
    with os.fdopen(r, "rb") as pipe:
        answer = pipe.read()
    os.waitpid(pid, 0)
    assert answer == b"ok"
