"""Level of detail's warm-up jobs (:mod:`service.warmup` runs them): chains, clouds built, drawn.

Three jobs, not one: from an empty cache the one job took 17.5 s wall on a loaded
machine (20.5 s of CPU measured later), past issue 29's 15 s a job.  Split by the
kernels each compiles (``docs/compile-time.md``): the quadric chain's error and
normal-carrying kernels (:mod:`service.simplify.distance_kernel`), the cloud's build
(:mod:`service.simplify.billboard_kernel`), and its draw
(:mod:`service.billboard_render`).  Each runs alone too (``holo-warmup --job``).
"""

from __future__ import annotations

from dataclasses import replace

from service.billboard_render import BillboardObject
from service.galilean.motion_field import render_with_motion
from service.lod.settings import LodSettings
from service.lod.state import LodState
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import Scene
from service.warmup_job import HERE, Job, Kit

#: The chain the jobs build: one quadric level, and (the cloud jobs) one coarse cloud.
CHAIN = LodSettings(error_px=1e6, fractions=(0.5,), cloud_eps=(), texture_res=16)
CLOUD = replace(CHAIN, cloud_eps=(0.2,))


def _chains(kit: Kit) -> None:
    """Level of detail (``--lod``): a quadric chain (errors, carried normals) and a frame."""
    scene = kit.scene()
    renderer = Renderer()
    # built in this process (its kernels are what is warmed), not written to the cache
    renderer.lod = LodState(cache=False, background=False)
    renderer.lod.prepare(scene, CHAIN)
    renderer.render(scene, kit.display, RenderSettings(lod=CHAIN))


def _cloud_renderer(kit: Kit) -> tuple[Renderer, Scene]:
    """A renderer holding the cloud chain of the kit scene's last mesh, and its scene.

    Built once (the build job's; the draw job's when it runs alone).
    """
    if "lod cloud" not in kit.cache:
        one = Scene([kit.scene().objects[-1]])
        renderer = Renderer()
        renderer.lod = LodState(cache=False, background=False)
        renderer.lod.prepare(one, CLOUD)
        kit.cache["lod cloud"] = (renderer, one)
    return kit.cache["lod cloud"]


def _clouds_built(kit: Kit) -> None:
    """Billboard clouds built (planes, texture shoot, dilation, tiles) as a chain's level."""
    _cloud_renderer(kit)


def _clouds_drawn(kit: Kit) -> None:
    """Billboard clouds drawn: chosen by LOD, by each occlusion method, with motion."""
    renderer, scene = _cloud_renderer(kit)
    renderer.render(scene, kit.display, RenderSettings(lod=CLOUD))
    chain = renderer.lod.chain(scene.objects[0].mesh, CLOUD)
    boards = [BillboardObject(level) for level, kind in zip(chain.levels, chain.kinds,
                                                            strict=True) if kind == "billboard"]
    shown = replace(kit.scene(), billboards=boards)
    for method in ("zbuffer", "runlength", "bsp", "raycast"):
        renderer.render(shown, kit.display, RenderSettings(method=method))
    # the service's workers draw clouds inside the Galilean render, with their motion
    render_with_motion(renderer, shown, kit.display, 0.0, 60.0)


#: This subsystem's jobs, in order (:data:`service.warmup.JOBS` gathers them).
WARMUP_JOBS: dict[str, Job] = {
    "level of detail: chains": Job(_chains, HERE),
    "billboard clouds: build": Job(_clouds_built, HERE, after="level of detail: chains"),
    "billboard clouds: draw": Job(_clouds_drawn, HERE, after="billboard clouds: build"),
}
