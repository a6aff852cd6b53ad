"""Checksums used by the byte protocols.

``crc16_ccitt`` is CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection,
no final xor; check value for ``b"123456789"`` is 0x29B1), computed in C by
:func:`binascii.crc_hqx`.  ``crc32`` is the zlib / IEEE 802.3 CRC-32 (check 0xCBF43926).
``crc16_ccitt_reference`` is a bit-by-bit implementation kept for the tests.
"""

from __future__ import annotations

import binascii
import zlib

CRC16_INIT = 0xFFFF
CRC16_POLY = 0x1021


def crc16_ccitt(data: bytes | bytearray | memoryview, init: int = CRC16_INIT) -> int:
    """CRC-16/CCITT-FALSE of ``data``.

    Parameters
    ----------
    data : bytes-like
        The bytes to check.
    init : int
        Initial register value (0..0xFFFF); pass a previous result to continue.

    Returns
    -------
    int
        The CRC, 0..0xFFFF.
    """
    return binascii.crc_hqx(data, init)


def crc16_ccitt_reference(data: bytes, init: int = CRC16_INIT) -> int:
    """Bit-by-bit CRC-16/CCITT-FALSE (slow; the definition, for tests)."""
    crc = init
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ CRC16_POLY) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def crc32(data: bytes | bytearray | memoryview, init: int = 0) -> int:
    """IEEE CRC-32 of ``data`` (0..2**32-1)."""
    return zlib.crc32(data, init) & 0xFFFFFFFF
