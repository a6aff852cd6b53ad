"""Billboard clouds on the worker wire: numpy arrays plus a JSON header, each cloud
sent once, and a clear error for every malformed field (never a crash)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from service.base.errors import MessageError
from service.billboard_render import BillboardObject
from service.net import wire
from service.primitives import sphere
from service.render.scene import Material, Scene, Transform
from service.simplify.billboard import build_cloud


@pytest.fixture(scope="module")
def cloud():
    s = sphere(0.5, 8, 16)
    return build_cloud(s.vertices, s.triangles, 0.05, texture_res=32)


def _through_wire(scene: Scene) -> tuple[dict, list[np.ndarray]]:
    """The scene as frames would carry it: JSON text and raw little-endian buffers."""
    spec, arrays = wire.extract(wire.scene_to_wire(scene))
    frames = wire.encode({"scene": spec}, arrays)
    head = json.loads(frames[0])
    arrays = wire.decode_arrays(head.pop("arrays"), [bytes(f) for f in frames[1:]], 1 << 30)
    return head["scene"], arrays


def test_scene_with_billboards_round_trips_and_shares_a_cloud(cloud):
    place = Transform(np.array([0.1, 0.2, -0.3]), np.array([0.0, 0.6, 0.0, 0.8]), 1.5)
    scene = Scene([], billboards=[
        BillboardObject(cloud, Material(colour=(1.0, 0.5, 0.0), shininess=20.0), place, "a"),
        BillboardObject(cloud, Material(), Transform(), "b")])
    spec, arrays = _through_wire(scene)
    assert len(arrays) == 6  # one cloud's six arrays, though two objects use it
    assert spec["billboards"][1]["cloud_ref"] == 0
    back = wire.scene_from_wire(wire.resolve(spec, arrays))
    a, b = back.billboards
    assert a.cloud is b.cloud and (a.name, b.name) == ("a", "b")
    for key in wire.CLOUD_ARRAYS:
        assert np.array_equal(getattr(a.cloud, key), getattr(cloud, key)), key
        assert getattr(a.cloud, key).dtype == getattr(cloud, key).dtype, key
    assert a.cloud.eps == cloud.eps and a.cloud.source_faces == cloud.source_faces
    assert a.material == scene.billboards[0].material
    np.testing.assert_allclose(a.transform.position, place.position)
    np.testing.assert_allclose(a.transform.orientation, place.orientation)
    assert a.transform.scale == 1.5


def _spec(cloud) -> dict:
    return wire.scene_to_wire(Scene([], billboards=[BillboardObject(cloud)]))


def _broken(cloud, key, value) -> dict:
    spec = _spec(cloud)
    spec["billboards"][0]["cloud"][key] = value
    return spec


@pytest.mark.parametrize(("key", "value", "match"), [
    ("rgba", lambda c: c.rgba[:-1], "rgba"),                       # texels missing
    ("normal", lambda c: c.normal.astype(np.int16), "normal: dtype"),
    ("tex_offset", lambda c: c.tex_offset + 1, "tex_offset"),       # offsets past the end
    ("tex_shape", lambda c: c.tex_shape * 0, "tex_shape sides"),
    ("corners", lambda c: np.full_like(c.corners, np.nan), "non-finite"),
    ("corners", lambda c: c.corners[:, :1].repeat(4, axis=1), "zero-length side"),
    ("planes", lambda c: c.planes * np.array([2.0, 2.0, 2.0, 1.0]), "unit"),
    ("planes", lambda c: c.planes[:1], "shape"),
    ("planes", lambda c: [1, 2, 3], "planes must be"),
    ("rgba", lambda c: None, "rgba must be an array"),
    ("eps", lambda c: -1.0, "eps"),
])
def test_malformed_cloud_gets_a_clear_error(cloud, key, value, match):
    with pytest.raises(MessageError, match=match) as info:
        wire.scene_from_wire(_broken(cloud, key, value(cloud)))
    assert info.value.code in ("bad_array", "bad_message")
    assert "scene.billboards[0].cloud" in str(info.value)


@pytest.mark.parametrize(("field", "value", "match"), [
    ("cloud_ref", 0, "cloud_ref"), ("cloud", "x", "must be an object"),
    ("scale", -1.0, "scale"), ("orientation", [0, 0, 0, 0], "orientation"),
])
def test_malformed_billboard_object_gets_a_clear_error(cloud, field, value, match):
    spec = _spec(cloud)
    b = spec["billboards"][0]
    if field == "cloud_ref":
        del b["cloud"]
    b[field] = value
    with pytest.raises(MessageError, match=match):
        wire.scene_from_wire(spec)
    with pytest.raises(MessageError, match="list"):
        wire.scene_from_wire({"billboards": {}})


def test_a_cloud_of_more_than_65536_billboards_is_too_large_before_its_other_arrays():
    # mutants: `planes.shape[0] > MAX_BILLBOARDS` as `>=`, its raise deleted
    with pytest.raises(MessageError, match="more than 65536 billboards") as err:
        wire.cloud_from_wire({"planes": np.zeros((65537, 4))}, "c")
    assert err.value.code == "too_large"
    with pytest.raises(MessageError, match="c.corners must be an array"):
        wire.cloud_from_wire({"planes": np.zeros((65536, 4))}, "c")


def test_a_billboard_that_is_not_an_object_is_a_bad_message():
    # mutant: billboard_from_wire's "must be an object" raise deleted
    with pytest.raises(MessageError, match="b must be an object") as err:
        wire.billboard_from_wire([], "b", {})
    assert err.value.code == "bad_message"


@pytest.mark.parametrize("faces", [None, 0])
def test_source_faces_defaults_to_and_may_be_zero(cloud, faces):
    # mutants: source_faces' default 0 -> 1 and its lower bound 0 -> 1
    spec = _spec(cloud)["billboards"][0]["cloud"]
    spec.pop("source_faces")
    if faces is not None:
        spec["source_faces"] = faces
    assert wire.cloud_from_wire(spec, "c").source_faces == 0


def test_a_cloud_of_more_than_64m_texels_is_too_large_before_it_is_copied(cloud):
    # the limit's check came after every array was copied (256 MB more for an rgba
    # over it); the texel arrays here are zero-stride views of one texel: no memory
    import tracemalloc

    spec = _spec(cloud)["billboards"][0]["cloud"]
    for key, width in (("rgba", 4), ("normal", 3)):
        over = np.broadcast_to(spec[key][:1], (wire.MAX_TEXELS + 1, width))
        tracemalloc.start()  # numpy reports its allocations to tracemalloc
        try:
            with pytest.raises(MessageError, match=f"more than {wire.MAX_TEXELS} texels") as err:
                wire.cloud_from_wire({**spec, key: over}, "c")
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert err.value.code == "too_large"
        assert peak < 2**20, f"{peak} bytes allocated refusing {key}"
