"""Stage 6 (service.render.frame) layouts and writers, and the PNG codec (service.png)."""

from __future__ import annotations

import io
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from service.base.errors import HoloError, SettingsError
from service.png import PngError, decode_png, encode_png, read_png, write_png
from service.render.frame import (
    Frame,
    default_grid,
    depth_grey,
    format_aspect,
    quilt,
    quilt_name,
    view_strip,
    write_quilt,
    write_strip,
    write_zones,
)


def labelled_views(n: int, rows: int = 4, cols: int = 6) -> np.ndarray:
    """Views whose every pixel holds (view index + 1, row, col) so tiles can be traced."""
    v = np.zeros((n, rows, cols, 3), np.uint8)
    v[..., 0] = (np.arange(n) + 1)[:, None, None]
    v[..., 1] = np.arange(rows)[None, :, None]
    v[..., 2] = np.arange(cols)[None, None, :]
    return v


def tile(img: np.ndarray, col: int, row_from_bottom: int, r: int, c: int) -> np.ndarray:
    rows = img.shape[0] // r
    y0 = (rows - 1 - row_from_bottom) * r
    return img[y0 : y0 + r, col * c : (col + 1) * c]


def test_quilt_places_view_zero_bottom_left_then_rightward_then_up():
    views = labelled_views(5)
    q = quilt(views, cols=3, rows=2)
    assert q.shape == (8, 18, 3)
    np.testing.assert_array_equal(tile(q, 0, 0, 4, 6), views[0])  # bottom-left
    np.testing.assert_array_equal(tile(q, 1, 0, 4, 6), views[1])  # bottom row, 2nd tile
    np.testing.assert_array_equal(tile(q, 2, 0, 4, 6), views[2])
    np.testing.assert_array_equal(tile(q, 0, 1, 4, 6), views[3])  # view `cols` starts row 2
    np.testing.assert_array_equal(tile(q, 1, 1, 4, 6), views[4])
    assert not tile(q, 2, 1, 4, 6).any()  # unused tile is black
    with pytest.raises(SettingsError):
        quilt(views, 2, 2)


def test_quilt_file_name_and_aspect_format(tmp_path):
    assert format_aspect(0.75) == "0.75"
    assert format_aspect(4 / 3) == "1.333"
    assert format_aspect(16 / 9) == "1.778"
    assert format_aspect(1.0) == "1.0"
    assert quilt_name(8, 6, 420, 560) == "quilt_qs8x6a0.75.png"
    frame = Frame(labelled_views(5, rows=3, cols=4), np.zeros((5, 3, 4), np.float32))
    path = write_quilt(frame, tmp_path / "q")
    assert path.name == "quilt_qs3x2a1.333.png"
    np.testing.assert_array_equal(read_png(path), quilt(frame.colour, 3, 2))
    assert write_quilt(frame, tmp_path, 5, 1).name == "quilt_qs5x1a1.333.png"


@pytest.mark.parametrize(
    ("n", "grid"), [(1, (1, 1)), (2, (2, 1)), (5, (3, 2)), (9, (3, 3)), (48, (8, 6))]
)
def test_default_grid(n, grid):
    assert default_grid(n) == grid


@given(st.integers(1, 100))
def test_default_grid_holds_all_views_with_little_waste(n):
    cols, rows = default_grid(n)
    assert cols * rows >= n
    assert cols * rows - n < max(cols, rows)  # never a whole empty row or column
    assert max(cols, rows) <= 2 * min(cols, rows)


def test_view_strip_puts_zone_zero_left_with_separators(tmp_path):
    views = labelled_views(3)
    s = view_strip(views, sep=2, sep_value=255)
    assert s.shape == (4, 3 * 6 + 2 * 2, 3)
    np.testing.assert_array_equal(s[:, 0:6], views[0])
    np.testing.assert_array_equal(s[:, 8:14], views[1])
    np.testing.assert_array_equal(s[:, 16:22], views[2])
    assert np.all(s[:, 6:8] == 255)
    assert view_strip(views).shape == (4, 18, 3)
    frame = Frame(views, np.zeros((3, 4, 6), np.float32))
    np.testing.assert_array_equal(read_png(write_strip(frame, tmp_path / "s.png", sep=0)),
                                  view_strip(views))


def test_write_zones_round_trips_colour_and_depth(tmp_path):
    views = labelled_views(2)
    depth = np.full((2, 4, 6), np.inf, np.float32)
    depth[0, 1:3, 2:5] = 1.25
    frame = Frame(views, depth, settings={"zones": 2})
    paths = write_zones(frame, tmp_path / "out")
    assert [p.name for p in paths] == ["zone-00.png", "depth-00.npy", "zone-01.png", "depth-01.npy"]
    for z in range(2):
        np.testing.assert_array_equal(read_png(tmp_path / "out" / f"zone-{z:02d}.png"), views[z])
        d = np.load(tmp_path / "out" / f"depth-{z:02d}.npy", allow_pickle=False)
        assert d.dtype == np.float32
        np.testing.assert_array_equal(d, depth[z])


def test_frame_refuses_mismatched_arrays():
    with pytest.raises(SettingsError):
        Frame(np.zeros((2, 4, 6, 3), np.uint8), np.zeros((2, 4, 5), np.float32))
    with pytest.raises(SettingsError):
        Frame(np.zeros((2, 4, 6, 3), np.float32), np.zeros((2, 4, 6), np.float32))


def test_depth_grey_nearer_is_brighter_and_empty_is_black():
    d = np.array([[1.0, 2.0, 3.0, np.inf]])
    g = depth_grey(d)
    assert g.dtype == np.uint8
    assert g[0, 0] == 255 and g[0, 3] == 0
    assert g[0, 0] > g[0, 1] > g[0, 2] > 0
    assert np.all(depth_grey(np.full((2, 2), np.inf)) == 0)
    assert np.all(depth_grey(np.full((2, 2), 5.0)) == 255)


images = st.integers(1, 9).flatmap(
    lambda h: st.integers(1, 9).flatmap(
        lambda w: st.sampled_from([(h, w), (h, w, 2), (h, w, 3), (h, w, 4)]).flatmap(
            lambda shape: arrays(np.uint8, shape)
        )
    )
)


@settings(max_examples=150, deadline=None)
@given(images)
def test_png_round_trip(img):
    np.testing.assert_array_equal(decode_png(encode_png(img)), img)


@settings(max_examples=30, deadline=None)
@given(images)
def test_png_is_readable_by_an_independent_decoder(img):
    image = pytest.importorskip("PIL.Image")
    np.testing.assert_array_equal(np.asarray(image.open(io.BytesIO(encode_png(img)))), img)


def paeth(a: int, b: int, c: int) -> int:
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else (b if pb <= pc else c)


def filtered_png(img: np.ndarray) -> bytes:
    """A PNG whose row r uses filter type r % 5, built independently of service.png."""
    h, w, ch = img.shape
    rows = img.reshape(h, w * ch).astype(int)
    raw = bytearray()
    for r in range(h):
        cur = rows[r]
        up = rows[r - 1] if r else np.zeros_like(cur)
        left = np.concatenate([np.zeros(ch, int), cur[:-ch]])
        corner = np.concatenate([np.zeros(ch, int), up[:-ch]])
        pred = [
            np.zeros_like(cur),
            left,
            up,
            (left + up) // 2,
            np.array([paeth(a, b, c) for a, b, c in zip(left, up, corner, strict=True)]),
        ][r % 5]
        raw += bytes([r % 5]) + bytes(((cur - pred) % 256).astype(np.uint8))

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data).to_bytes(4, "big")
        return len(data).to_bytes(4, "big") + kind + data + crc

    ihdr = w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes([8, {3: 2, 4: 6}[ch], 0, 0, 0])
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
            + chunk(b"IDAT", zlib.compress(bytes(raw))) + chunk(b"IEND", b""))


@pytest.mark.parametrize("ch", [3, 4])
def test_png_reader_decodes_every_filter_type(ch):
    rng = np.random.default_rng(ch)
    img = rng.integers(0, 256, (11, 7, ch)).astype(np.uint8)
    np.testing.assert_array_equal(decode_png(filtered_png(img)), img)


def test_png_errors_are_clear(tmp_path):
    good = encode_png(np.zeros((3, 3, 3), np.uint8))
    with pytest.raises(PngError, match="signature"):
        decode_png(b"GIF89a" + good[6:])
    broken = bytearray(good)
    broken[40] ^= 0xFF
    with pytest.raises(PngError, match="CRC|corrupt"):
        decode_png(bytes(broken))
    with pytest.raises(PngError, match="truncated"):
        decode_png(good[:30])
    with pytest.raises(PngError):
        encode_png(np.zeros((3, 3), np.float32))
    with pytest.raises(HoloError):
        write_png(tmp_path / "x.png", np.zeros((3, 3, 5), np.uint8))
