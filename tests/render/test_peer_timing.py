"""Peer timing: an untimed warm-up call each, then calls interleaved one by one.

A fake clock that the engines themselves advance stands for the machine: a first
call that compiles shaders, and a busy moment, cost what they cost there.
"""

import pytest

from service.bench.peers import PeerRun, interleaved_ms


class Machine:
    """A clock in seconds, advanced by the engines' calls; a log of the calls."""

    def __init__(self) -> None:
        self.now = 0.0
        self.calls: list[str] = []

    def clock(self) -> float:
        return self.now

    def engine(self, name: str, ms: float, first_ms: float | None = None):
        def call() -> str:
            first = name not in self.calls
            self.calls.append(name)
            busy = 50.0 if 7 <= len(self.calls) < 10 else 0.0  # a busy moment: 3 calls
            self.now += ((first_ms if first and first_ms else ms) + busy) / 1e3
            return name
        return call


def test_the_first_draw_is_not_timed():
    m = Machine()
    engines = {"ours": m.engine("ours", 2.0), "llvmpipe": m.engine("llvmpipe", 4.0, 900.0)}
    ms, out = interleaved_ms(engines, PeerRun(repeats=3, rounds=3), m.clock)
    assert ms == pytest.approx({"ours": 2.0, "llvmpipe": 4.0})  # the 900 ms shader compile left out
    assert out == {"ours": "ours", "llvmpipe": "llvmpipe"}
    assert m.calls.count("ours") == m.calls.count("llvmpipe") == 1 + 9


def test_calls_are_interleaved_one_by_one_in_a_rotating_order():
    m = Machine()
    engines = {n: m.engine(n, 1.0) for n in ("ours", "llvmpipe", "embree")}
    ms, _ = interleaved_ms(engines, PeerRun(repeats=2, rounds=2), m.clock)
    warm, timed = m.calls[:3], m.calls[3:]
    assert warm == ["ours", "llvmpipe", "embree"]
    turns = [timed[k:k + 3] for k in range(0, len(timed), 3)]
    assert turns == [["ours", "llvmpipe", "embree"], ["llvmpipe", "embree", "ours"],
                     ["embree", "ours", "llvmpipe"], ["ours", "llvmpipe", "embree"]]
    # the busy moment (3 calls in a row) fell on every engine once: medians untouched
    assert ms == pytest.approx({"ours": 1.0, "llvmpipe": 1.0, "embree": 1.0})
