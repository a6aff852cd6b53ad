"""Helpers shared by the mesh loaders: reading, decoding, number parsing, assembly.

Every failure becomes a :class:`~service.base.errors.MeshFileError` naming the file and
the line or element, so no loader lets a bare ``ValueError``, ``UnicodeDecodeError``
or numpy error escape.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from service.base.errors import MeshError, MeshFileError
from service.mesh_repair import MeshRepair, MeshRepairWarning, distinct_corners, split_bad_shapes
from service.render.mesh import Mesh, describe_fault, polygon_shape_faults, too_large


def read_bytes(path: str | Path) -> bytes:
    """The whole file; an unreadable or empty file raises :class:`MeshFileError`."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise MeshFileError(str(path), "", f"cannot read the file: {exc.strerror or exc}") from None
    if not data.strip():
        raise MeshFileError(str(path), "", "the file is empty")
    return data


def decode_text(path: str | Path, data: bytes, first_line: int = 1) -> str:
    """Decode UTF-8 text (a BOM is dropped), refusing binary data.

    Parameters
    ----------
    path : str or Path
        For messages.
    data : bytes
    first_line : int
        Line number of the first line of ``data`` in the file.
    """
    nul = data.find(b"\x00")
    if nul >= 0:
        line = first_line + data.count(b"\n", 0, nul)
        raise MeshFileError(str(path), f"line {line}", "binary data (a NUL byte) in a text file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = first_line + data.count(b"\n", 0, exc.start)
        raise MeshFileError(str(path), f"line {line}", "the text is not valid UTF-8") from None
    return text.removeprefix("\ufeff")


def text_lines(path: str | Path) -> list[str]:
    """Read a text file as a list of lines (line ``n`` at index ``n - 1``)."""
    return decode_text(path, read_bytes(path)).splitlines()


def to_float(path: str | Path, where: str, token: str) -> float:
    """Parse a finite float or raise :class:`MeshFileError` at ``where``."""
    try:
        value = float(token)
    except ValueError:
        raise MeshFileError(str(path), where, f"not a number: {token[:40]!r}") from None
    if not math.isfinite(value):
        raise MeshFileError(str(path), where, f"coordinate is not finite: {token[:40]!r}")
    return value


#: Integers in mesh files are below this in magnitude (an int64 holds them); a larger
#: index or count is refused, not an OverflowError where numpy takes it.
INT_LIMIT = 1 << 62


def bounded_int(token: str) -> int:
    """``int(token)``; ValueError if not an integer, OverflowError past :data:`INT_LIMIT`."""
    value = int(token)
    if not -INT_LIMIT < value < INT_LIMIT:
        raise OverflowError(token)
    return value


def to_int(path: str | Path, where: str, token: str, what: str) -> int:
    """Parse an integer (``what`` names it in messages) or raise at ``where``."""
    try:
        return bounded_int(token)
    except ValueError:
        raise MeshFileError(str(path), where, f"{what} is not an integer: {token[:40]!r}") from None
    except OverflowError:
        raise MeshFileError(str(path), where, f"{what} is out of range: {token[:40]!r}") from None


def pad_flat(flat: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Padded polygon array from concatenated indices.

    Parameters
    ----------
    flat : ndarray, shape (sum(counts),)
        Vertex indices of all polygons, one after another.
    counts : ndarray, shape (P,)

    Returns
    -------
    ndarray, shape (P, max(counts)), int64
        Padded with -1.
    """
    counts = np.asarray(counts, dtype=np.int64)
    width = int(counts.max()) if counts.size else 3
    out = np.full((counts.size, width), -1, dtype=np.int64)
    rows = np.repeat(np.arange(counts.size), counts)
    cols = np.arange(rows.size) - np.repeat(np.cumsum(counts) - counts, counts)
    out[rows, cols] = flat
    return out


def twice_areas(vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Twice each polygon's vector area (Newell), shape (P,)."""
    total = np.zeros((polygons.shape[0], 3))
    ar = np.arange(polygons.shape[0])
    for i in range(polygons.shape[1]):
        nxt = np.where(i + 1 < counts, min(i + 1, polygons.shape[1] - 1), 0)
        cross = np.cross(vertices[polygons[:, i]], vertices[polygons[ar, nxt]])
        total += np.where((counts > i)[:, None], cross, 0.0)
    return np.linalg.norm(total, axis=1)


def by_polygon(p: int) -> str:
    """The default place of polygon ``p`` in messages (``"polygon 3"``)."""
    return f"polygon {p}"


def check_shapes(
    path: str | Path, vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray,
    where: Callable[[int], str] = by_polygon,
) -> None:
    """Refuse a non-planar or non-convex polygon, naming its place in the file.

    Parameters
    ----------
    path : str or Path
    vertices : ndarray, shape (V, 3), finite
    polygons : ndarray, shape (P, K), indices in range, padded with -1
    counts : ndarray, shape (P,)
    where : callable
        Polygon index (file order, from 0) to its place: ``"line 12"``, ``"face 7"``.

    Raises
    ------
    MeshFileError
        For the first bad polygon (see :func:`service.render.mesh.polygon_shape_faults`).
    """
    faults = polygon_shape_faults(vertices, polygons, counts)
    if faults.polygon.size:
        raise MeshFileError(str(path), where(int(faults.polygon[0])), describe_fault(faults))


def finish_mesh(
    path: str | Path, vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray,
    where: Callable[[int], str] = by_polygon, strict: bool = False,
    report: MeshRepair | None = None,
) -> Mesh:
    """Repair (or, if ``strict``, check) the polygons, drop zero-area ones, build the mesh.

    Unless ``strict``, faces with fewer than 3 distinct corners are skipped and
    non-planar or concave polygons are replaced by ear-clipped triangles
    (:mod:`service.mesh_repair`), with one :class:`MeshRepairWarning` saying so.
    ``strict`` refuses a polygon that is not planar and convex, as before.

    Parameters
    ----------
    path : str or Path
        The file read; its stem names the mesh.
    vertices : ndarray, shape (V, 3), finite
    polygons : ndarray, shape (P, K), indices checked in range, padded with -1
    counts : ndarray, shape (P,); each >= 3 when ``strict``
    where : callable
        Polygon index (file order) to its place in the file, for messages.
    strict : bool
    report : MeshRepair, optional
        Repairs the reader already made (trailing values); counted on here.

    Raises
    ------
    MeshFileError
        If there are no polygons, none with a non-zero area, or (``strict``) a
        polygon is not planar and convex.

    Returns
    -------
    Mesh
        Its ``repair`` says what was repaired.
    """
    vertices = _checked_vertices(path, vertices)
    report = report or MeshRepair()
    report.faces_read = int(counts.size)
    if counts.size == 0:
        raise MeshFileError(str(path), "", "the file has no polygons")
    from_split = np.zeros(counts.size, bool)
    if strict:
        check_shapes(path, vertices, polygons, counts, where)
    else:
        polygons, counts, from_split = _repair_shapes(path, vertices, polygons, counts, report)
    polygons, counts = _drop_zero_area(path, vertices, polygons, counts, from_split, strict, report)
    if not strict and report.message():
        _warn_repaired(path, report)
    return _mesh(path, vertices, polygons, counts, report)


def _checked_vertices(path: str | Path, vertices: np.ndarray) -> np.ndarray:
    """The vertices as float64 (V, 3); a vertex too large to compute with is refused.

    Checked before the repairs, which would call such polygons degenerate.
    """
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    big = too_large(vertices)  # before the repairs, which would call it degenerate
    if big is not None:
        raise MeshFileError(str(path), f"vertex {big[1]}", big[0])
    return vertices


def _repair_shapes(
    path: str | Path, vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray,
    report: MeshRepair,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Skip faces of under 3 distinct corners, ear-clip non-planar or concave ones.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    polygons : ndarray, shape (P, K), padded with -1
    counts : ndarray, shape (P,)
    report : MeshRepair
        Counts the repairs.

    Returns
    -------
    polygons : ndarray, shape (Q, K')
    counts : ndarray, shape (Q,)
    from_split : ndarray, shape (Q,), bool
        Which polygons are triangles of a split one.
    """
    few = distinct_corners(polygons, counts) < 3
    if few.any():
        report.degenerate += int(few.sum())
        polygons, counts = polygons[~few], counts[~few]
    if counts.size == 0:
        raise MeshFileError(str(path), "", "every polygon is degenerate (zero area)")
    return split_bad_shapes(vertices, polygons, counts, report)


def _warn_repaired(path: str | Path, report: MeshRepair) -> None:
    """One :class:`MeshRepairWarning` for the file, attributed to the loader's caller."""
    warnings.warn(MeshRepairWarning(
        f"{path}: repaired on load: {report.message()} (--strict refuses such files)"
    ), stacklevel=4)  # finish_mesh's stacklevel=3, one frame deeper


def _mesh(path: str | Path, vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray,
          report: MeshRepair) -> Mesh:
    """The mesh (its stem for a name); a mesh fault is a :class:`MeshFileError`."""
    try:
        return Mesh(vertices, polygons.astype(np.int64), counts.astype(np.int64),
                    Path(path).stem, repair=report)
    except MeshError as exc:
        raise MeshFileError(str(path), "", str(exc)) from None


def _drop_zero_area(
    path: str | Path, vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray,
    from_split: np.ndarray, strict: bool, report: MeshRepair,
) -> tuple[np.ndarray, np.ndarray]:
    """Polygons and counts without the zero-area ones (counted, or warned of if strict)."""
    centred = vertices - vertices.mean(axis=0)
    scale = float(np.abs(centred).max())
    keep = twice_areas(centred, polygons, counts) > 1e-12 * scale * scale
    if not keep.any():
        raise MeshFileError(str(path), "", "every polygon is degenerate (zero area)")
    if keep.all():
        return polygons, counts
    if strict:
        dropped = int((~keep).sum())
        warnings.warn(MeshRepairWarning(
            f"{path}: dropped {dropped} degenerate (zero-area) polygon(s)"), stacklevel=4)
    report.degenerate += int(np.sum(~keep & ~from_split))
    report.zero_area_triangles += int(np.sum(~keep & from_split))
    polygons, counts = polygons[keep], counts[keep]
    return polygons[:, : int(counts.max())], counts
