"""docs/protocol.md and the service agree: its tables against the code, its sentences
against a real service, asked the way a client written from the doc alone asks.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import zmq
from testkit import HANG_S, ROOT, raw_request, wait_until

from service.net import protocol

DOC = (ROOT / "docs" / "protocol.md").read_text()
UNITS = {"MiB": 1 << 20, "KiB": 1 << 10}


def _section(title: str) -> str:
    start = DOC.index(title)
    end = DOC.find("\n### ", start + 1)
    return DOC[start:end]


def _doc_number(text: str) -> int:
    """The number a limit cell starts with: ``128 MiB``, ``2,000,000``, ``1 + 1 + 1024``."""
    head = text.split(":")[0].split("(")[0]
    m = re.match(r"\s*([\d,]+(?:\s*\+\s*[\d,]+)*)\s*(MiB|KiB)?", head)
    assert m, f"no number in {text!r}"
    total = sum(int(t.replace(",", "")) for t in m.group(1).split("+"))
    return total * UNITS.get(m.group(2) or "", 1)


def test_the_limits_table_is_the_code():
    rows = re.findall(r"^\| [^|]+ \| `(\w+)` \| ([^|]+) \|$", _section("### 1.6"), re.M)
    documented = {key: _doc_number(value) for key, value in rows}
    assert documented == protocol.Limits().as_dict()


def test_the_error_code_table_is_the_code():
    codes = re.findall(r"^\| `(\w+)` \|", _section("### 1.3"), re.M)
    assert tuple(codes) == protocol.ERROR_CODES


def test_the_message_type_table_is_the_code():
    types = re.findall(r"^\| `(\w+)` \|", _section("### 1.5").split("Render reply")[0], re.M)
    assert tuple(types) == protocol.MESSAGE_TYPES


def ask(svc, header: dict, buffers: tuple = ()) -> dict:
    got = raw_request(svc.control, {"v": 1, **header}, buffers, 10000)
    assert got is not None, f"no reply to {header}"
    return got


def code(reply: dict) -> str | None:
    return None if reply["ok"] else reply["error"]["code"]


ID_CASES = {
    "an id of 64 characters": ({"id": "i" * 64}, None),
    "an id of 65 characters": ({"id": "i" * 65}, "too_large"),
    "an empty id": ({"id": ""}, "bad_message"),
    "a float id": ({"id": 1.5}, "bad_message"),
    "a client_id of 64 characters": ({"id": 1, "client_id": "c" * 64}, None),
    "a client_id of 65 characters": ({"id": 1, "client_id": "c" * 65}, "too_large"),
    "an empty client_id": ({"id": 1, "client_id": ""}, "bad_message"),
    "an integer client_id": ({"id": 1, "client_id": 12}, "bad_message"),
}


@pytest.mark.parametrize("fields, expected", ID_CASES.values(), ids=ID_CASES.keys())
def test_ids_follow_the_header_table(svc, fields, expected):
    assert code(ask(svc, {"type": "ping", **fields})) == expected


def test_strings_are_capped_at_max_string(svc):
    limits = protocol.Limits()
    ok = ask(svc, {"type": "hello", "id": 1, "client": "c" * limits.max_string})
    assert ok["ok"]
    big = ask(svc, {"type": "hello", "id": 2, "client": "c" * (limits.max_string + 1)})
    assert code(big) == "too_large" and big["id"] == 2


def test_names_are_capped_at_max_name(svc):
    n = protocol.Limits().max_name
    update = {"type": "update_objects", "id": 3}
    at_cap = ask(svc, {**update, "objects": [{"name": "n" * n, "position": [0, 0, 0]}]})
    assert code(at_cap) == "not_found"  # a legal name no object has
    over = ask(svc, {**update, "objects": [{"name": "n" * (n + 1), "position": [0, 0, 0]}]})
    assert code(over) == "too_large"


def _load_object_header(shape: list[int], n_arrays: int = 2) -> dict:
    mesh = {"vertices": {"$array": 0}, "triangles": {"$array": 1}}
    arrays = [{"dtype": "float32", "shape": shape}, {"dtype": "int32", "shape": [1, 3]}]
    arrays += [{"dtype": "uint8", "shape": [1]}] * (n_arrays - 2)
    return {"type": "load_object", "id": 7, "object": {"name": "q", "mesh": mesh},
            "arrays": arrays}


def test_arrays_of_more_than_max_dims_are_too_large(svc):
    vertices = np.zeros((1, 1, 1, 1, 3), np.float32)
    got = ask(svc, _load_object_header([1, 1, 1, 1, 3]),
              (vertices.tobytes(), np.zeros((1, 3), np.int32).tobytes()))
    assert code(got) == "too_large"


def test_more_than_1024_buffers_are_too_large(svc):
    head = _load_object_header([3, 3], n_arrays=1025)
    buffers = (np.zeros((3, 3), np.float32).tobytes(), np.zeros((1, 3), np.int32).tobytes(),
               *[b"\0"] * 1023)
    assert code(ask(svc, head, buffers)) == "too_large"


def test_mesh_arrays_must_be_buffers(svc):
    obj = {"name": "q", "mesh": {"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
                                 "triangles": [[0, 1, 2]]}}
    assert code(ask(svc, {"type": "load_object", "id": 8, "object": obj})) == "bad_array"


def test_an_unreferenced_buffer_is_a_bad_message(svc):
    head = {"type": "ping", "id": 9, "arrays": [{"dtype": "uint8", "shape": [1]}]}
    assert code(ask(svc, head, (b"\0",))) == "bad_message"


def test_a_nan_literal_is_not_finite(svc):
    s = zmq.Context.instance().socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    s.connect(svc.control)
    try:
        body = b'{"v": 1, "type": "set_viewer", "id": 10, "position": [0, NaN, 1]}'
        s.send_multipart([b"", body])
        assert s.poll(10000)
        assert code(json.loads(s.recv_multipart()[1])) == "not_finite"
    finally:
        s.close(0)


def test_an_unknown_type_is_echoed(svc):
    got = ask(svc, {"type": "nosuch", "id": 11})
    assert code(got) == "unknown_type" and got["type"] == "nosuch" and got["id"] == 11


def test_the_error_example_of_section_1_3(svc):
    example = re.search(r'"error": (\{"code": "\w+", "message": "[^"]+"\})', _section("### 1.3"))
    doc_error = json.loads(example.group(1))
    got = ask(svc, {"type": "update_objects", "id": 42,
                    "objects": [{"index": 0, "position": [1, 2]}]})
    assert got["error"] == doc_error and got["id"] == 42 and got["type"] == "update_objects"


def test_set_viewer_takes_a_pose_or_devices_not_both(svc):
    both = ask(svc, {"type": "set_viewer", "id": 12, "position": [0, 0, 1], "devices": None})
    assert code(both) == "bad_message"
    pose = ask(svc, {"type": "set_viewer", "id": 13, "position": [0, 0, 1]})
    assert set(pose["viewer"]) == {"position", "orientation", "velocity", "acceleration",
                                   "angular_velocity", "angular_acceleration"}
    assert pose["viewer"]["position"] == [0, 0, 1] and pose["devices"] is None


def test_hello_lists_the_limits_of_the_table(svc):
    assert ask(svc, {"type": "hello", "id": 14})["limits"] == protocol.Limits().as_dict()


def test_load_scene_counts_polygons_as_the_mesh_holds_them(svc, tmp_path: Path):
    quad = tmp_path / "quad.obj"
    quad.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    got = ask(svc, {"type": "load_scene", "id": 15, "path": str(quad)})
    assert got["ok"] and got["polygons"] == 1  # one quad
    ask(svc, {"type": "load_scene", "id": 16, "builtin": "game"})


def _stats_row() -> str:
    return next(line for line in _section("### 1.5").splitlines() if line.startswith("| `stats`"))


def test_the_worker_stats_are_documented_and_served(service_factory):
    """Every worker field of ``stats`` is in the doc's ``stats`` row, and the reverse."""
    row = _stats_row()
    workers = service_factory("--scene", "game", "--zones", "2", "--size", "32x24",
                              "--refresh", "30", "--workers", "1")
    assert wait_until(lambda: ask(workers, {"type": "stats"})["stats"]["worker_pids"], HANG_S)
    st = ask(workers, {"type": "stats", "id": 16})["stats"]
    for key in ("workers", "worker_pids", "worker_deaths", "worker_restarts", "worker_error",
                "jobs_resent", "split"):
        assert f"`{key}`" in row and key in st, key
    for key in st["workers"]:
        assert f"`{key}`" in row, key
    entry = re.search(r"`\{(pid, [a-z_, ]+)\}`", row)
    assert entry, "no per-worker entry in the stats row"
    documented = [k.strip() for k in entry.group(1).split(",")]
    got = st["workers"]["workers"]
    assert got, "the service's worker is not listed"
    assert sorted(got[0]) == sorted(documented)


def test_the_frame_header_table_is_a_real_frame_header(svc):
    """Section 2: every key of the table is in a published frame's header, and back."""
    table = DOC.split("Frame header:")[1].split("Heartbeat header")[0]
    rows = re.findall(r"^\| (`[^|]+`) \|", table, re.M)
    documented = {k for row in rows for k in re.findall(r"`(\w+)`", row)}
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"frame")
    sub.setsockopt(zmq.RCVTIMEO, 10000)
    sub.connect(svc.frames)
    try:
        header = json.loads(sub.recv_multipart()[1])
    finally:
        sub.close(0)
    # v, kind and session are the envelope every message of the stream has
    assert documented == set(header) - {"v", "kind", "session"}
    assert header["held"] in (True, False) and 0 <= header["use_by"] <= 16


def test_every_set_display_key_is_documented():
    from service.display import DisplaySettings
    from service.engine.state import Settings

    row = next(line for line in DOC.splitlines() if line.startswith("| `set_display` |"))
    named = set(re.findall(r"`(\w+)`", row.split("|")[2]))
    missing = set(Settings(DisplaySettings()).as_dict()) - named
    assert not missing, f"set_display keys not in docs/protocol.md: {sorted(missing)}"
