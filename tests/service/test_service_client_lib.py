"""The client library against a real service: files, inline scenes, errors as exceptions."""

from __future__ import annotations

import numpy as np
import pytest
from testkit import TINY_DISPLAY

from service.base.errors import ServiceError
from service.loaders.obj import save_obj
from service.net.client import ServiceClient
from service.render.mesh import Mesh
from service.render.scene import MotionState, Scene, SceneObject, Transform


def test_library_calls(service_factory, tmp_path):
    svc = service_factory(*TINY_DISPLAY)
    mesh = Mesh.from_triangles([[-0.3, -0.3, 0], [0.3, -0.3, 0], [0, 0.3, 0.1]], [[0, 1, 2]])
    path = tmp_path / "tri.obj"
    save_obj(path, mesh)
    with ServiceClient(svc.control, timeout_s=10) as c:
        assert c.hello()["version"] == 1
        assert c.load_scene(path=str(path))["polygons"] == 1
        assert c.load_object(path=str(path), name="second") == 1
        ship = SceneObject(
            mesh,
            transform=Transform(np.array([0.0, 0.2, 0.0])),
            motion=MotionState(velocity=np.array([0.1, 0, 0])),
            name="ship",
        )
        assert c.load_object(ship) == 2
        assert c.update_objects([{"name": "ship", "position": np.array([0.1, 0.1, 0.0])}]) == 1
        header, arrays = c.render_once()
        assert arrays["colour"].shape == (2, 24, 32, 3) and arrays["colour"].any()
        assert c.load_scene(scene=Scene([ship, ship]))["objects"] == ["ship", "ship"]
        shown = c.set_display(zones=3, light_model="phong", specular="vertex", refresh_hz=30)
        assert shown["zones"] == 3 and shown["specular"] == "vertex"
        with pytest.raises(ServiceError) as info:
            c.set_display(galpixel_order=7)
        assert info.value.code == "bad_message"
        with pytest.raises(ServiceError) as info:
            c.load_scene(builtin="nothing")
        assert info.value.code == "not_found"
        assert c.heartbeat()
        c.shutdown()
    assert svc.proc.wait(15) == 0


def test_paths_limited_to_scene_dirs(service_factory, tmp_path):
    inside, outside = tmp_path / "scenes", tmp_path / "elsewhere"
    inside.mkdir()
    outside.mkdir()
    mesh = Mesh.from_triangles([[-0.3, -0.3, 0], [0.3, -0.3, 0], [0, 0.3, 0.1]], [[0, 1, 2]])
    save_obj(inside / "ok.obj", mesh)
    save_obj(outside / "no.obj", mesh)
    svc = service_factory(
        "--workers", "0", "--zones", "1", "--size", "16x12", "--scene-dir", str(inside)
    )
    with ServiceClient(svc.control, timeout_s=10) as c:
        assert c.load_scene(path=str(inside / "ok.obj"))["polygons"] == 1
        for bad in (outside / "no.obj", inside / ".." / "elsewhere" / "no.obj"):
            with pytest.raises(ServiceError) as info:
                c.load_scene(path=str(bad))
            assert info.value.code == "not_found" and "outside" in info.value.message
