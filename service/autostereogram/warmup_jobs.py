"""The autostereogram output's warm-up job (:mod:`service.warmup` runs it)."""

from __future__ import annotations

from service.autostereogram.output import warm_up_sird
from service.warmup_job import HERE, Job, Kit


def _autostereograms(kit: Kit) -> None:
    """The autostereogram output's kernels (service encoding, game mode, holo-sird)."""
    for method in ("row", "interpolated", "tiw"):
        warm_up_sird(method)


#: This subsystem's jobs, in order (:data:`service.warmup.JOBS` gathers them).
WARMUP_JOBS: dict[str, Job] = {
    "autostereograms: row, interpolated, tiw": Job(_autostereograms, HERE, service=True,
                                                   first_frame=True),
}
