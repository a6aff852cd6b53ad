"""The .hbc file: round trip, and one clear error for every kind of damage."""

import io
import json
import zipfile

import numpy as np
import pytest

from service.base.errors import MeshFileError
from service.primitives import sphere
from service.simplify.billboard import build_cloud
from service.simplify.cloud_file import load_cloud, save_cloud


@pytest.fixture(scope="module")
def cloud():
    s = sphere(0.5, 8, 16)
    return build_cloud(s.vertices, s.triangles, 0.05, texture_res=32)


@pytest.fixture
def saved(tmp_path, cloud):
    path = tmp_path / "c.hbc"
    save_cloud(cloud, path)
    return path


def test_round_trip(saved, cloud):
    back = load_cloud(saved)
    for name in ("corners", "planes", "tex_shape", "tex_offset", "rgba", "normal"):
        assert np.array_equal(getattr(back, name), getattr(cloud, name)), name
    assert back.eps == cloud.eps and back.source_faces == cloud.source_faces
    with zipfile.ZipFile(saved) as z:  # stored, not compressed; no pickle inside
        assert all(i.compress_type == zipfile.ZIP_STORED for i in z.infolist())
        assert json.loads(z.read("header.json"))["version"] == 1


@pytest.mark.parametrize("cut", [0.1, 0.5, 0.99])
def test_truncated_file(saved, cut):
    data = saved.read_bytes()
    saved.write_bytes(data[: int(len(data) * cut)])
    with pytest.raises(MeshFileError, match="truncated"):
        load_cloud(saved)


def _rewrite(path, name, payload):
    members = {}
    with zipfile.ZipFile(path) as z:
        for i in z.infolist():
            members[i.filename] = z.read(i.filename)
    if payload is None:
        del members[name]
    else:
        members[name] = payload
    with zipfile.ZipFile(path, "w") as z:
        for k, v in members.items():
            z.writestr(k, v)


def _npy(arr):
    buf = io.BytesIO()
    np.lib.format.write_array(buf, arr, allow_pickle=True)
    return buf.getvalue()


@pytest.mark.parametrize("name, payload, match", [
    ("header.json", None, "no header.json"),
    ("header.json", b"{nope", "not JSON"),
    ("header.json", json.dumps({"format": "other", "version": 1}).encode(), "format"),
    ("header.json", json.dumps({"format": "holo-billboard-cloud", "version": 9}).encode(),
     "version 9"),
    ("rgba.npy", None, "missing"),
    ("rgba.npy", b"garbage", "unreadable"),
    ("planes.npy", _npy(np.zeros((3, 4), np.float32)), "dtype"),
    ("corners.npy", _npy(np.zeros((1, 4, 3))), "shape"),
    ("normal.npy", _npy(np.array([object()] * 3, dtype=object)), "unreadable"),
])
def test_damaged_member(saved, name, payload, match):
    _rewrite(saved, name, payload)
    with pytest.raises(MeshFileError, match=match) as info:
        load_cloud(saved)
    assert "\n" not in str(info.value)


def test_inconsistent_offsets(saved, cloud):
    bad = cloud.tex_offset.copy()
    bad[1] += 1
    _rewrite(saved, "tex_offset.npy", _npy(bad))
    with pytest.raises(MeshFileError, match="tex_shape"):
        load_cloud(saved)


def test_not_a_zip(tmp_path):
    p = tmp_path / "x.hbc"
    p.write_bytes(b"ply\nformat ascii 1.0\n")
    with pytest.raises(MeshFileError, match="not a billboard-cloud zip"):
        load_cloud(p)


def _header_with(path, **fields):
    with zipfile.ZipFile(path) as z:
        header = json.loads(z.read("header.json"))
    return json.dumps({**header, **fields}).encode()


@pytest.mark.parametrize("fields, match", [
    ({"build_s": "x"}, "build_s must be a number"),
    ({"build_s": None}, "build_s must be a number"),
    ({"build_s": [1]}, "build_s must be a number"),
    ({"build_s": -1}, "build_s must be a number"),
    ({"eps": 10**400}, "eps must be a positive number"),  # a JSON integer past float
    ({"eps": True}, "eps must be a positive number"),
    ({"eps": "0.05"}, "eps must be a positive number"),
])
def test_a_header_field_of_the_wrong_type_is_named(saved, fields, match):
    _rewrite(saved, "header.json", _header_with(saved, **fields))
    with pytest.raises(MeshFileError, match=match):
        load_cloud(saved)


def test_a_header_without_build_s_still_loads(saved, cloud):
    with zipfile.ZipFile(saved) as z:
        header = json.loads(z.read("header.json"))
    del header["build_s"]
    _rewrite(saved, "header.json", json.dumps(header).encode())
    assert load_cloud(saved).build_s == 0.0


def test_a_damaged_compression_field_is_unreadable_not_a_crash(saved):
    data = bytearray(saved.read_bytes())
    entry = data.index(b"PK\x01\x02")  # the first central-directory entry: method at +10
    data[entry + 10] = 99  # no such compression method
    saved.write_bytes(bytes(data))
    with pytest.raises(MeshFileError, match="unreadable|truncated|not a billboard"):
        load_cloud(saved)
