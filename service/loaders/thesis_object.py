"""The thesis's object file (``.hobj``): counts, then each polygon's vertex coordinates.

Seed 000, section 3.1: "The object file contains the number of polygons, the number
of vertices in the object, and the (x, y, z) coordinates for each vertex of each
polygon"; the program reads ``Numverts`` (vertices in the whole object, counted
polygon by polygon) and ``Numpolyg``.  The exact grammar is in
``docs/file-formats.md``::

    # comment            (anything after '#' on any line)
    NUMVERTS NUMPOLYG    (first data line; NUMVERTS = sum of the k below)
    k                    (per polygon: its vertex count, k >= 3)
    x y z                (k lines, counter-clockwise seen from outside)
    ...

Blank lines are ignored.  Coordinates repeated exactly are welded into one shared
vertex (in order of first appearance) so smooth normals work.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from service.base.errors import MeshFileError
from service.loaders._build import finish_mesh, pad_flat, text_lines, to_float, to_int
from service.render.mesh import Mesh


def _data_lines(lines: list[str]) -> list[tuple[int, list[str]]]:
    """(line number, tokens) of every line with data, comments removed."""
    out = []
    for n, line in enumerate(lines, start=1):
        tokens = (line[: line.index("#")] if "#" in line else line).split()
        if tokens:
            out.append((n, tokens))
    return out


def _header(path: Path, rows: list) -> tuple[int, int]:
    """NUMVERTS and NUMPOLYG from the first data line."""
    if not rows:
        raise MeshFileError(str(path), "", "the file has no data (only comments)")
    n, tokens = rows[0]
    where = f"line {n}"
    if len(tokens) != 2:
        reason = f"expected 'NUMVERTS NUMPOLYG', got {len(tokens)} values"
        raise MeshFileError(str(path), where, reason)
    nverts = to_int(path, where, tokens[0], "NUMVERTS")
    npolyg = to_int(path, where, tokens[1], "NUMPOLYG")
    if nverts < 3 or npolyg < 1:
        raise MeshFileError(str(path), where, "NUMVERTS must be >= 3 and NUMPOLYG >= 1")
    return nverts, npolyg


def _structure(path: Path, rows: list, npolyg: int) -> tuple[np.ndarray, list[int]]:
    """Walk the polygon headers: each polygon's k, and where its first coordinate row is."""
    counts = np.empty(npolyg, dtype=np.int64)
    starts, pos = [], 1
    for p in range(npolyg):
        if pos >= len(rows):
            raise MeshFileError(str(path), f"polygon {p}", "the file ends before this polygon")
        n, tokens = rows[pos]
        where = f"line {n}"
        if len(tokens) != 1:
            raise MeshFileError(str(path), where, f"expected the vertex count of polygon {p}")
        k = to_int(path, where, tokens[0], "vertex count")
        if k < 3:
            reason = f"polygon {p} has {k} vertices; at least 3 needed"
            raise MeshFileError(str(path), where, reason)
        if pos + k >= len(rows):
            reason = f"the file ends inside this polygon (line {n} says {k} vertices)"
            raise MeshFileError(str(path), f"polygon {p}", reason)
        counts[p] = k
        starts.append(pos + 1)
        pos += 1 + k
    if pos < len(rows):
        raise MeshFileError(str(path), f"line {rows[pos][0]}", "data after the last polygon")
    return counts, starts


def _coordinates(path: Path, rows: list, counts: np.ndarray, starts: list[int]) -> np.ndarray:
    """The x y z rows of all polygons, shape (sum(counts), 3); errors name the line."""
    picked = [rows[s + j] for s, k in zip(starts, counts.tolist(), strict=True) for j in range(k)]
    for n, tokens in picked:
        if len(tokens) != 3:
            reason = f"expected 'x y z', got {len(tokens)} values"
            raise MeshFileError(str(path), f"line {n}", reason)
    try:
        points = np.array([float(t) for _, tokens in picked for t in tokens]).reshape(-1, 3)
    except ValueError:
        points = None  # find the culprit line below
    if points is None or not np.all(np.isfinite(points)):
        for n, tokens in picked:
            for t in tokens:
                to_float(path, f"line {n}", t)
    return points + 0.0  # + 0.0 turns -0.0 into 0.0 so welding compares values


def weld(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge exactly equal rows, keeping the order of first appearance.

    Parameters
    ----------
    points : ndarray, shape (N, 3)

    Returns
    -------
    unique : ndarray, shape (V, 3)
    index : ndarray, shape (N,), int64
        ``unique[index] == points``.
    """
    order = np.lexsort(points.T[::-1])
    srt = points[order]
    new = np.concatenate([[True], np.any(srt[1:] != srt[:-1], axis=1)])
    group = np.cumsum(new) - 1
    first = order[new]  # lexsort is stable: the earliest row of each group
    rank = np.empty(first.size, dtype=np.int64)
    rank[np.argsort(first)] = np.arange(first.size)
    index = np.empty(points.shape[0], dtype=np.int64)
    index[order] = rank[group]
    return points[np.sort(first)], index


def load_thesis_object(path: str | Path, strict: bool = False) -> Mesh:
    """Read a thesis object file.

    Parameters
    ----------
    path : str or Path
    strict : bool
        Refuse polygons that are not planar and convex instead of triangulating them
        (:func:`~service.loaders._build.finish_mesh`).

    Returns
    -------
    Mesh
        Welded vertices (V, 3); polygons (NUMPOLYG, max k), minus any zero-area ones.

    Raises
    ------
    MeshFileError
        Naming the line or polygon at fault; a polygon that is not planar and convex
        is reported at the line of its vertex count ``k``.
    """
    path = Path(path)
    rows = _data_lines(text_lines(path))
    nverts, npolyg = _header(path, rows)
    counts, starts = _structure(path, rows, npolyg)
    if int(counts.sum()) != nverts:
        reason = f"NUMVERTS is {nverts} but the polygons list {int(counts.sum())} vertices"
        raise MeshFileError(str(path), f"line {rows[0][0]}", reason)
    vertices, index = weld(_coordinates(path, rows, counts, starts))
    k_lines = [rows[s - 1][0] for s in starts]  # the line of each polygon's k
    polygons = pad_flat(index, counts)
    return finish_mesh(path, vertices, polygons, counts, lambda p: f"line {k_lines[p]}",
                       strict)


def save_thesis_object(path: str | Path, mesh: Mesh, comment: str = "") -> None:
    """Write a mesh as a thesis object file (coordinates written exactly, ``repr``).

    Parameters
    ----------
    path : str or Path
    mesh : Mesh
    comment : str
        Written as ``#`` lines at the top.
    """
    out = [f"# {line}" for line in comment.splitlines()]
    out.append(f"{int(mesh.counts.sum())} {mesh.n_polygons}")
    for row, k in zip(mesh.polygons, mesh.counts, strict=True):
        out.append(str(int(k)))
        out.extend(" ".join(repr(float(c)) for c in mesh.vertices[i]) for i in row[:k])
    Path(path).write_text("\n".join(out) + "\n", encoding="utf-8")
