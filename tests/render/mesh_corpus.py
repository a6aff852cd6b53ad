"""A corpus of mesh files as other tools write them, with what loading them must report.

Seven are the files issue 13 found refused (Blender, a quad-mesh knot, a concave
polygon, near-planar polygons, a 2-index face, MeshLab's trailing values, a far
non-planar pentagon); the rest are good files that must load untouched.  Each case is
built so its expected counts are known by construction, not by running the loader.

Run as a script to write the corpus to a folder: ``python tests/render/mesh_corpus.py DIR``.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Case:
    """One corpus file and what a non-strict load must count.

    ``expect`` holds :class:`~service.mesh_repair.MeshRepair` counts (missing keys are
    0); ``strict_error`` is a phrase the strict refusal contains ("" for a good file).
    """

    name: str
    write: Callable[[Path], None]
    expect: dict = field(default_factory=dict)
    strict_error: str = ""


def _obj_text(verts: np.ndarray, faces: list, header: str, fmt: str = "{:.6f}") -> str:
    lines = [f"# {header}"]
    lines += ["v " + " ".join(fmt.format(c) for c in v) for v in verts]
    lines += ["f " + " ".join(str(i + 1) for i in f) for f in faces]
    return "\n".join(lines) + "\n"


def grid_quads(n: int, lift: float) -> tuple[np.ndarray, list, int]:
    """An n x n grid of unit quads on z = 0 where every other quad has a corner lifted.

    Corners are shared, so a lifted corner belongs only to quads of the "odd" colour:
    the grid's own vertices stay at z = 0 and each odd quad gets its own extra corner.

    Returns
    -------
    verts : (V, 3), faces : list of 4-lists, lifted : int
        ``lifted`` odd quads are off their plane by about ``lift``.
    """
    xs, ys = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0), indexing="ij")
    verts = [np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)]
    faces, lifted, extra = [], 0, (n + 1) ** 2

    def vid(i: int, j: int) -> int:
        return i * (n + 1) + j

    for i in range(n):
        for j in range(n):
            quad = [vid(i, j), vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1)]
            if (i + j) % 2:
                verts.append(np.array([[i + 1.0, j + 1.0, lift]]))
                quad[2] = extra
                extra += 1
                lifted += 1
            faces.append(quad)
    return np.concatenate(verts) / n, faces, lifted


def _write_blender_ply(path: Path, verts: np.ndarray, faces: list) -> None:
    """Binary little-endian PLY as Blender writes it: float x y z nx ny nz s t, uint lists."""
    head = (
        "ply\nformat binary_little_endian 1.0\ncomment Created by Blender 3.6.0\n"
        f"element vertex {len(verts)}\n"
        + "".join(f"property float {p}\n" for p in ("x", "y", "z", "nx", "ny", "nz", "s", "t"))
        + f"element face {len(faces)}\nproperty list uchar uint vertex_indices\nend_header\n"
    )
    rec = np.zeros((len(verts), 8), "<f4")
    rec[:, :3] = verts
    rec[:, 5] = 1.0
    body = [rec.tobytes()]
    for f in faces:
        body.append(bytes([len(f)]) + np.asarray(f, "<u4").tobytes())
    path.write_bytes(head.encode() + b"".join(body))


def write_suzanne(path: Path) -> None:
    """Suzanne-like: a 12 x 12 quad grid (extent 2.7), 72 quads 0.00026 off planar."""
    verts, faces, _ = grid_quads(12, 0.00026 * 12 / 2.7)
    _write_blender_ply(path, verts * 2.7, faces)


def knot_quads(segments: int = 229, ring: int = 5) -> tuple[np.ndarray, list]:
    """A tube of quads around a (2, 3) torus knot, its rings twisted by 36 degrees each."""
    t = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    centre = np.stack([(2 + np.cos(3 * t)) * np.cos(2 * t), (2 + np.cos(3 * t)) * np.sin(2 * t),
                       np.sin(3 * t)], axis=1)
    tangent = np.roll(centre, -1, axis=0) - np.roll(centre, 1, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    side = np.cross(tangent, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    up = np.cross(side, tangent)
    twist = np.radians(36) * np.arange(segments)[:, None]
    angle = 2 * np.pi * np.arange(ring)[None, :] / ring + twist
    verts = (centre[:, None, :] + 0.4 * (np.cos(angle)[..., None] * side[:, None, :]
                                         + np.sin(angle)[..., None] * up[:, None, :]))
    faces = [[s * ring + r, s * ring + (r + 1) % ring, ((s + 1) % segments) * ring + (r + 1) % ring,
              ((s + 1) % segments) * ring + r] for s in range(segments) for r in range(ring)]
    return verts.reshape(-1, 3), faces


def write_knot(path: Path) -> None:
    """A quad-mesh knot OBJ: 1,145 quads, every one twisted off its plane."""
    verts, faces = knot_quads()
    path.write_text(_obj_text(verts, faces, "quad-mesh torus knot"))


_STAR_ANGLES = np.linspace(0, 2 * np.pi, 10, endpoint=False)
STAR = [(np.cos(a) * r, np.sin(a) * r) for a, r in zip(_STAR_ANGLES, [1, 0.4] * 5, strict=True)]


def write_concave(path: Path) -> None:
    """A planar 10-corner star (concave) next to a triangle and a square."""
    verts = [(x, y, 0.0) for x, y in STAR] + [(2, 0, 0), (3, 0, 0), (2, 1, 0), (3, 1, 0)]
    faces = [list(range(10)), [10, 11, 12], [11, 13, 12]]
    path.write_text(_obj_text(np.array(verts), faces, "exported by a CAD program"))


def write_near_planar(path: Path) -> None:
    """An 8 x 8 quad grid (extent 1) with 32 quads 0.0005 off planar, as an OBJ."""
    verts, faces, _ = grid_quads(8, 0.0005)
    path.write_text(_obj_text(verts, faces, "polygons 0.0005 off planar"))


def write_two_index(path: Path) -> None:
    """An OBJ of a quad and two triangles plus one face of only 2 indices."""
    verts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], float)
    text = _obj_text(verts, [[0, 1, 2, 3], [1, 4, 5], [1, 5, 2]], "one bad face")
    path.write_text(text + "f 1 5\n")


def write_meshlab(path: Path) -> None:
    """MeshLab ascii PLY: an octahedron whose face lines carry 4 undeclared trailing values."""
    verts = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    faces = [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5),
             (0, 3, 5)]
    lines = ["ply", "format ascii 1.0", "comment VCGLIB generated", "element vertex 6",
             "property float x", "property float y", "property float z", "element face 8",
             "property list uchar int vertex_indices", "end_header"]
    lines += [f"{x} {y} {z} " for x, y, z in verts]
    lines += [f"3 {a} {b} {c} 255 255 255 255 " for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


def write_far_pentagon(path: Path) -> None:
    """A 5-corner polygon far from planar (a saddle) among two triangles."""
    a = np.linspace(0, 2 * np.pi, 5, endpoint=False)
    penta = np.stack([np.cos(a), np.sin(a), 0.6 * np.cos(2 * a)], axis=1)
    verts = np.concatenate([penta, [[3, 0, 0], [4, 0, 0], [3, 1, 0]]])
    path.write_text(_obj_text(verts, [[0, 1, 2, 3, 4], [5, 6, 7], [5, 7, 6]], "saddle pentagon"))


def write_good_cube_ply(path: Path) -> None:
    """A cube of planar, convex quads, binary, as Blender writes it."""
    from service.primitives import cube

    c = cube(1.0)
    _write_blender_ply(path, c.vertices, [list(r[:k]) for r, k in zip(c.polygons, c.counts,
                                                                      strict=True)])


def write_good_sphere_obj(path: Path) -> None:
    """A UV sphere of quads and triangles, 6 decimals (within the planarity tolerance)."""
    from service.primitives import sphere

    s = sphere(1.0, 12, 16)
    faces = [list(r[:k]) for r, k in zip(s.polygons, s.counts, strict=True)]
    path.write_text(_obj_text(s.vertices, faces, "UV sphere"))


def write_good_ascii_ply(path: Path) -> None:
    """A flat grid of exact quads, ascii PLY with declared colour values on its faces."""
    verts, faces, _ = grid_quads(4, 0.0)
    lines = ["ply", "format ascii 1.0", f"element vertex {len(verts)}", "property double x",
             "property double y", "property double z", f"element face {len(faces)}",
             "property list uchar int vertex_indices", "property uchar red", "end_header"]
    lines += [" ".join(repr(float(c)) for c in v) for v in verts]
    lines += [f"4 {' '.join(str(i) for i in f)} 200" for f in faces]
    path.write_text("\n".join(lines) + "\n")


NON_PLANAR_STRICT = "is not planar"
_SPLIT = "triangles_added"
CASES = [
    Case("suzanne.ply", write_suzanne, {"non_planar": 72, _SPLIT: 144}, NON_PLANAR_STRICT),
    Case("knot.obj", write_knot, {"non_planar": 1145, "triangles_added": 2290}, NON_PLANAR_STRICT),
    Case("concave.obj", write_concave, {"concave": 1, "triangles_added": 8}, "is not convex"),
    Case("near_planar.obj", write_near_planar, {"non_planar": 32, "triangles_added": 64},
         NON_PLANAR_STRICT),
    Case("two_index.obj", write_two_index, {"degenerate": 1}, "a face needs >= 3 vertices"),
    Case("meshlab.ply", write_meshlab, {"trailing_values": 8}, "more values than the declared"),
    Case("far_pentagon.obj", write_far_pentagon, {"non_planar": 1, "triangles_added": 3},
         NON_PLANAR_STRICT),
    Case("cube.ply", write_good_cube_ply),
    Case("sphere.obj", write_good_sphere_obj),
    Case("grid.ply", write_good_ascii_ply),
]
"""The corpus: the seven files issue 13 found refused, then good ones."""


def write_corpus(folder: Path) -> list[Path]:
    """Write every case into ``folder``; return the paths in ``CASES`` order."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for case in CASES:
        case.write(folder / case.name)
        paths.append(folder / case.name)
    return paths


if __name__ == "__main__":
    for p in write_corpus(Path(sys.argv[1] if len(sys.argv) > 1 else "mesh-corpus")):
        print(p)
