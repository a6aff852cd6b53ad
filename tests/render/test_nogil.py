"""Render kernels release the GIL, and renders in threads give the frames a serial one does."""

import importlib
import threading

import numpy as np
from numba.core.registry import CPUDispatcher

from service.builtin_scenes import builtin_scene
from service.display import DisplaySettings
from service.render.pipeline import Renderer

RENDER_MODULES = (
    "service.render.raster",
    "service.render.light",
    "service.render.depth_sort",
    "service.normals_kernel",
    "service.render.cull",
    "service.render.projection",
    "service.render.occlusion.zbuffer",
    "service.render.occlusion.runlength",
    "service.render.occlusion.bsp",
    "service.render.occlusion.raycast",
)


def kernels():
    for name in RENDER_MODULES:
        module = importlib.import_module(name)
        for attr, obj in vars(module).items():
            if isinstance(obj, CPUDispatcher) and obj.__module__ == name:
                yield f"{name}.{attr}", obj


def test_every_render_kernel_is_nogil_and_cached():
    found = dict(kernels())
    assert "service.render.raster.zbuffer_zones_kernel" in found
    assert "service.render.light._polygon_table" in found
    for name, kernel in found.items():
        assert kernel.targetoptions.get("nogil") is True, name
        assert kernel.targetoptions.get("nopython") is True, name
        assert kernel._cache.__class__.__name__ != "NullCache", name


def test_renders_in_threads_equal_a_serial_render():
    scene = builtin_scene("game")
    display = DisplaySettings(zones=5, cols=160, rows=120)
    want = Renderer().render(scene, display)
    got: list = []

    def work():
        renderer = Renderer()
        for _ in range(4):
            got.append(renderer.render(scene, display))

    threads = [threading.Thread(target=work) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(got) == 12
    for frame in got:
        assert np.array_equal(frame.colour, want.colour)
        assert np.array_equal(frame.depth, want.depth)
