"""The autostereogram output's warm-up jobs (:mod:`service.warmup` runs them)."""

from __future__ import annotations

from collections.abc import Callable

from service.autostereogram.output import warm_up_sird
from service.warmup_job import HERE, Job, Kit


def _autostereograms(*methods: str) -> Callable[[Kit], None]:
    """A job compiling these methods' kernels (service encoding, game mode, holo-sird)."""

    def job(kit: Kit) -> None:
        for method in methods:
            warm_up_sird(method)

    return job


#: This subsystem's jobs, in order (:data:`service.warmup.JOBS` gathers them).  Two
#: jobs, each under the 15 s budget: the three methods together compiled 20 signatures
#: in 16.5 s of CPU at load 5-12, tiw 10.2 of them (docs/compile-time.md, 2026-11-29).
WARMUP_JOBS: dict[str, Job] = {
    "autostereograms: row, interpolated": Job(_autostereograms("row", "interpolated"), HERE,
                                              service=True, first_frame=True),
    "autostereograms: tiw": Job(_autostereograms("tiw"), HERE, service=True, first_frame=True),
}
