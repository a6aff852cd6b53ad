"""PLY (Stanford polygon file) reader and writer: ascii and binary, either byte order.

The ``vertex`` element must have ``x``, ``y`` and ``z`` properties of any numeric
type; its other properties are skipped.  The ``face`` element must have a list
property ``vertex_indices`` (or ``vertex_index``) with an integer index type; its
other properties are skipped, and so are all other elements.  In ascii files each
element record is one line.  Binary faces that are all the same size are read in one
numpy step; mixed sizes go through a per-record reader.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from service.base.errors import MeshFileError, SettingsError
from service.loaders._build import (
    bounded_int,
    decode_text,
    finish_mesh,
    pad_flat,
    read_bytes,
    to_int,
)
from service.mesh_repair import MeshRepair
from service.render.mesh import Mesh

PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
FACE_LISTS = ("vertex_indices", "vertex_index")


@dataclass
class Property:
    """One property: its numpy type code, and the count type if it is a list."""

    name: str
    dtype: str
    count_dtype: str = ""


@dataclass
class Element:
    """One element declared in the header."""

    name: str
    count: int
    props: list[Property] = field(default_factory=list)


@dataclass
class Header:
    """The parsed header: format (byte-order prefix or ``""`` for ascii) and elements."""

    fmt: str | None = None
    elements: list[Element] = field(default_factory=list)
    n_lines: int = 0


def _ply_type(path: Path, where: str, name: str) -> str:
    if name not in PLY_TYPES:
        raise MeshFileError(str(path), where, f"unknown PLY property type {name[:20]!r}")
    return PLY_TYPES[name]


def _h_format(path: Path, where: str, tokens: list[str], head: Header) -> None:
    if len(tokens) != 3 or tokens[1] not in FORMATS:
        raise MeshFileError(str(path), where, f"unknown PLY format {' '.join(tokens[1:])[:40]!r}")
    head.fmt = FORMATS[tokens[1]]


def _h_element(path: Path, where: str, tokens: list[str], head: Header) -> None:
    if len(tokens) != 3:
        raise MeshFileError(str(path), where, "expected 'element NAME COUNT'")
    count = to_int(path, where, tokens[2], "element count")
    if count < 0:
        raise MeshFileError(str(path), where, "element count is negative")
    head.elements.append(Element(tokens[1], count))


def _h_property(path: Path, where: str, tokens: list[str], head: Header) -> None:
    if not head.elements:
        raise MeshFileError(str(path), where, "property before any element")
    if len(tokens) == 5 and tokens[1] == "list":
        item, count = (_ply_type(path, where, t) for t in (tokens[3], tokens[2]))
        prop = Property(tokens[4], item, count)
        if prop.count_dtype[0] == "f":
            raise MeshFileError(str(path), where, "a list count must have an integer type")
    elif len(tokens) == 3:
        prop = Property(tokens[2], _ply_type(path, where, tokens[1]))
    else:
        raise MeshFileError(str(path), where, "expected 'property TYPE NAME' or a list property")
    head.elements[-1].props.append(prop)


def _h_ignore(path: Path, where: str, tokens: list[str], head: Header) -> None:
    """Comments and object info carry nothing we need."""


HEADER_KEYWORDS = {
    "format": _h_format, "element": _h_element, "property": _h_property,
    "comment": _h_ignore, "obj_info": _h_ignore,
}


def parse_header(path: Path, data: bytes) -> tuple[Header, int]:
    """Parse the header; return it and the byte offset where the body starts."""
    if not data.startswith(b"ply"):
        raise MeshFileError(str(path), "line 1", "not a PLY file (it must start with 'ply')")
    head, pos = Header(), 0
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            where = f"line {head.n_lines + 1}"
            raise MeshFileError(str(path), where, "the header has no end_header")
        head.n_lines += 1
        where = f"line {head.n_lines}"
        tokens = decode_text(path, data[pos:end], head.n_lines).split()
        pos = end + 1
        if head.n_lines == 1 or not tokens:
            continue
        if tokens[0] == "end_header":
            break
        if tokens[0] not in HEADER_KEYWORDS:
            raise MeshFileError(str(path), where, f"unknown header keyword {tokens[0][:20]!r}")
        HEADER_KEYWORDS[tokens[0]](path, where, tokens, head)
    if head.fmt is None:
        raise MeshFileError(str(path), "", "the header has no format line")
    return head, pos


# --- ascii body -------------------------------------------------------------------


def _ascii_record(
    path: Path, where: str, tokens: list[str], props: list[Property], strict: bool = True
) -> tuple[list, bool]:
    """Values of one record, and whether it had extra trailing values.

    A float per scalar, a list of ints per list property; extra values at the end are
    ignored unless ``strict``, which refuses them.
    """
    values, i = [], 0
    try:
        for prop in props:
            if prop.count_dtype:
                n = int(tokens[i])
                if n < 0:
                    raise ValueError
                items = tokens[i + 1 : i + 1 + n]
                if len(items) < n:
                    raise IndexError
                values.append([bounded_int(t) for t in items] if prop.dtype[0] != "f" else items)
                i += 1 + n
            else:
                values.append(float(tokens[i]))
                i += 1
    except IndexError:
        reason = "too few values for the declared properties"
        raise MeshFileError(str(path), where, reason) from None
    except ValueError:
        reason = "a value is not a number of the declared type"
        raise MeshFileError(str(path), where, reason) from None
    except OverflowError:
        raise MeshFileError(str(path), where, "an integer value is out of range") from None
    if i != len(tokens) and strict:
        raise MeshFileError(str(path), where, "more values than the declared properties")
    return values, i != len(tokens)


# --- binary body ------------------------------------------------------------------


class _Truncated(Exception):
    """The data ran out inside record ``record`` of the element being read."""

    def __init__(self, record: int) -> None:
        self.record = record


def _fixed_dtype(el: Element, order: str, data: bytes, start: int) -> np.dtype | None:
    """Record dtype if every list may have the first record's length, else None."""
    fields = []
    pos = start
    for i, p in enumerate(el.props):
        if not p.count_dtype:
            fields.append((f"p{i}", order + p.dtype))
            pos += np.dtype(p.dtype).itemsize
            continue
        if fields and any(f[0] == "count" for f in fields):
            return None  # more than one list: use the general reader
        cd = np.dtype(order + p.count_dtype)
        if el.count == 0 or pos + cd.itemsize > len(data):
            return None
        n = int(np.frombuffer(data, cd, 1, pos)[0])
        fields += [("count", cd), (f"p{i}", order + p.dtype, (max(n, 0),))]
        pos += cd.itemsize + max(n, 0) * np.dtype(p.dtype).itemsize
    return np.dtype(fields)


def _binary_fast(el: Element, order: str, data: bytes, start: int) -> tuple[list | None, int]:
    """Whole-element numpy read of fixed-size records; ``(None, start)`` if not fixed."""
    dt = _fixed_dtype(el, order, data, start)
    if dt is None:
        return None, start
    end = start + dt.itemsize * el.count
    has_list = "count" in dt.names
    if end > len(data):
        if has_list:
            return None, start  # the general reader finds the record where it ends
        raise _Truncated((len(data) - start) // max(dt.itemsize, 1))
    arr = np.frombuffer(data, dt, el.count, start)
    if has_list and np.any(arr["count"] != dt[dt.names.index("count") + 1].shape[0]):
        return None, start
    return [arr[n] for n in dt.names if n != "count"], end


def _binary_general(el: Element, order: str, data: bytes, start: int) -> tuple[list, int]:
    """Record-by-record read: per-property columns, list properties as arrays."""
    cols: list[list] = [[] for _ in el.props]
    pos, size = start, len(data)
    codes = [
        (np.dtype(order + p.dtype), struct.Struct(order + np.dtype(p.count_dtype).char))
        if p.count_dtype else (np.dtype(order + p.dtype), None)
        for p in el.props
    ]
    for r in range(el.count):
        for col, (item, count) in zip(cols, codes, strict=True):
            if count is None:
                if pos + item.itemsize > size:
                    raise _Truncated(r)
                col.append(np.frombuffer(data, item, 1, pos)[0])
                pos += item.itemsize
                continue
            if pos + count.size > size:
                raise _Truncated(r)
            n = count.unpack_from(data, pos)[0]
            pos += count.size
            if n < 0 or pos + n * item.itemsize > size:
                raise _Truncated(r)
            col.append(np.frombuffer(data, item, n, pos))
            pos += n * item.itemsize
    return cols, pos


def _read_binary(
    path: Path, data: bytes, head: Header, start: int, strict: bool
) -> tuple[dict[str, list], int]:
    """Columns (one per property) of every element, and 0 lines with trailing values."""
    out, pos = {}, start
    for el in head.elements:
        try:
            cols, new_pos = _binary_fast(el, head.fmt, data, pos)
            if cols is None:
                cols, new_pos = _binary_general(el, head.fmt, data, pos)
        except _Truncated as exc:
            where = f"{el.name} {exc.record}"
            raise MeshFileError(str(path), where, "the file ends early") from None
        pos = new_pos
        out[el.name] = cols
    return out, 0


def _read_ascii(
    path: Path, data: bytes, head: Header, start: int, strict: bool
) -> tuple[dict[str, list], int]:
    """Columns of every element of an ascii body (one record per non-blank line).

    Also returns how many lines had extra trailing values (ignored; ``strict``
    refuses them).
    """
    lines = decode_text(path, data[start:], head.n_lines + 1).splitlines()
    rows = [(head.n_lines + 1 + i, s.split()) for i, s in enumerate(lines) if s.strip()]
    out, pos, trailing = {}, 0, 0
    for el in head.elements:
        if pos + el.count > len(rows):
            raise MeshFileError(str(path), f"{el.name} {len(rows) - pos}", "the file ends early")
        chunk = rows[pos : pos + el.count]
        recs = [_ascii_record(path, f"line {n}", t, el.props, strict) for n, t in chunk]
        trailing += sum(extra for _, extra in recs)
        pos += el.count
        cols = [list(c) for c in zip(*(r for r, _ in recs), strict=True)]
        out[el.name] = cols or [[] for _ in el.props]
    return out, trailing


BODY_READERS = {"": _read_ascii, "<": _read_binary, ">": _read_binary}


# --- assembly ---------------------------------------------------------------------


def _find(path: Path, el: Element, names: tuple[str, ...], want_list: bool) -> int:
    for i, p in enumerate(el.props):
        if p.name in names and bool(p.count_dtype) == want_list:
            return i
    kind = "list property" if want_list else "property"
    raise MeshFileError(str(path), f"element {el.name}", f"no {kind} {' or '.join(names)}")


def _vertices(path: Path, el: Element, cols: list) -> np.ndarray:
    idx = [_find(path, el, (axis,), False) for axis in "xyz"]
    verts = np.stack([np.asarray(cols[i], dtype=np.float64) for i in idx], axis=1).reshape(-1, 3)
    bad = np.nonzero(~np.all(np.isfinite(verts), axis=1))[0]
    if bad.size:
        raise MeshFileError(str(path), f"vertex {int(bad[0])}", "coordinate is not finite")
    return verts


def _faces(
    path: Path, el: Element, cols: list, n_verts: int, strict: bool
) -> tuple[np.ndarray, np.ndarray]:
    i = _find(path, el, FACE_LISTS, True)
    if el.props[i].dtype[0] == "f":
        raise MeshFileError(str(path), f"element {el.name}", "vertex indices must be integers")
    col = cols[i]
    if isinstance(col, np.ndarray):  # fast path: (F, n)
        counts = np.full(col.shape[0], col.shape[1], dtype=np.int64)
        flat = col.reshape(-1).astype(np.int64)
    else:
        counts = np.array([len(f) for f in col], dtype=np.int64)
        flat = np.concatenate([np.asarray(f, np.int64) for f in col]) if col else np.zeros(0, int)
    small = np.nonzero(counts < 3)[0] if strict else np.zeros(0, np.int64)
    if small.size:
        f = int(small[0])
        raise MeshFileError(str(path), f"face {f}", f"has {counts[f]} vertices; at least 3 needed")
    out = np.nonzero((flat < 0) | (flat >= n_verts))[0]
    if out.size:
        f = int(np.searchsorted(np.cumsum(counts), out[0], side="right"))
        raise MeshFileError(
            str(path), f"face {f}", f"vertex index {flat[out[0]]} is outside 0..{n_verts - 1}"
        )
    return pad_flat(flat, counts), counts


def load_ply(path: str | Path, strict: bool = False) -> Mesh:
    """Read a PLY file (ascii, binary_little_endian or binary_big_endian).

    Parameters
    ----------
    path : str or Path
    strict : bool
        Refuse faces of under 3 corners, extra values on ascii lines, and polygons
        that are not planar and convex, instead of repairing them
        (:mod:`service.mesh_repair`).

    Returns
    -------
    Mesh
        Vertices (V, 3) from x, y, z; polygons from the face element's index lists
        (degenerate faces dropped, bad shapes triangulated, with one warning).

    Raises
    ------
    MeshFileError
        Naming the header line, or the element record (``"face 7"``), at fault; a
        face that is not planar and convex is reported as its record.
    """
    path = Path(path)
    data = read_bytes(path)
    head, start = parse_header(path, data)
    elements = {el.name: el for el in head.elements}
    for need in ("vertex", "face"):
        if need not in elements:
            raise MeshFileError(str(path), "header", f"no {need} element")
    cols, trailing = BODY_READERS[head.fmt](path, data, head, start, strict)
    verts = _vertices(path, elements["vertex"], cols["vertex"])
    polygons, counts = _faces(path, elements["face"], cols["face"], verts.shape[0], strict)
    report = MeshRepair(trailing_values=trailing)
    return finish_mesh(path, verts, polygons, counts, lambda p: f"face {p}", strict, report)


def save_ply(path: str | Path, mesh: Mesh, fmt: str = "binary_little_endian") -> None:
    """Write a mesh as PLY: double x, y, z and a ``uchar int vertex_indices`` list.

    Parameters
    ----------
    path : str or Path
    mesh : Mesh
    fmt : {"ascii", "binary_little_endian", "binary_big_endian"}

    Raises
    ------
    SettingsError
        For another format, or a polygon of more than 255 vertices.
    """
    if fmt not in FORMATS or mesh.counts.size and mesh.counts.max() > 255:
        raise SettingsError(f"cannot write PLY format {fmt!r} (or a face has > 255 vertices)")
    head = (
        f"ply\nformat {fmt} 1.0\ncomment written by Holo-realizer\n"
        f"element vertex {mesh.n_vertices}\nproperty double x\nproperty double y\n"
        f"property double z\nelement face {mesh.n_polygons}\n"
        "property list uchar int vertex_indices\nend_header\n"
    )
    rows = [row[:k] for row, k in zip(mesh.polygons, mesh.counts, strict=True)]
    if fmt == "ascii":
        body = "".join(" ".join(repr(float(c)) for c in v) + "\n" for v in mesh.vertices)
        body += "".join(f"{len(r)} " + " ".join(str(int(i)) for i in r) + "\n" for r in rows)
        Path(path).write_bytes(head.encode() + body.encode())
        return
    order = FORMATS[fmt]
    parts = [head.encode(), mesh.vertices.astype(order + "f8").tobytes()]
    for r in rows:
        parts += [bytes([len(r)]), r.astype(order + "i4").tobytes()]
    Path(path).write_bytes(b"".join(parts))
