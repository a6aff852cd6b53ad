"""The request handlers in process, against a state object (no socket, no subprocess).

The end-to-end tests (``test_service_requests.py`` and the others) send the same
requests to a real ``holo-service``; these call :data:`service.net.handlers.HANDLERS`
directly on a :class:`~service.net.state.ServiceState`.
"""

from __future__ import annotations

import pytest

from service.base.errors import MessageError
from service.net import protocol
from service.net.handlers import HANDLERS, error_code
from service.net.state import ServiceConfig, ServiceState, service_state


def call(st: ServiceState, mtype: str, **req) -> dict:
    """The reply fields of one request (``mtype`` plus ``req``)."""
    out = HANDLERS[mtype](st, {"type": mtype, **req})
    return out if out is None else out[0]


def code_of(st: ServiceState, mtype: str, **req) -> str:
    """The error code a request is refused with."""
    with pytest.raises(MessageError) as info:
        HANDLERS[mtype](st, {"type": mtype, **req})
    return info.value.code


@pytest.fixture
def st() -> ServiceState:
    return service_state(ServiceConfig())


@pytest.fixture
def scene_st(st: ServiceState) -> ServiceState:
    call(st, "load_scene", builtin="sphere-torus")
    return st


def test_every_message_type_has_a_handler():
    assert set(HANDLERS) == set(protocol.MESSAGE_TYPES)


def test_hello_agrees_a_version_and_names_the_session(st):
    r = call(st, "hello", versions=[protocol.VERSION, 99])
    assert r["version"] == protocol.VERSION
    assert r["session"] == st.session and r["status"] == "ready"
    assert r["limits"] == st.limits.as_dict()
    assert code_of(st, "hello", versions=[99]) == "bad_version"
    assert code_of(st, "hello", versions="1") == "bad_message"


def test_load_scene_replaces_the_scene_and_counts_versions(st):
    r = call(st, "load_scene", builtin="sphere-torus")
    assert r["objects"] == ["sphere", "torus"] and r["polygons"] > 0
    assert st.state.scene_version == 1 and len(st.state.scene.objects) == 2
    assert code_of(st, "load_scene", builtin="no-such-scene") == "not_found"
    assert code_of(st, "load_scene") == "bad_message"
    assert code_of(st, "load_scene", builtin="sphere-torus", path="x.obj") == "bad_message"
    assert st.state.scene_version == 1  # refused requests changed nothing


def test_update_objects_by_name_and_index_all_or_nothing(st, scene_st):
    assert code_of(service_state(ServiceConfig()), "update_objects", objects=[]) == "no_scene"
    before = st.state.scene_version
    r = call(st, "update_objects", objects=[{"name": "torus", "position": [0.0, 0.1, 0.0]}])
    assert r == {"updated": 1}
    assert list(st.state.scene.objects[1].transform.position) == [0.0, 0.1, 0.0]
    assert st.state.scene_version == before + 1
    bad = [{"index": 0, "position": [1.0, 0.0, 0.0]}, {"index": 5}]
    assert code_of(st, "update_objects", objects=bad) == "not_found"
    assert code_of(st, "update_objects", objects=[{"name": "nobody"}]) == "not_found"
    assert code_of(st, "update_objects", objects=[{}]) == "bad_message"
    assert list(st.state.scene.objects[0].transform.position) != [1.0, 0.0, 0.0]
    assert st.state.scene_version == before + 1


def test_set_display_makes_a_new_generation_and_refuses_bad_settings(st):
    r = call(st, "set_display", zones=3, method="bsp", encodings=["colour"])
    assert r["display"]["zones"] == 3 and r["display"]["method"] == "bsp"
    assert st.state.settings.generation == 1 and st.state.settings.encodings == ("colour",)
    assert code_of(st, "set_display", method="nope") == "bad_settings"
    assert code_of(st, "set_display", encodings=["x"]) == "bad_message"
    assert code_of(st, "set_display", quality="sometimes") == "bad_settings"
    assert st.state.settings.generation == 1


def test_set_viewer_takes_a_pose_or_devices_not_both(st):
    r = call(st, "set_viewer", position=[0.0, 0.0, 0.5])
    assert r["viewer"]["position"] == [0.0, 0.0, 0.5] and st.state.viewer.active
    r = call(st, "set_viewer", devices="tcp://127.0.0.1:5999")
    assert r["devices"] == st.state.devices == "tcp://127.0.0.1:5999"
    both = {"position": [0.0, 0.0, 1.0], "devices": None}
    assert code_of(st, "set_viewer", **both) == "bad_message"


def test_render_waits_for_a_scene_and_is_answered_later(st):
    assert code_of(st, "render") == "no_scene"
    call(st, "load_scene", builtin="sphere-torus")
    assert call(st, "render") is None  # the control loop answers it with the next render
    assert code_of(st, "render", encodings=["smell"]) == "bad_message"


def test_stats_without_sockets_or_workers(scene_st):
    s = call(scene_st, "stats")["stats"]
    assert s["split"] == "in_process" and s["workers"] is None and s["worker_pids"] == []
    assert s["frames_published"] == 0 and s["session"] == scene_st.session
    assert s["status"] == "ready"


def test_shutdown_sets_the_stop_event(st):
    assert not st.stop.is_set()
    assert call(st, "shutdown") == {}
    assert st.stop.is_set()


def test_unexpected_exceptions_map_to_error_codes():
    from service.base.errors import HoloError, MeshFileError, SettingsError

    assert error_code(SettingsError("x")) == "bad_settings"
    assert error_code(MeshFileError("a.obj", "line 3", "bad face")) == "not_found"
    assert error_code(HoloError("x")) == "bad_message"
    assert error_code(RuntimeError("x")) == "internal"


def test_load_object_from_a_file_only_inside_the_scene_dirs(tmp_path):
    import numpy as np

    from service.loaders.obj import save_obj
    from service.render.mesh import Mesh

    inside, outside = tmp_path / "in", tmp_path / "out"
    inside.mkdir(), outside.mkdir()
    mesh = Mesh.from_triangles(np.eye(3), [[0, 1, 2]])
    save_obj(inside / "tri.obj", mesh)
    save_obj(outside / "tri.obj", mesh)
    st = service_state(ServiceConfig(scene_dirs=(str(inside),)))
    assert call(st, "load_object", path=str(inside / "tri.obj"), name="tri") == {"index": 0}
    assert [o.name for o in st.state.scene.objects] == ["tri"]
    assert code_of(st, "load_object", path=str(outside / "tri.obj")) == "not_found"
    assert code_of(st, "load_object", path=str(inside / "none.obj")) == "not_found"
    assert len(st.state.scene.objects) == 1


def test_a_lone_mesh_file_is_fitted_to_the_services_display(st, tmp_path):
    # fitted to the default display, a tall mesh overran a wider, shorter --size
    import numpy as np

    from service.loaders import fit_view
    from service.loaders.obj import save_obj
    from service.render.mesh import Mesh

    mesh = Mesh.from_triangles(np.array([[0.0, -3, 0], [0, 3, 0], [1, 0, 0.5]]), [[0, 1, 2]])
    save_obj(tmp_path / "tall.obj", mesh)
    call(st, "set_display", zones=5, cols=200, rows=60)
    display = st.state.settings.display
    call(st, "load_scene", path=str(tmp_path / "tall.obj"))
    got, want = st.state.scene.objects[0].transform, fit_view(mesh.vertices, display)
    assert got.scale == pytest.approx(want.scale)
    assert np.allclose(got.position, want.position)
    assert want.scale != pytest.approx(fit_view(mesh.vertices, ServiceConfig().display).scale)
