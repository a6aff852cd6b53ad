"""Repairs made while loading a mesh file, and the count of each.

Files written by other tools often break the rules a :class:`~service.render.mesh.Mesh`
keeps (polygons planar and convex, three or more distinct corners).  Unless the
loader is ``strict``, such a file is repaired instead of refused:

=====================  =================================================================
repair                 what is done
=====================  =================================================================
``non_planar``         a polygon off its plane is replaced by ear-clipped triangles
``concave``            a concave (or self-intersecting) polygon: the same
``degenerate``         a face with fewer than 3 distinct corners, or no area: skipped
``trailing_values``    an ascii PLY line with values beyond the declared ones: the
                       extra values are ignored
=====================  =================================================================

Each load that repairs anything gives one :class:`MeshRepairWarning`, one line long.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from service.render.mesh import CONVEX, PLANAR, polygon_shape_faults
from service.triangulate import triangulate_rows


class MeshRepairWarning(UserWarning):
    """A mesh file was repaired on load (see :class:`MeshRepair` for what was counted)."""


@dataclass
class MeshRepair:
    """What loading one mesh file repaired.

    Attributes
    ----------
    faces_read : int
        Faces (polygons) in the file.
    non_planar, concave : int
        Polygons replaced by their ear-clipped triangles, by the fault found.
    triangles_added : int
        Triangles that replaced them.
    degenerate : int
        Faces skipped: fewer than 3 distinct corners, or zero area.
    zero_area_triangles : int
        Triangles of repaired polygons dropped for covering no area.
    trailing_values : int
        Ascii PLY lines whose extra trailing values were ignored.
    """

    faces_read: int = 0
    non_planar: int = 0
    concave: int = 0
    triangles_added: int = 0
    degenerate: int = 0
    zero_area_triangles: int = 0
    trailing_values: int = 0

    def as_dict(self) -> dict:
        """The counts by name (the ``mesh`` block of ``holo-render --json``)."""
        return asdict(self)

    def add(self, other: MeshRepair) -> None:
        """Add another mesh's counts to these (a scene's total)."""
        for key, value in asdict(other).items():
            setattr(self, key, getattr(self, key) + value)

    def message(self) -> str:
        """One line saying what was repaired, or ``""`` when nothing was."""
        parts = []
        shapes = [f"{n} {what}" for n, what in ((self.non_planar, "non-planar"),
                                                 (self.concave, "concave")) if n]
        if shapes:
            parts.append(f"triangulated {' and '.join(shapes)} polygon(s) into "
                         f"{self.triangles_added} triangles")
        if self.degenerate:
            parts.append(f"dropped {self.degenerate} degenerate face(s) (under 3 distinct "
                         "corners or zero area)")
        if self.trailing_values:
            parts.append(f"ignored extra trailing values on {self.trailing_values} line(s)")
        return "; ".join(parts)


def distinct_corners(polygons: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Number of distinct vertex indices of each polygon.

    Parameters
    ----------
    polygons : ndarray, shape (P, K), padded with -1
    counts : ndarray, shape (P,)

    Returns
    -------
    ndarray, shape (P,), int64
    """
    if polygons.shape[1] == 0:  # every polygon empty (an OBJ whose only face is a bare 'f')
        return np.zeros(polygons.shape[0], np.int64)
    used = np.arange(polygons.shape[1])[None, :] < counts[:, None]
    rows = np.sort(np.where(used, polygons, -1), axis=1)
    new = (rows[:, 1:] != rows[:, :-1]) & (rows[:, 1:] >= 0)
    return (rows[:, 0] >= 0).astype(np.int64) + new.sum(axis=1)


def split_bad_shapes(
    vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray, report: MeshRepair
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Replace non-planar and concave polygons by ear-clipped triangles, in place in order.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    polygons : ndarray, shape (P, K), padded with -1
    counts : ndarray, shape (P,)
    report : MeshRepair
        Its ``non_planar``, ``concave`` and ``triangles_added`` are counted up.

    Returns
    -------
    polygons : ndarray, shape (P', K)
    counts : ndarray, shape (P',)
    from_split : ndarray, shape (P',), bool
        Which rows are triangles of a split polygon.
    """
    faults = polygon_shape_faults(vertices, polygons, counts)
    if faults.polygon.size == 0:
        return polygons, counts, np.zeros(counts.size, bool)
    report.non_planar += int(np.sum(faults.kind == PLANAR))
    report.concave += int(np.sum(faults.kind == CONVEX))
    rows = faults.polygon
    tri, first = triangulate_rows(vertices, polygons, counts, rows)
    report.triangles_added += int(tri.shape[0])
    repeat = np.ones(counts.size, np.int64)
    repeat[rows] = counts[rows] - 2
    src = np.repeat(np.arange(counts.size), repeat)
    out = polygons[src].copy()
    out_counts = counts[src].copy()
    split = np.zeros(counts.size, bool)
    split[rows] = True
    from_split = split[src]
    out[from_split] = -1
    out[from_split, :3] = tri
    out_counts[from_split] = 3
    return out, out_counts, from_split
