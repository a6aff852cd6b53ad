"""Pure protocol and wire functions: frames <-> dicts and arrays, every check."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from service.base.errors import MessageError
from service.builtin_scenes import builtin_scene
from service.net import protocol, wire


def _body(frames: list) -> list[bytes]:
    return [bytes(f) for f in frames[1:]]  # drop the empty delimiter


def test_request_round_trip_with_arrays():
    a = np.arange(12, dtype=np.float32).reshape(4, 3)
    b = np.array([[0, 1, 2]], np.int64)
    frames = protocol.request(
        "load_object", 5, {"object": {"mesh": {"vertices": a, "triangles": b}}}
    )
    req = protocol.parse_request(_body(frames))
    got = req["object"]["mesh"]
    assert req["id"] == 5 and req["type"] == "load_object"
    np.testing.assert_array_equal(got["vertices"], a)
    np.testing.assert_array_equal(got["triangles"], b)
    assert not got["vertices"].flags.writeable  # a view on the frame, no copy


def test_scene_round_trip_shares_meshes():
    scene = builtin_scene("game")
    spec, arrays = wire.extract(wire.scene_to_wire(scene))
    assert sum("mesh_ref" in o for o in spec["objects"]) == 5  # six attackers, one mesh
    back = wire.scene_from_wire(wire.resolve(json.loads(json.dumps(spec)), arrays))
    assert [o.name for o in back.objects] == [o.name for o in scene.objects]
    assert back.objects[2].mesh is back.objects[3].mesh
    np.testing.assert_allclose(
        back.objects[1].transform.position, scene.objects[1].transform.position
    )
    np.testing.assert_allclose(
        back.objects[1].motion.angular_velocity, scene.objects[1].motion.angular_velocity
    )


@pytest.mark.parametrize(
    ("body", "code"),
    [
        ([], "bad_frames"),
        ([b"\xff\xfe"], "bad_json"),
        ([b"1"], "bad_json"),
        ([b'{"type": "ping"}'], "bad_version"),
        ([b'{"v": 1, "type": "nope"}'], "unknown_type"),
        ([b'{"v": 1, "type": "ping", "id": true}'], "bad_message"),
        (
            [b'{"v": 1, "type": "ping", "arrays": [{"dtype": "f8", "shape": [1]}]}', b"\0" * 8],
            "bad_array",
        ),
        (
            [
                b'{"v": 1, "type": "ping", "arrays": [{"dtype": "float64", "shape": [2]}]}',
                b"\0" * 8,
            ],
            "bad_array",
        ),
        (
            [
                b'{"v": 1, "type": "ping", "arrays": [{"dtype": "float64", "shape": [1,1,1,1,1]}]}',
                b"\0" * 8,
            ],
            "too_large",
        ),
        (
            [
                b'{"v": 1, "type": "ping", "arrays": [{"dtype": "float64", "shape": [1]}]}',
                b"\0" * 8,
            ],
            "bad_message",
        ),  # a buffer nobody refers to
        ([b'{"v": 1, "type": "ping", "x": {"$array": 3}}'], "bad_message"),
    ],
)
def test_parse_errors(body, code):
    with pytest.raises(MessageError) as info:
        protocol.parse_request(body)
    assert info.value.code == code


def test_every_descriptor_says_raw_encoding():
    """protocol.md 1.4 / 2: each array descriptor carries ``"encoding": "raw"``."""
    a = np.zeros((2, 3), np.float32)
    assert wire.describe(a, "depth") == {
        "dtype": "float32",
        "shape": [2, 3],
        "encoding": "raw",
        "name": "depth",
    }
    head = json.loads(protocol.reply([], 1, "render", {}, [a, a.astype(np.uint8)], ["d", "c"])[0])
    assert [d["encoding"] for d in head["arrays"]] == ["raw", "raw"]
    head = json.loads(protocol.request("load_object", 1, {"x": a})[1])
    assert head["arrays"][0]["encoding"] == "raw"


@pytest.mark.parametrize("encoding", [None, "raw"])
def test_raw_or_absent_encoding_is_accepted(encoding):
    desc = {"dtype": "float64", "shape": [1]}
    if encoding is not None:
        desc["encoding"] = encoding
    head = {"v": 1, "type": "ping", "x": {"$array": 0}, "arrays": [desc]}
    req = protocol.parse_request([json.dumps(head).encode(), np.ones(1).tobytes()])
    np.testing.assert_array_equal(req["x"], [1.0])


@pytest.mark.parametrize("encoding", ["zlib", "", 1, None])
def test_unknown_encoding_is_bad_message(encoding):
    desc = {"dtype": "float64", "shape": [1], "encoding": encoding}
    head = {"v": 1, "type": "ping", "x": {"$array": 0}, "arrays": [desc]}
    with pytest.raises(MessageError) as info:
        protocol.parse_request([json.dumps(head).encode(), np.ones(1).tobytes()])
    assert info.value.code == "bad_message" and "encoding" in info.value.message


def test_error_reply_keeps_id_and_type():
    with pytest.raises(MessageError) as info:
        protocol.parse_request([b'{"v": 7, "type": "ping", "id": "r1"}'])
    assert info.value.partial == {"id": "r1", "type": "ping"}
    frames = protocol.error_reply([b"peer", b""], "r1", "ping", "bad_version", "v 7")
    header = json.loads(frames[2])
    assert frames[:2] == [b"peer", b""]
    assert header == {
        "v": 1,
        "id": "r1",
        "type": "ping",
        "ok": False,
        "error": {"code": "bad_version", "message": "v 7"},
    }


@pytest.mark.parametrize(
    ("value", "code"),
    [
        ([1.0, float("nan"), 0.0], "not_finite"),
        ([1.0, 2.0], "bad_message"),
        (["a", 1, 2], "bad_message"),
        (np.array([1, 2, 3], np.int32), "bad_array"),
        (np.array([1.0, np.inf, 3.0]), "not_finite"),
    ],
)
def test_vector_checks(value, code):
    with pytest.raises(MessageError) as info:
        wire.vector(value, "v", 3)
    assert info.value.code == code


def test_big_buffers_are_sent_without_copy():
    import zmq

    ctx = zmq.Context()
    a, b = ctx.socket(zmq.PAIR), ctx.socket(zmq.PAIR)
    try:
        a.bind("inproc://wire-test")
        b.connect("inproc://wire-test")
        big = np.random.default_rng(1).random((300, 300)).astype(np.float32)  # 360 kB
        assert wire.send(a, wire.encode({"k": 1}, [big], ["big"]), 1000)
        assert b.poll(1000)
        header = protocol.parse_reply(b.recv_multipart())
        np.testing.assert_array_equal(header["arrays"]["big"], big)
    finally:
        a.close(0)
        b.close(0)
        ctx.term()


def test_send_gives_up_after_its_timeout_on_a_full_pipe_and_sends_nothing_half():
    import zmq

    ctx = zmq.Context()
    a, b = ctx.socket(zmq.PAIR), ctx.socket(zmq.PAIR)
    try:
        for s in (a, b):
            s.setsockopt(zmq.SNDHWM, 1)
            s.setsockopt(zmq.RCVHWM, 1)
        a.bind("inproc://wire-full")
        b.connect("inproc://wire-full")
        msg = wire.encode({"k": 1}, [np.arange(4, dtype=np.int32)], ["n"])
        sent = 0
        while wire.send(a, msg, 0):  # fill the pipe: nobody reads
            sent += 1
            assert sent < 100
        t0 = time.monotonic()
        assert not wire.send(a, wire.encode({"k": 2}, [], []), 200)
        assert 0.15 <= time.monotonic() - t0 < 5
        got = []
        while b.poll(200):
            got.append(protocol.parse_reply(b.recv_multipart())["k"])
        assert got == [1] * sent  # the refused message left no part behind
    finally:
        a.close(0)
        b.close(0)
        ctx.term()


def test_number_takes_its_bounds_inclusive_and_refuses_beyond():
    # mutant: the range check's raise deleted (an out-of-range number accepted)
    assert wire.number(0.0, "x", 0.0, 1.0) == 0.0 and wire.number(1, "x", 0.0, 1.0) == 1.0
    for bad in (-1e-9, 1.000001):
        with pytest.raises(MessageError, match=r"x must be in \[0.0, 1.0\]") as err:
            wire.number(bad, "x", 0.0, 1.0)
        assert err.value.code == "bad_message"


@pytest.mark.parametrize("bad", [True, 2.0, "2", None, -1, 11])
def test_integer_refuses_bools_floats_strings_and_out_of_range(bad):
    # mutants: integer()'s `or`s as `and`, its raise deleted
    with pytest.raises(MessageError, match=r"n must be an integer in \[0, 10\]"):
        wire.integer(bad, "n", 0, 10)


def test_integer_gives_a_python_int_at_both_bounds():
    # mutant: `return int(v)` replaced (None returned)
    got = [wire.integer(v, "n", 0, 10) for v in (0, np.int64(10))]
    assert got == [0, 10] and all(type(v) is int for v in got)


def test_string_takes_4096_characters_by_default_and_not_more():
    # mutant: max_len default 4096 -> 4097
    assert wire.string("x" * 4096, "s") == "x" * 4096
    with pytest.raises(MessageError, match="longer than 4096") as err:
        wire.string("x" * 4097, "s")
    assert err.value.code == "too_large"


@pytest.mark.parametrize(("descs", "code", "words"), [
    ({"dtype": "uint8"}, "bad_message", "must be a list"),
    ([{"dtype": "uint8", "shape": [0]}] * 1025, "too_large", r"1025 arrays \(max 1024\)"),
])
def test_array_descriptors_not_a_list_or_too_many_are_refused(descs, code, words):
    # mutants: the two raises deleted, `len(descs) > MAX_ARRAYS` as `>=`, MAX_ARRAYS changed
    buffers = [b""] * (len(descs) if isinstance(descs, list) else 1)
    with pytest.raises(MessageError, match=words) as err:
        wire.decode_arrays(descs, buffers, 1 << 20)
    assert err.value.code == code


def test_1024_arrays_are_accepted():
    got = wire.decode_arrays([{"dtype": "uint8", "shape": [0]}] * 1024, [b""] * 1024, 1 << 20)
    assert len(got) == 1024


def test_as_wire_sends_big_endian_as_little_and_refuses_other_dtypes():
    # mutants: the byte-order test flipped, the bad-dtype raise deleted
    a = np.arange(3, dtype=">i4")
    got = wire.as_wire(a)
    assert got.dtype == np.dtype("<i4") and got.tolist() == [0, 1, 2]
    assert wire.as_wire(np.arange(3, dtype="<f8")).dtype == np.dtype("<f8")
    for bad in (np.zeros(2, np.complex64), np.zeros(2, np.float16), np.zeros(2, "U1")):
        with pytest.raises(MessageError, match="cannot be sent") as err:
            wire.as_wire(bad)
        assert err.value.code == "bad_array"


def _code(call) -> str:
    with pytest.raises(MessageError) as err:
        call()
    return err.value.code


def test_float_array_checks_type_shape_rows_and_finiteness():
    # mutants: float_array's `or`s as `and`, its three raises deleted, `>` as `>=`
    ok = np.zeros((3, 2), np.float32)
    got = wire.float_array(ok, "v", 2, 3)
    assert got.dtype == np.float64 and got.shape == (3, 2)
    assert _code(lambda: wire.float_array(ok.tolist(), "v", 2, 3)) == "bad_array"
    assert _code(lambda: wire.float_array(ok.astype(np.int32), "v", 2, 3)) == "bad_array"
    assert _code(lambda: wire.float_array(ok.ravel(), "v", 2, 3)) == "bad_array"
    assert _code(lambda: wire.float_array(ok, "v", 3, 3)) == "bad_array"
    assert _code(lambda: wire.float_array(ok, "v", 2, 2)) == "too_large"
    assert _code(lambda: wire.float_array(np.full((1, 2), np.nan), "v", 2, 3)) == "not_finite"


def test_int_array_checks_type_dims_and_rows():
    # mutants: int_array's `or`s as `and`, its two raises deleted, `>` as `>=`
    ok = np.zeros((3, 3), np.int32)
    got = wire.int_array(ok, "t", 2, 3)
    assert got.dtype == np.int64 and got.shape == (3, 3)
    assert _code(lambda: wire.int_array(ok.tolist(), "t", 2, 3)) == "bad_array"
    assert _code(lambda: wire.int_array(ok.astype(np.float32), "t", 2, 3)) == "bad_array"
    assert _code(lambda: wire.int_array(ok, "t", 1, 3)) == "bad_array"
    assert _code(lambda: wire.int_array(ok, "t", 2, 2)) == "too_large"


def test_list_fields_must_be_lists_of_at_most_max_len():
    # mutants: _list's raises deleted, `len(v) > max_len` as `>=`
    assert wire._list([1, 2], "l", 2) == [1, 2]
    assert _code(lambda: wire._list((1, 2), "l", 2)) == "bad_message"
    assert _code(lambda: wire._list([1, 2, 3], "l", 2)) == "too_large"


@pytest.mark.parametrize("parse", [wire.mesh_from_wire, wire.material_from_wire,
                                   wire.light_from_wire, wire.object_from_wire])
def test_object_fields_that_are_not_objects_are_bad_messages(parse):
    # mutants: the "must be an object" raises deleted
    with pytest.raises(MessageError, match="x must be an object") as err:
        parse([1, 2], "x")
    assert err.value.code == "bad_message"


def test_material_and_light_fields_and_their_defaults():
    # mutants: material_from_wire's None default, `"colour" in spec` and both returns
    # replaced; light_from_wire's return replaced
    from service.render.scene import Light, Material
    assert wire.material_from_wire(None, "m") == Material()
    m = wire.material_from_wire({"colour": [0.5, 0.25, 1.0], "shininess": 8}, "m")
    assert m.colour == (0.5, 0.25, 1.0) and m.shininess == 8.0
    assert wire.material_from_wire({"ambient": 0.5}, "m").colour == Material().colour
    light = wire.light_from_wire({}, "l")
    assert isinstance(light, Light) and light.intensity == 1.0
    assert wire.light_from_wire({"kind": "point", "intensity": 3}, "l").kind == "point"


def test_an_array_over_max_bytes_is_too_large_and_one_at_it_is_read():
    # mutants: `nbytes > max_bytes` as `>=`, its raise deleted
    desc = [{"dtype": "float32", "shape": [4]}]
    assert wire.decode_arrays(desc, [bytes(16)], 16)[0].shape == (4,)
    with pytest.raises(MessageError, match=r"arrays\[0\] has 16 bytes \(max 15\)") as err:
        wire.decode_arrays(desc, [bytes(16)], 15)
    assert err.value.code == "too_large"


def test_a_scene_that_is_not_an_object_is_a_bad_message():
    # mutant: the "scene must be an object" raise deleted
    assert _code(lambda: wire.scene_from_wire([])) == "bad_message"


def test_mesh_from_wire_builds_triangle_meshes_and_names_bad_indices():
    # mutants: the triangle path's return replaced, the MeshError -> bad_message raise
    # deleted
    verts = np.eye(3, dtype=np.float64)
    mesh = wire.mesh_from_wire({"vertices": verts, "triangles": np.array([[0, 1, 2]])}, "m")
    np.testing.assert_array_equal(mesh.vertices, verts)
    with pytest.raises(MessageError, match="^bad_message: m: ") as err:
        wire.mesh_from_wire({"vertices": verts, "triangles": np.array([[0, 1, 7]])}, "m")
    assert err.value.code == "bad_message"


def test_material_fields_are_used_and_an_impossible_material_is_a_bad_message():
    # mutants: `key in spec` as `not in`, the SettingsError -> bad_message raise deleted
    m = wire.material_from_wire({"ambient": 0.5, "diffuse": 0.25}, "m")
    assert (m.ambient, m.diffuse) == (0.5, 0.25)
    for bad in ({"colour": [2, 0, 0]}, {"shininess": 0.5}):
        with pytest.raises(MessageError, match="^bad_message: m: ") as err:
            wire.material_from_wire(bad, "m")
        assert err.value.code == "bad_message"


def test_orientation_is_normalised_and_scale_applied():
    # mutants: `q / norm` as `q * norm`, `"scale" in spec` as `not in`
    from service.render.scene import Transform
    t = wire.transform_from_wire({"orientation": [0, 0, 0, 1.5], "scale": 2}, "o", Transform())
    assert np.linalg.norm(t.orientation) == pytest.approx(1.0) and t.scale == 2.0
    assert wire.transform_from_wire({}, "o", Transform()).scale == Transform().scale


def test_a_light_of_an_unknown_kind_is_a_bad_message_and_a_scene_holds_64_lights():
    # mutants: light_from_wire's SettingsError -> bad_message raise deleted, the
    # scene's 64-light bound changed
    assert _code(lambda: wire.light_from_wire({"kind": "spot"}, "l")) == "bad_message"
    assert len(wire.scene_from_wire({"lights": [{}] * 64}).lights) == 64
    assert _code(lambda: wire.scene_from_wire({"lights": [{}] * 65})) == "too_large"


def test_a_negative_dimension_is_a_bad_array():
    # mutant: `n >= 0` in the shape check changed
    with pytest.raises(MessageError, match="non-negative ints") as err:
        wire.decode_arrays([{"dtype": "uint8", "shape": [-1]}], [b""], 16)
    assert err.value.code == "bad_array"


def test_triangles_must_have_three_columns():
    # mutants: `tri.shape[1] != 3` changed, its raise deleted
    verts = np.zeros((4, 3), np.float64)
    with pytest.raises(MessageError, match=r"m.triangles must have shape \(T, 3\)") as err:
        wire.mesh_from_wire({"vertices": verts, "triangles": np.array([[0, 1, 2, 3]])}, "m")
    assert err.value.code == "bad_array"


@pytest.mark.parametrize(("q", "ok"), [([0, 0, 0, 0.5], False), ([0, 0, 0, 0.51], True),
                                       ([0, 0, 0, 1.99], True), ([0, 0, 0, 2.0], False)])
def test_an_orientation_needs_a_norm_strictly_between_half_and_two(q, ok):
    # mutants: `0.5 < norm < 2.0` with either < as <=
    from service.render.scene import Transform
    if ok:
        t = wire.transform_from_wire({"orientation": q}, "o", Transform())
        assert np.linalg.norm(t.orientation) == pytest.approx(1.0)
    else:
        assert _code(lambda: wire.transform_from_wire({"orientation": q}, "o",
                                                       Transform())) == "bad_message"


@pytest.mark.parametrize("ref", [1, 5, "0", None])
def test_a_mesh_ref_must_name_an_earlier_object(ref):
    # mutants: the mesh_ref check's `and` as `or`, its raise deleted (a KeyError)
    mesh = {"vertices": np.eye(3, dtype=np.float64), "triangles": np.array([[0, 1, 2]])}
    spec = {"objects": [{"mesh": mesh}, {"mesh_ref": ref}]}
    with pytest.raises(MessageError, match=r"objects\[1\].mesh_ref must name an earlier"):
        wire.scene_from_wire(spec)
    shared = wire.scene_from_wire({"objects": [{"mesh": mesh}, {"mesh_ref": 0}]})
    assert shared.objects[1].mesh is shared.objects[0].mesh


@pytest.mark.parametrize("ref", [-1, 1, True, "0"])
def test_an_array_reference_out_of_range_is_a_bad_message(ref):
    # mutants: `0 <= i < len(arrays)` with either < as <= (an IndexError, or index 0 refused)
    a = np.zeros(2)
    assert wire.resolve({"x": {"$array": 0}}, [a])["x"] is a
    assert _code(lambda: wire.resolve({"x": {"$array": ref}}, [a])) == "bad_message"


def test_a_light_defaults_to_white_from_above_and_in_front():
    # mutants: the default colour's and vector's numbers changed
    light = wire.light_from_wire({}, "l")
    assert light.colour == (1.0, 1.0, 1.0) and light.kind == "directional"


def test_split_envelope_with_and_without_the_empty_delimiter():
    # mutant: the no-delimiter return replaced
    assert protocol.split_envelope([b"id", b"", b"h", b"a"]) == ([b"id", b""], [b"h", b"a"])
    assert protocol.split_envelope([b"id", b"h", b"a"]) == ([b"id"], [b"h", b"a"])
    assert protocol.split_envelope([b"id"]) == ([b"id"], [])


def _ping(**extra) -> bytes:
    return json.dumps({"v": 1, "type": "ping", **extra}).encode()


def test_request_limits_take_their_bound_and_refuse_one_more():
    # each cap inclusive: mutants of parse_request's `>` comparisons (as `>=`)
    desc = [{"dtype": "uint8", "shape": [4]}]
    head = _ping(arrays=desc, x={"$array": 0})
    limits = protocol.Limits(max_frames=3, max_request_bytes=len(head) + 4)
    assert protocol.parse_request([head, bytes(4)], limits)["x"].shape == (4,)
    too = [(lambda: protocol.parse_request([head, bytes(4), b""], limits), "frames"),
           (lambda: protocol.parse_request(
               [head, bytes(4)], protocol.Limits(max_request_bytes=len(head) + 3)), "bytes")]
    for call, words in too:
        with pytest.raises(MessageError, match=words) as err:
            call()
        assert err.value.code == "too_large"
    h = _ping(s="12345")
    assert protocol.parse_request([h], protocol.Limits(max_header_bytes=len(h), max_string=5))
    for lim in (protocol.Limits(max_header_bytes=len(h) - 1),
                protocol.Limits(max_string=4)):
        with pytest.raises(MessageError) as err:
            protocol.parse_request([h], lim)
        assert err.value.code == "too_large"


@pytest.mark.parametrize(("key", "value", "code"), [
    ("id", "abcd", None), ("id", "abcde", "too_large"), ("id", "", "bad_message"),
    ("id", True, "bad_message"), ("id", 7, None), ("client_id", 7, "bad_message"),
    ("client_id", "abcd", None), ("client_id", "abcde", "too_large"),
])
def test_ids_are_ints_or_short_non_empty_strings(key, value, code):
    # mutants: _check_token's checks (kinds, "", len > max_id) and check_id's bound
    limits = protocol.Limits(max_id=4)
    body = [_ping(**{key: value})]
    if code is None:
        assert protocol.parse_request(body, limits)[key] == value
        return
    with pytest.raises(MessageError) as err:
        protocol.parse_request(body, limits)
    assert err.value.code == code


def test_check_id_keeps_ints_and_short_strings_only():
    limits = protocol.Limits(max_id=4)
    assert [protocol.check_id(v, limits) for v in (3, "abcd", "abcde", True, 1.5, None)] \
        == [3, "abcd", None, None, None, None]


def test_an_unknown_type_of_at_most_64_characters_is_echoed_in_the_error():
    # mutant: _readable_type's 64-character bound changed
    for t, echoed in (("x" * 64, True), ("x" * 65, False)):
        with pytest.raises(MessageError) as err:
            protocol.parse_request([json.dumps({"v": 1, "type": t}).encode()])
        assert err.value.code == "unknown_type"
        assert err.value.partial["type"] == (t if echoed else None)


def test_check_request_size_takes_each_bound_and_refuses_one_more():
    # mutants: check_request_size's comparisons (as >=) and raises
    frames = [b"", b"h" * 10, bytes(5), bytes(5)]
    ok = protocol.Limits(max_frames=4, max_header_bytes=10, max_array_bytes=5,
                         max_request_bytes=20)
    protocol.check_request_size(frames, ok)
    for change in (dict(max_frames=3), dict(max_header_bytes=9), dict(max_array_bytes=4),
                   dict(max_request_bytes=19)):
        lim = protocol.Limits(**{**ok.as_dict(), **change})
        with pytest.raises(MessageError) as err:
            protocol.check_request_size(frames, lim)
        assert err.value.code == "too_large"


def test_limits_from_a_hello_reply_ignore_unknown_keys_and_default_missing_ones():
    # mutants: Limits.as_dict's and Limits.from_dict's returns replaced
    got = protocol.Limits.from_dict({"max_id": "8", "max_frames": 10, "future_key": 1})
    assert got == protocol.Limits(max_id=8, max_frames=10)
    assert protocol.Limits.from_dict(got.as_dict()) == got
    assert got.as_dict()["max_string"] == protocol.Limits().max_string


def test_parse_reply_names_arrays_when_all_have_names_and_refuses_an_empty_reply():
    # mutants: parse_reply's "empty reply" raise deleted (an IndexError), its
    # `names and all(...)` as `or`
    a, b = np.arange(3, dtype=np.int32), np.ones(2)
    named = protocol.reply([], 4, "render", {"x": 1}, [a, b], ["depth", "mask"])
    got = protocol.parse_reply([bytes(f) for f in named])
    assert set(got["arrays"]) == {"depth", "mask"} and got["x"] == 1
    plain = protocol.parse_reply([bytes(f) for f in protocol.reply([b""], 4, "render", {},
                                                                    [a, b])])
    assert isinstance(plain["arrays"], list) and plain["arrays"][0].tolist() == [0, 1, 2]
    assert "arrays" not in protocol.parse_reply([bytes(f) for f in protocol.reply([], 4, "ping")])
    for empty in ([], [b""]):
        with pytest.raises(MessageError, match="empty reply") as err:
            protocol.parse_reply(empty)
        assert err.value.code == "bad_frames"


def test_default_limits_are_the_documented_ones():
    # docs/protocol.md section 1.6 (tests/service/test_protocol_doc.py checks the table
    # through a running service); mutants: every default of Limits changed
    mib = 1 << 20
    assert protocol.Limits().as_dict() == {
        "max_message_bytes": 256 * mib, "max_array_bytes": 128 * mib,
        "max_request_bytes": 160 * mib, "max_frames": 1 + 1 + 1024,
        "max_header_bytes": mib, "max_string": 4096, "max_id": 64, "max_name": 256,
        "max_objects": 4096, "max_vertices": 2_000_000, "max_polygons": 4_000_000,
        "max_dims": 4}


def test_a_request_exposes_its_type_and_id():
    # mutants: Request.type's and Request.id's returns replaced
    req = protocol.Request([b"x", b""], {"type": "ping", "id": 9})
    assert (req.type, req.id) == ("ping", 9)
    assert protocol.Request([b"x"], {"type": "ping"}).id is None


def test_each_frame_header_integer_takes_its_least_value_and_optional_ones_may_be_absent():
    # mutants: FRAME_INTS' least values and required flags changed
    def frame(**fields) -> list[bytes]:
        head = {"v": 1, "kind": "frame", "session": "s", "seq": 0, "render_id": -1, **fields}
        return [b"frame", json.dumps({k: v for k, v in head.items() if v is not None}).encode()]
    assert protocol.parse_frame(frame())["arrays"] == {}
    for key, least, required in protocol.FRAME_INTS:
        assert protocol.parse_frame(frame(**{key: least}))[key] == least
        with pytest.raises(MessageError, match=f"{key} must be an integer >= {least}"):
            protocol.parse_frame(frame(**{key: least - 1}))
        if required:
            with pytest.raises(MessageError, match=f"{key} missing"):
                protocol.parse_frame(frame(**{key: None}))
    assert protocol.FRAME_INTS[:2] == (("seq", 0, True), ("render_id", -1, True))
    assert all(not required and least == 0 for _k, least, required in protocol.FRAME_INTS[2:])


def test_check_request_size_checks_the_first_array_too():
    # mutant: the per-array loop starting at the second buffer (sizes[2:])
    lim = protocol.Limits(max_array_bytes=4)
    with pytest.raises(MessageError, match=r"arrays\[0\] has 5 bytes"):
        protocol.check_request_size([b"", b"h", bytes(5), bytes(1)], lim)
    with pytest.raises(MessageError, match=r"arrays\[0\] has 5 bytes"):
        protocol.check_request_size([b"h", bytes(5)], lim)  # no delimiter


def test_string_refuses_what_is_not_a_string():
    # mutant: string()'s "must be a string" raise deleted (5 returned as a name)
    assert _code(lambda: wire.string(5, "s")) == "bad_message"
