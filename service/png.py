"""A minimal pure-Python PNG writer and reader (8-bit, no extra dependency).

The writer stores 8-bit greyscale, grey + alpha, RGB or RGBA images, non-interlaced,
every row with PNG filter type 2 ("Up": each byte minus the byte above, which
compresses smooth renders well and is one numpy subtraction), deflated with
:mod:`zlib`.  The reader decodes what the writer writes and, more generally, any
8-bit non-interlaced PNG of those colour types with any of the five filter types
(types 3 and 4 decode row by row in Python, so slowly); it checks every chunk's CRC.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

from service.base.errors import PngError

_SIGNATURE = b"\x89PNG\r\n\x1a\n"

#: Channels per pixel -> PNG colour type.
_COLOUR_TYPE = {1: 0, 2: 4, 3: 2, 4: 6}

#: PNG colour type -> channels per pixel.
_CHANNELS = {v: k for k, v in _COLOUR_TYPE.items()}


def _chunk(kind: bytes, data: bytes) -> bytes:
    """One PNG chunk: length, type, data, CRC-32 of type + data."""
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _as_pixels(image: np.ndarray) -> np.ndarray:
    """Check and reshape an image to (H, W, channels) uint8."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise PngError(f"PNG pixels must be uint8, got {img.dtype}")
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3 or img.shape[2] not in _COLOUR_TYPE:
        raise PngError(f"PNG image must be (H, W) or (H, W, 1|2|3|4), got {img.shape}")
    if img.shape[0] < 1 or img.shape[1] < 1:
        raise PngError(f"PNG image must be at least 1 x 1, got {img.shape[:2]}")
    return np.ascontiguousarray(img)


def encode_png(image: np.ndarray, level: int = 6) -> bytes:
    """PNG bytes of an 8-bit image.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C), uint8
        C = 1 (grey), 2 (grey + alpha), 3 (RGB) or 4 (RGBA).
    level : int
        zlib compression level, 0 to 9.

    Returns
    -------
    bytes

    Raises
    ------
    PngError
        If the array is not uint8 or has an unsupported shape.
    """
    img = _as_pixels(image)
    h, w, ch = img.shape
    rows = img.reshape(h, w * ch)
    up = rows.copy()
    up[1:] -= rows[:-1]  # uint8 arithmetic wraps modulo 256, as the filter wants
    raw = np.empty((h, w * ch + 1), np.uint8)
    raw[:, 0] = 2
    raw[:, 1:] = up
    ihdr = struct.pack(">IIBBBBB", w, h, 8, _COLOUR_TYPE[ch], 0, 0, 0)
    return b"".join(
        [
            _SIGNATURE,
            _chunk(b"IHDR", ihdr),
            _chunk(b"IDAT", zlib.compress(raw.tobytes(), level)),
            _chunk(b"IEND", b""),
        ]
    )


def write_png(path: str | Path, image: np.ndarray, level: int = 6) -> Path:
    """Write an 8-bit image as a PNG file; see :func:`encode_png`.

    Returns
    -------
    Path
        The path written.
    """
    p = Path(path)
    p.write_bytes(encode_png(image, level))
    return p


def _chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    """Split PNG bytes into (type, data) chunks, checking signature and CRCs."""
    if not data.startswith(_SIGNATURE):
        raise PngError("not a PNG file (bad signature)")
    out, pos = [], len(_SIGNATURE)
    while pos < len(data):
        if pos + 8 > len(data):
            raise PngError(f"truncated chunk header at byte {pos}")
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        kind = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + length]
        crc = data[pos + 8 + length : pos + 12 + length]
        if len(body) != length or len(crc) != 4:
            raise PngError(f"truncated {kind!r} chunk at byte {pos}")
        if struct.unpack(">I", crc)[0] != zlib.crc32(kind + body):
            raise PngError(f"CRC mismatch in {kind!r} chunk at byte {pos}")
        out.append((kind, body))
        pos += 12 + length
        if kind == b"IEND":
            break
    return out


def _paeth(a: int, b: int, c: int) -> int:
    """The PNG Paeth predictor."""
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else (b if pb <= pc else c)


def _row_none(line: np.ndarray, prev: np.ndarray, bpp: int) -> np.ndarray:
    """Filter 0: bytes as stored."""
    return line


def _row_sub(line: np.ndarray, prev: np.ndarray, bpp: int) -> np.ndarray:
    """Filter 1: each byte plus the byte ``bpp`` to its left (a running sum mod 256)."""
    return np.cumsum(line.reshape(-1, bpp), axis=0, dtype=np.uint8).reshape(-1)


def _row_up(line: np.ndarray, prev: np.ndarray, bpp: int) -> np.ndarray:
    """Filter 2: each byte plus the byte above."""
    return line + prev


def _row_predicted(line: np.ndarray, prev: np.ndarray, bpp: int, paeth: bool) -> np.ndarray:
    """Filters 3 (Average) and 4 (Paeth), byte by byte."""
    out = [int(v) for v in line]
    up = [int(v) for v in prev]
    for i in range(len(out)):
        left = out[i - bpp] if i >= bpp else 0
        corner = up[i - bpp] if i >= bpp else 0
        pred = _paeth(left, up[i], corner) if paeth else (left + up[i]) // 2
        out[i] = (out[i] + pred) & 0xFF
    return np.array(out, np.uint8)


#: PNG filter type -> function(row bytes, decoded row above, bytes per pixel) -> row.
_UNFILTER = {
    0: _row_none,
    1: _row_sub,
    2: _row_up,
    3: lambda line, prev, bpp: _row_predicted(line, prev, bpp, False),
    4: lambda line, prev, bpp: _row_predicted(line, prev, bpp, True),
}


def _unfilter(raw: np.ndarray, bpp: int) -> np.ndarray:
    """Undo PNG filtering of ``raw`` (H, 1 + stride) -> (H, stride) uint8."""
    h, stride = raw.shape[0], raw.shape[1] - 1
    out = np.zeros((h, stride), np.uint8)
    prev = np.zeros(stride, np.uint8)
    for r in range(h):
        fn = _UNFILTER.get(int(raw[r, 0]))
        if fn is None:
            raise PngError(f"row {r}: unknown filter type {int(raw[r, 0])}")
        out[r] = fn(raw[r, 1:], prev, bpp)
        prev = out[r]
    return out


def decode_png(data: bytes) -> np.ndarray:
    """Decode 8-bit non-interlaced PNG bytes.

    Returns
    -------
    ndarray, shape (H, W) for greyscale or (H, W, C) with C = 2, 3 or 4; uint8

    Raises
    ------
    PngError
        On a bad signature, a CRC mismatch, truncation, or an unsupported format
        (bit depth other than 8, palette images, interlacing).
    """
    chunks = _chunks(data)
    if not chunks or chunks[0][0] != b"IHDR" or len(chunks[0][1]) != 13:
        raise PngError("PNG must start with a 13-byte IHDR chunk")
    w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", chunks[0][1])
    if depth != 8 or ctype not in _CHANNELS or interlace != 0:
        raise PngError(f"unsupported PNG: bit depth {depth}, colour type {ctype}, "
                       f"interlace {interlace} (only 8-bit, non-interlaced, types 0/2/4/6)")
    ch = _CHANNELS[ctype]
    try:
        raw = zlib.decompress(b"".join(body for kind, body in chunks if kind == b"IDAT"))
    except zlib.error as exc:
        raise PngError(f"corrupt image data: {exc}") from None
    if len(raw) != h * (w * ch + 1):
        raise PngError(f"image data is {len(raw)} bytes, expected {h * (w * ch + 1)}")
    pixels = _unfilter(np.frombuffer(raw, np.uint8).reshape(h, w * ch + 1), ch)
    return pixels.reshape(h, w) if ch == 1 else pixels.reshape(h, w, ch)


def read_png(path: str | Path) -> np.ndarray:
    """Read a PNG file; see :func:`decode_png`."""
    return decode_png(Path(path).read_bytes())
