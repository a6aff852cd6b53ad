"""Billboard clouds through the render service: a scene naming an ``.hbc`` file is
served, over the worker wire and in process, with the same pixels as a local render."""

from __future__ import annotations

import numpy as np
import pytest

from service.base.errors import ServiceError
from service.display import DisplaySettings
from service.loaders import load_scene
from service.net import wire
from service.net.client import ServiceClient
from service.primitives import sphere
from service.render.light import LightSettings
from service.render.pipeline import Renderer, RenderSettings
from service.simplify.billboard import build_cloud
from service.simplify.cloud_file import save_cloud

DISPLAY = DisplaySettings(zones=3, angle_deg=16.0, cols=48, rows=36)
SIZE = ("--zones", "3", "--size", "48x36", "--refresh", "30")


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    """A sphere mesh in front of a sphere's billboard cloud, named by a scene file."""
    folder = tmp_path_factory.mktemp("bb")
    ball = sphere(0.5, 10, 20)
    save_cloud(build_cloud(ball.vertices, ball.triangles, 0.03, texture_res=64),
               folder / "ball.hbc")
    (folder / "s.toml").write_text(
        '[[object]]\nfile = "ball.hbc"\nposition = [0.1, 0, -0.3]\n'
        'material = {colour = [1, 0.5, 0]}\n'
        '[[object]]\nprimitive = "sphere"\nparams = {radius = 0.2}\nposition = [-0.2, 0, 0.2]\n')
    return folder / "s.toml"


@pytest.mark.parametrize("workers", ["1", "0"], ids=["worker-wire", "in-process"])
def test_service_renders_a_scene_with_a_billboard_cloud(service_factory, scene_file, workers):
    svc = service_factory("--workers", workers, *SIZE)
    with ServiceClient(svc.control, timeout_s=60) as c:
        c.set_display(method="runlength", light_model="blinn", specular="polygon")
        c.load_scene(path=str(scene_file))
        local = Renderer().render(load_scene(scene_file), DISPLAY, RenderSettings(
            method="runlength", light=LightSettings("blinn", "polygon")))
        header, arrays = c.render_once()
        stats = header["stats"]
        bands = stats.get("bands") or [stats]
        board = bands[0]["billboards"]
        assert board["drawn_with"] == "zbuffer" and "runlength" in board["note"]
        assert board["quads"] == local.stats["billboards"]["quads"] > 0
        assert local.stats["billboards"]["covered_pixels"] > 100
        # the same frame, pixel for pixel, in every zone
        assert np.array_equal(arrays["colour"], local.colour)
        assert np.array_equal(arrays["depth"], local.depth)
        assert c.stats()["last_render_error"] == ""
        if workers == "0":  # bad input is one clear line, and the scene is kept
            with pytest.raises(ServiceError, match="load_scene") as info:
                c.load_object(path=str(scene_file.parent / "ball.hbc"))  # no mesh in it
            assert info.value.code == "bad_message"
            spec = wire.scene_to_wire(load_scene(scene_file))
            spec["billboards"][0]["cloud"]["tex_offset"] = \
                spec["billboards"][0]["cloud"]["tex_offset"] + 7  # texels past the end
            with pytest.raises(ServiceError, match=r"billboards\[0\]\.cloud\.tex_offset"):
                c.load_scene(scene=spec)
            assert np.array_equal(c.render_once()[1]["colour"], local.colour)
