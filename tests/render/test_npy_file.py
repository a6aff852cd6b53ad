"""``service.npy_file``: arrays from damaged ``.npy``/``.npz`` bytes are a ValueError.

``np.load`` allocates what a header claims before it reads, and a garbled header
surfaces as SyntaxError or tokenize.TokenError; the depth-map, billboard-cloud and
LOD-cache readers go through these functions instead.
"""

from __future__ import annotations

import io
import warnings
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.npy_file import read_npy, read_npy_file, read_npz


def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


def _claim(data: bytes, old: str, new: str) -> bytes:
    """The same file with ``old`` in its header written ``new`` (padding kept)."""
    end = data.index(b"\n") + 1
    head = data[:end].decode("latin1")
    assert old in head
    body = head.replace(old, new, 1)[:-1].rstrip(" ")
    assert len(body) < len(head)
    fixed = body + " " * (len(head) - len(body) - 1) + "\n"
    return fixed.encode("latin1") + data[end:]


@pytest.mark.parametrize("arr", [
    np.arange(12, dtype=np.float32).reshape(3, 4),
    np.asfortranarray(np.arange(12, dtype=np.int64).reshape(3, 4)),
    np.zeros((0, 3), np.uint8), np.array(2.5), np.arange(5, dtype=">i2"),
    np.zeros(3, dtype=[("a", "<f4"), ("b", "u1")]),
])
def test_what_np_save_writes_reads_back_the_same(arr):
    back = read_npy(_npy(arr))
    assert back.dtype == arr.dtype and back.shape == arr.shape
    np.testing.assert_array_equal(back, arr)
    assert back.flags.writeable


def test_a_header_that_claims_more_than_the_file_allocates_nothing():
    # np.load would first make a 400 GB array (MemoryError here; found by fuzzing)
    data = _claim(_npy(np.zeros((20, 30), np.float32)), "(20, 30)", "(100000000000,)")
    with pytest.raises(ValueError, match=r"need 400000000000 bytes of data, the file has 2400"):
        read_npy(data)


@pytest.mark.parametrize(("old", "new", "words"), [
    ("'<f4'", "'|O'", "holds Python objects"),
    ("(20, 30)", "(20, 31)", "need 2480 bytes"),
    ("(20, 30)", "(20, 30", "not a readable .npy header"),
    ("'descr'", "'dexcr'", "not a readable .npy header"),
])
def test_a_damaged_header_says_what_is_wrong(old, new, words):
    with pytest.raises(ValueError, match=words):
        read_npy(_claim(_npy(np.zeros((20, 30), np.float32)), old, new))


@settings(max_examples=300, deadline=None)
@given(data=st.data())
def test_any_cut_or_flipped_byte_is_a_value_error_or_the_array(data):
    good = _npy(np.arange(60, dtype=np.float32).reshape(6, 10))
    raw = bytearray(good)
    if data.draw(st.booleans()):
        del raw[data.draw(st.integers(0, len(raw) - 1)):]
    else:  # the header, where np.load's failures are not ValueError
        raw[data.draw(st.integers(0, 127))] ^= data.draw(st.integers(1, 255))
    try:
        arr = read_npy(bytes(raw))
    except ValueError:
        return
    assert arr.size * arr.dtype.itemsize == len(raw) - (len(good) - 240)


def test_npz_members_by_name_and_a_damaged_member_named(tmp_path):
    path = tmp_path / "a.npz"
    np.savez(path, vertices_1=np.ones((4, 3)), faces_1=np.zeros((2, 3), np.int32))
    got = read_npz(path)
    assert set(got) == {"vertices_1", "faces_1"} and got["faces_1"].shape == (2, 3)
    with zipfile.ZipFile(path) as z:
        members = {n: z.read(n) for n in z.namelist()}
    members["faces_1.npy"] = _claim(members["faces_1.npy"], "(2, 3)", "(2000000000, 3000)")
    with zipfile.ZipFile(path, "w") as z:
        for n, v in members.items():
            z.writestr(n, v)
    with pytest.raises(ValueError, match="faces_1.npy: the header's shape"):
        read_npz(path)
    path.write_bytes(path.read_bytes()[:50])
    with pytest.raises(ValueError, match="not a readable .npz"):
        read_npz(path)


def test_a_file_that_is_not_there_is_an_os_error(tmp_path):
    with pytest.raises(OSError):
        read_npy_file(tmp_path / "none.npy")


@pytest.mark.parametrize("version", [(1, 0), (2, 0)])
def test_format_versions_1_and_2_read_and_3_is_a_value_error_naming_it(version):
    # mutants: the (2, 0) entry of the header-reader table changed (version 2.0 refused)
    arr = np.arange(6, dtype=np.int16).reshape(2, 3)
    buf = io.BytesIO()
    np.lib.format.write_array(buf, arr, version=version, allow_pickle=False)
    np.testing.assert_array_equal(read_npy(buf.getvalue()), arr)
    buf = io.BytesIO()
    np.lib.format.write_array(buf, arr, version=(3, 0), allow_pickle=False)
    with pytest.raises(ValueError, match=r"format version \(3, 0\)"):
        read_npy(buf.getvalue())


def test_an_npz_member_not_npy_is_named_even_when_its_bytes_are_an_array(tmp_path):
    # mutant: the "not an .npy member" raise deleted (the member read as "notes.txt")
    path = tmp_path / "a.npz"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("notes.txt", _npy(np.ones(3)))
    with pytest.raises(ValueError, match=r"notes\.txt: not an \.npy member"):
        read_npz(path)


def test_a_header_with_a_stray_escape_is_a_value_error_and_no_warning():
    # ast.literal_eval of a garbled header warns "invalid escape sequence" (found by fuzzing)
    data = _claim(_npy(np.zeros(3)), "'descr'", "'d\\o'")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(ValueError, match="not a readable .npy header"):
            read_npy(data)
    assert [str(w.message) for w in caught] == []
