"""Level of detail's warm-up job (:mod:`service.warmup` runs it): chains and clouds."""

from __future__ import annotations

from dataclasses import replace

from service.billboard_render import BillboardObject
from service.galilean.motion_field import render_with_motion
from service.lod.settings import LodSettings
from service.lod.state import LodState
from service.render.pipeline import Renderer, RenderSettings
from service.warmup_job import HERE, Job, Kit


def _level_of_detail(kit: Kit) -> None:
    """Level of detail (``--lod``): decimation errors, billboard clouds built and drawn.

    Clouds are drawn by the pipeline and by the service's Galilean render (with motion).
    """
    scene = kit.scene()
    lod = LodSettings(error_px=1e6, fractions=(0.5,), cloud_eps=(0.2,), texture_res=16)
    renderer = Renderer()
    # built in this process (its kernels are what is warmed), not written to the cache
    renderer.lod = LodState(cache=False, background=False)
    renderer.lod.prepare(scene, lod)
    renderer.render(scene, kit.display, RenderSettings(lod=lod))
    # the chain prepare built (a second build cost every service start 0.1-0.2 s)
    chain = renderer.lod.chain(scene.objects[-1].mesh, lod)
    boards = [BillboardObject(level) for level, kind in zip(chain.levels, chain.kinds,
                                                            strict=True) if kind == "billboard"]
    for method in ("zbuffer", "runlength", "bsp", "raycast"):
        renderer.render(replace(scene, billboards=boards), kit.display,
                        RenderSettings(method=method))
    # the service's workers draw clouds inside the Galilean render, with their motion
    render_with_motion(renderer, replace(scene, billboards=boards), kit.display, 0.0, 60.0)


#: This subsystem's jobs, in order (:data:`service.warmup.JOBS` gathers them).
WARMUP_JOBS: dict[str, Job] = {
    "level of detail, billboard clouds": Job(_level_of_detail, HERE),
}
