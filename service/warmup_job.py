"""One warm-up job: what it runs, on which inputs, and where :func:`service.warmup.warm_up` runs it.

Each subsystem registers its own jobs in its ``warmup_jobs`` module (a ``JOBS``
table of :class:`Job`; :data:`service.warmup.JOB_MODULES` names the modules), so a
new kernel's warm-up goes beside the kernel.  A job runs the real code path on the
tiny inputs of a :class:`Kit`, so its kernels compile for the types they are really
called with.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from service.builtin_scenes import SCENES
from service.display import DisplaySettings

#: Where a job runs when :func:`warm_up` has two processes: ``FIRST`` jobs run
#: before the split (the render path every Galilean job calls), then ``APART``
#: jobs run in a second process while this one runs the ``HERE`` jobs; once its
#: ``APART`` jobs are done the second process takes ``HERE`` jobs too, each job
#: claimed by whichever process is free first (:func:`service.warmup.claim`; a
#: job's ``after`` keeps one that reaches another's kernels with it), so the two
#: end close together whatever each job costs.  Jobs running at once should
#: compile disjoint kernels: two processes compiling one kernel both pay for it
#: (numba's cache saves are locked between processes,
#: :func:`service.numba_patches.locked_cache_saves`, so the cache stays right).
#: Render kernels that only a Galilean job reached (the depth-only shadows)
#: compile in the first ``HERE`` job, before the second process gets to them: it
#: then loads them.  ``EARLY`` jobs start the second process as soon as a
#: ``FIRST`` job had to compile, and run there beside the rest of the ``FIRST``
#: jobs, so they must reach none of their kernels: the Galilean stage's kernels
#: on a made-up map (the scatter kernels, none shared with the render path:
#: checked 2026-11-26).  The second process holds its ``APART`` jobs until this
#: one's ``FIRST`` jobs end.
FIRST, HERE, APART, EARLY = "first", "here", "apart", "early"
#: The order the parts run in: jobs are gathered and stably sorted by it.
PARTS = (FIRST, EARLY, APART, HERE)


@dataclass
class Kit:
    """Small inputs the jobs share (built once, on first use)."""

    display: DisplaySettings = field(
        default_factory=lambda: DisplaySettings(zones=3, angle_deg=16.0, cols=24, rows=16)
    )
    cache: dict[str, Any] = field(default_factory=dict)

    def scene(self, name: str = "game") -> Any:
        """A built-in scene (cached)."""
        if name not in self.cache:
            self.cache[name] = SCENES[name]()
        return self.cache[name]


@dataclass(frozen=True)
class Job:
    """A warm-up job: ``run(kit)`` and where it runs (``part``, one of :data:`PARTS`)."""

    run: Callable[[Kit], None]
    part: str
    #: a ``holo-service`` loads it before it is ready (:data:`service.warmup.SERVICE_JOBS`)
    service: bool = False
    #: a cold ``holo-service`` compiles it before its first frame
    #: (:data:`service.warmup.FIRST_FRAME_JOBS`)
    first_frame: bool = False
    #: a ``HERE`` job whose kernels that earlier job compiles too: whichever process
    #: claims that one runs this one (:func:`service.warmup.claim`), so the two
    #: processes never compile one kernel at once
    after: str = ""


def stage_refreshes(stage: Any, n: int = 3) -> None:
    """``n`` refreshes of a Galilean stage (the refresh kernels of its settings)."""
    for _ in range(n):
        stage.refresh()
