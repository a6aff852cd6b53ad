"""The Galilean stage's warm-up jobs (:mod:`service.warmup` runs them).

Renders with motion, the refresh kernels and the head-motion update on made-up
maps (no render kernel: they run beside the render jobs, see
:data:`service.warmup_job.EARLY`), the plain
scatter (not on the first frame's path), every stage variant and the local updates.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from service.galilean import GalileanSettings, GalileanStage
from service.galilean.galpixmap import FIELDS, Galpixmap
from service.galilean.local_update import render_local
from service.galilean.motion_field import render_with_motion
from service.galilean.scatter_bands import scatter_bands, scatter_bands_plain
from service.render.light import LightSettings
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import MotionState
from service.warmup_job import APART, EARLY, FIRST, Job, Kit, stage_refreshes


def _motion(colour_motion: bool, model: str) -> Callable:
    def job(kit: Kit) -> None:
        settings = RenderSettings(method="zbuffer", light=LightSettings(model))
        render_with_motion(Renderer(), kit.scene(), kit.display, 0.1, 60.0, settings,
                           colour_motion=colour_motion)

    return job


def _refresh_kernels(kit: Kit) -> None:
    """The service refresh's stage kernels on made-up G(2) maps: no render kernel runs.

    The maps are laid out as ``stitch`` lays out a band render's (each field a
    C-contiguous copy), so the scatter, finish and show kernels compile for the types
    the engine's service-refresh job (:mod:`service.engine.warmup_jobs`) then loads
    them with.  Run beside the ``FIRST`` jobs in the second process (see
    :data:`EARLY`).  The viewer stays still: :func:`_head_motion` is the next job.
    """
    _made_up_refreshes(kit, moving=False)


def _head_motion(kit: Kit) -> None:
    """:func:`_refresh_kernels` with the viewer moving: the head-motion update's kernel too.

    A job of its own (1-1.5 s) so that the refresh kernels' job stays under issue 29's
    15 s a job while it shares the two cores with the render jobs (14.2 s at worst
    with both in one, 2026-11-29); the same kernels in all.
    """
    _made_up_refreshes(kit, moving=True)


def _galilean_kernels(kit: Kit) -> None:
    """Both made-up-map jobs: every refresh kernel of a G(2) stage, the viewer moving."""
    _refresh_kernels(kit)
    _head_motion(kit)


def _made_up_refreshes(kit: Kit, moving: bool) -> None:
    """Refreshes of a G(2) stage on two made-up maps, the viewer turning when ``moving``."""
    stage = GalileanStage(kit.display, GalileanSettings(order=2, refresh_hz=60.0))
    rng = np.random.default_rng(7)
    for k in range(2):
        stage.submit(made_up_map(stage, rng), stage.index + 1, None, True,
                     (), None, None, MotionState())
        if moving:
            stage.viewer(MotionState(velocity=[0.1 * k, 0.0, 0.0],
                                     angular_velocity=[0.0, 0.2, 0.0]))
        stage_refreshes(stage)


def made_up_map(stage: GalileanStage, rng: np.random.Generator) -> Galpixmap:
    """A random G(2) map for ``stage``, each field a C-contiguous copy (as ``stitch`` lays out).

    Every pixel covered (no debris, object 0), at random depths, colours, motions and
    fractions: every galpixel moves, so a refresh runs every branch of the scatter.
    """
    blank = Galpixmap.empty(2, stage.fixed, stage.shape)
    f = {n: np.array(getattr(blank, n)) for n in FIELDS}
    f["depth"][:] = rng.integers(2**20, 2**21, f["depth"].shape)
    f["debris"][:], f["obj"][:] = 0, 0
    f["colour"][:] = rng.uniform(0, 255, f["colour"].shape)
    f["motion"][:] = rng.integers(-3000, 3000, f["motion"].shape)
    f["frac"][:] = rng.integers(-100, 100, f["frac"].shape)
    return Galpixmap(order=2, fixed=stage.fixed, **f)


def _plain_scatter(kit: Kit) -> None:
    """:func:`scatter_bands_plain` for every signature :func:`scatter_bands` has here.

    A stage runs the plain kernel only once it is compiled or cached (see
    ``GalileanStage._plain_ready``); until then it runs :func:`scatter_bands` with the
    bookkeeping off, so the made-up-map job (first frame) compiles only that one and
    this job (the background phase) the plain one: the two kernels take the same
    arguments.  The made-up-map refreshes first load :func:`scatter_bands` (or
    compile it, run alone), then a new stage's refreshes run the plain kernel.
    """
    _galilean_kernels(kit)
    for sig in scatter_bands.signatures:
        scatter_bands_plain.compile(sig)
    _galilean_kernels(kit)


def _galilean_variants(kit: Kit) -> None:
    """Stage settings that take other kernels: orders 0-3, cache, margin, no Poisson."""
    renderer = Renderer()
    variants = [
        GalileanSettings(order=o, cache=c, margin=m, poisson=p, threads=th, expansion=e)
        for o, c, m, p, th, e in [
            (0, False, 0, True, 0, "average"), (1, True, 2, True, 1, "replicate"),
            (3, True, 0, False, 0, "average"), (2, False, 2, True, 1, "average"),
        ]
    ]
    up = render_with_motion(renderer, kit.scene(), kit.display, 0.1, 60.0)
    for s in variants:
        stage = GalileanStage(kit.display, s)
        stage.update(up)
        stage_refreshes(stage, 4)


def _galilean_local(kit: Kit) -> None:
    """Local updates (Flinders Street buffers with depth-only shadows), grafted."""
    stage = GalileanStage(kit.display, GalileanSettings(order=2))
    renderer = Renderer()
    for shadow in ("depth", "full"):
        local = render_local(renderer, kit.scene(), kit.display, [0], 0.1, 60.0, 2, stage.fixed,
                             shadow=shadow)
        stage.submit(local.buffer, None, (0,))
        stage_refreshes(stage)


#: This subsystem's jobs, in order (:data:`service.warmup.JOBS` gathers them).
WARMUP_JOBS: dict[str, Job] = {
    "motion field": Job(_motion(True, "blinn"), FIRST, service=True, first_frame=True),
    "motion field, no colour motion": Job(_motion(False, "ambient"), FIRST),
    "galilean: refresh kernels, made-up map": Job(_refresh_kernels, EARLY, first_frame=True),
    "galilean: head motion, made-up map": Job(_head_motion, EARLY, first_frame=True),
    "galilean: plain scatter": Job(_plain_scatter, APART),
    "galilean: orders, cache, margin": Job(_galilean_variants, APART, service=True),
    "galilean: local updates": Job(_galilean_local, APART),
}
