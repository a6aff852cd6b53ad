r"""Wavefront OBJ reader and writer (geometry only: ``v`` and ``f`` statements).

``v x y z [w]`` defines a vertex (extra values such as w or vertex colours are
ignored).  ``f`` lists three or more corners, each ``v``, ``v/vt``, ``v//vn`` or
``v/vt/vn``; ``v`` counts from 1, or from the end when negative (``-1`` is the last
vertex defined so far).  Every other statement (``vt``, ``vn``, ``o``, ``g``, ``s``,
``usemtl``, ``mtllib``, ``l``, ...) is ignored; ``#`` starts a comment and a line
ending in ``\`` continues on the next.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from service.base.errors import MeshFileError
from service.loaders._build import finish_mesh, pad_flat, text_lines, to_float, to_int
from service.render.mesh import Mesh


def _statements(lines: list[str]) -> list[tuple[int, list[str]]]:
    """(line number, tokens) of each statement, with continuations joined."""
    out, pending, start = [], "", 0
    for n, raw in enumerate(lines, start=1):
        line = raw.split("#", 1)[0]
        if not pending:
            start = n
        if line.rstrip().endswith("\\"):
            pending += line.rstrip()[:-1] + " "
            continue
        tokens = (pending + line).split()
        pending = ""
        if tokens:
            out.append((start, tokens))
    if pending.split():
        out.append((start, pending.split()))
    return out


def _vertex(path: Path, n: int, tokens: list[str], verts: list) -> None:
    if len(tokens) < 4:
        raise MeshFileError(str(path), f"line {n}", "a vertex needs x, y and z")
    verts.append([to_float(path, f"line {n}", t) for t in tokens[1:4]])


def _face(path: Path, n: int, tokens: list[str], n_verts: int, strict: bool) -> list[int]:
    """Zero-based vertex indices of one face (relative ones resolved)."""
    where = f"line {n}"
    if strict and len(tokens) < 4:
        raise MeshFileError(str(path), where, f"a face needs >= 3 vertices, got {len(tokens) - 1}")
    out = []
    for tok in tokens[1:]:
        i = to_int(path, where, tok.split("/", 1)[0], "vertex index")
        if i == 0 or i < -n_verts:
            raise MeshFileError(str(path), where, f"vertex index {i} is out of range")
        out.append(i - 1 if i > 0 else n_verts + i)
    return out


def load_obj(path: str | Path, strict: bool = False) -> Mesh:
    """Read the polygons of a Wavefront OBJ file.

    Parameters
    ----------
    path : str or Path
    strict : bool
        Refuse faces of under 3 corners, and polygons that are not planar and convex,
        instead of skipping or triangulating them (:mod:`service.mesh_repair`).

    Returns
    -------
    Mesh
        Vertices (V, 3) in file order; polygons in file order (degenerate ones
        dropped, bad shapes triangulated, with one warning).

    Raises
    ------
    MeshFileError
        Naming the line at fault; a polygon that is not planar and convex is
        reported at its ``f`` line.
    """
    path = Path(path)
    verts: list[list[float]] = []
    faces: list[list[int]] = []
    face_lines: list[int] = []
    for n, tokens in _statements(text_lines(path)):
        if tokens[0] == "v":
            _vertex(path, n, tokens, verts)
        elif tokens[0] == "f":
            faces.append(_face(path, n, tokens, len(verts), strict))
            face_lines.append(n)
    if not faces:
        raise MeshFileError(str(path), "", "no faces ('f' lines) in the file")
    counts = np.array([len(f) for f in faces], dtype=np.int64)
    flat = np.array([i for f in faces for i in f], dtype=np.int64)
    bad = np.nonzero(flat >= len(verts))[0]
    if bad.size:
        face = int(np.searchsorted(np.cumsum(counts), bad[0], side="right"))
        raise MeshFileError(
            str(path), f"line {face_lines[face]}",
            f"vertex index {flat[bad[0]] + 1} is beyond the {len(verts)} vertices",
        )
    vertices = np.array(verts, np.float64).reshape(-1, 3)
    polygons = pad_flat(flat, counts)
    return finish_mesh(path, vertices, polygons, counts, lambda p: f"line {face_lines[p]}",
                       strict)


def save_obj(path: str | Path, mesh: Mesh) -> None:
    """Write a mesh as OBJ ``v`` and ``f`` lines (coordinates written exactly).

    Parameters
    ----------
    path : str or Path
    mesh : Mesh
    """
    out = ["# written by Holo-realizer"]
    out += ["v " + " ".join(repr(float(c)) for c in v) for v in mesh.vertices]
    out += [
        "f " + " ".join(str(int(i) + 1) for i in row[:k])
        for row, k in zip(mesh.polygons, mesh.counts, strict=True)
    ]
    Path(path).write_text("\n".join(out) + "\n", encoding="utf-8")
