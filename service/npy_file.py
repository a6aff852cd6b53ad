"""``.npy`` and ``.npz`` arrays read from bytes that may be damaged.

``np.load`` trusts a file's header: a header whose shape claims 10^18 elements makes
it allocate before it reads (``MemoryError``), and a torn or garbled header surfaces
as ``SyntaxError``, ``tokenize.TokenError`` or ``EOFError`` rather than one error a
caller can name.  :func:`read_npy` parses the header with numpy's own functions,
refuses object arrays, and checks that the data the header promises is exactly the
data there, before any array is made; every kind of damage is one ``ValueError``
saying what is wrong.  Used for the files users hand in or keep between runs:
depth maps (``.npy``), billboard clouds (``.hbc``) and the LOD cache (``.npz``).
"""

from __future__ import annotations

import io
import tokenize
import warnings
import zipfile
import zlib
from pathlib import Path

import numpy as np
from numpy.lib import format as npformat

#: numpy's header readers by format version (3.0 only adds UTF-8 field names).
_HEADERS = {(1, 0): npformat.read_array_header_1_0, (2, 0): npformat.read_array_header_2_0}
#: What numpy's header parsing raises on a damaged header, besides ValueError.
_HEADER_ERRORS = (ValueError, SyntaxError, tokenize.TokenError, EOFError, TypeError,
                  RecursionError)
#: What reading a damaged zip raises (a member's compression field damaged:
#: NotImplementedError; an encrypted member: RuntimeError).
ZIP_ERRORS = (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, NotImplementedError,
              RuntimeError, zlib.error)


def read_npy(data: bytes) -> np.ndarray:
    """The array stored in the bytes of a ``.npy`` file.

    Parameters
    ----------
    data : bytes
        The whole file.

    Returns
    -------
    ndarray
        The header's shape and dtype; a new, writeable array.

    Raises
    ------
    ValueError
        Not a ``.npy`` file, a header numpy cannot parse, an object dtype, or data
        longer or shorter than the header's shape and dtype need.
    """
    fp = io.BytesIO(data)
    try:
        version = npformat.read_magic(fp)
        if version not in _HEADERS:
            raise ValueError(f"format version {version} (read: 1.0, 2.0)")
        with warnings.catch_warnings():  # a garbled header's '\\o' is damage, not a warning
            warnings.simplefilter("ignore", (SyntaxWarning, DeprecationWarning))
            shape, fortran, dtype = _HEADERS[version](fp)
    except _HEADER_ERRORS as exc:
        raise ValueError(f"not a readable .npy header ({type(exc).__name__}: {exc})"[:200]) \
            from None
    if dtype.hasobject:
        raise ValueError(f"dtype {dtype} holds Python objects (not read)")
    count = 1
    for n in shape:
        count *= int(n)
    need, have = count * dtype.itemsize, len(data) - fp.tell()
    if need != have:
        raise ValueError(f"the header's shape {shape} and dtype {dtype} need {need} bytes "
                         f"of data, the file has {have}")
    flat = np.frombuffer(data, dtype, count, fp.tell())
    return flat.reshape(shape, order="F" if fortran else "C").copy(order="K")


def read_npy_file(path: str | Path) -> np.ndarray:
    """:func:`read_npy` of a file; ``OSError`` if it cannot be read."""
    return read_npy(Path(path).read_bytes())


def read_npz(path: str | Path) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file (a zip of ``.npy`` members) by name.

    Raises
    ------
    ValueError
        A damaged zip or member (the member is named), or a member not ``.npy``.
    """
    out = {}
    try:
        with zipfile.ZipFile(path) as z:
            for name in z.namelist():
                if not name.endswith(".npy"):
                    raise ValueError(f"{name}: not an .npy member")
                try:
                    out[name.removesuffix(".npy")] = read_npy(z.read(name))
                except ValueError as exc:
                    raise ValueError(f"{name}: {exc}") from None
    except (*ZIP_ERRORS, OSError) as exc:
        raise ValueError(f"not a readable .npz ({type(exc).__name__}: {exc})"[:200]) from None
    return out
