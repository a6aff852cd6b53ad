"""Mesh and scene files: one entry point for each, dispatching by file extension.

=========  ================================================  ==========================
extension  format                                            module
=========  ================================================  ==========================
``.hobj``  the thesis's object file (seed 000, section 3.1)  :mod:`.thesis_object`
``.ply``   PLY, ascii or binary                              :mod:`.ply`
``.obj``   Wavefront OBJ (v and f lines)                     :mod:`.obj`
``.toml``  scene file: objects, materials, motion, lights    :mod:`.scene_file`
``.hbc``   billboard cloud (a scene, or a scene's object)    :mod:`service.simplify.cloud_file`
=========  ================================================  ==========================

Every format is described in ``docs/file-formats.md``.  A bad file raises
:class:`~service.base.errors.MeshFileError` naming the file and the line or element.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np

from service.base.errors import MeshFileError
from service.billboard_render import ALPHA_OPAQUE, BillboardObject
from service.display import DisplaySettings
from service.loaders.obj import load_obj, save_obj
from service.loaders.ply import load_ply, save_ply
from service.loaders.scene_file import load_scene_file
from service.loaders.thesis_object import load_thesis_object, save_thesis_object
from service.render.mesh import Mesh
from service.render.scene import Light, Material, Scene, SceneObject, Transform
from service.simplify.cloud_file import load_cloud

MESH_LOADERS = {".hobj": load_thesis_object, ".ply": load_ply, ".obj": load_obj}
"""Mesh readers by lower-case file extension."""

SCENE_EXTENSIONS = (".toml",)
FIT_WIDTH = 1.6
""":func:`fit_transform`'s default largest extent (world units; benchmarks place by it)."""
FIT_FRACTION = 0.8
"""A lone mesh loaded as a scene fills this fraction of every zone's view, at most."""

__all__ = [
    "MESH_LOADERS", "load_mesh", "load_obj", "load_ply", "load_scene", "load_scene_file",
    "load_thesis_object", "save_obj", "save_ply", "save_thesis_object",
]


def load_mesh(path: str | Path, strict: bool = False) -> Mesh:
    """Read a mesh file, choosing the reader by extension (see ``MESH_LOADERS``).

    Parameters
    ----------
    path : str or Path
    strict : bool
        Refuse what would otherwise be repaired (non-planar or concave polygons,
        degenerate faces, extra values on ascii PLY lines; :mod:`service.mesh_repair`).

    Returns
    -------
    Mesh

    Raises
    ------
    MeshFileError
        For an unknown extension or a bad file.
    """
    path = Path(path)
    loader = MESH_LOADERS.get(path.suffix.lower())
    if loader is None:
        known = ", ".join(sorted(MESH_LOADERS))
        raise MeshFileError(str(path), "", f"unknown mesh file extension {path.suffix!r} ({known})")
    return loader(path, strict)


def fit_transform(mesh: Mesh, width: float = FIT_WIDTH) -> Transform:
    """Placement centring a mesh's bounding box on the origin, largest extent ``width``."""
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    extent = float(np.max(hi - lo))
    scale = width / extent if extent > 0 else 1.0
    return Transform(position=-(lo + hi) / 2 * scale, scale=scale)


def fit_view(points: np.ndarray, display: DisplaySettings,
             fraction: float = FIT_FRACTION) -> Transform:
    """Placement showing ``points`` whole in every zone of ``display``, shear included.

    The points' bounding box is centred on the origin and scaled as large as keeps
    every point within ``fraction`` of the half width and half height of every
    zone's view (a zone's column is ``x - z tan(theta)``, so depth widens the outer
    zones' picture).

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        The object's vertices (object coordinates).
    display : DisplaySettings
    fraction : float
        Share of the view the object may fill each way, 0 < fraction <= 1.

    Returns
    -------
    Transform
    """
    lo, hi = points.min(axis=0), points.max(axis=0)
    p = points - (lo + hi) / 2
    cols = p[None, :, 0] - p[None, :, 2] * display.shears()[:, None]  # (Z, N)
    half = (float(np.abs(cols).max()), float(np.abs(p[:, 1]).max()))
    room = (display.width / 2, display.height / 2)
    scales = [fraction * r / h for r, h in zip(room, half, strict=True) if h > 0]
    scale = min(scales) if scales else 1.0
    return Transform(position=-(lo + hi) / 2 * scale, scale=scale)


def load_scene(path: str | Path, strict: bool = False,
               display: DisplaySettings | None = None) -> Scene:
    """Read a scene file, or a single mesh file as a one-object scene.

    A lone mesh (or billboard cloud) gets the default :class:`Material` and
    :class:`Light`, and is centred and scaled to fill ``FIT_FRACTION`` of every zone's
    view of ``display`` (:func:`fit_view`).

    Parameters
    ----------
    path : str or Path
    strict : bool
        Passed to :func:`load_mesh` for every mesh file.
    display : DisplaySettings, optional
        The display a lone mesh is fitted to (default: ``DisplaySettings()``).

    Returns
    -------
    Scene
    """
    path, display = Path(path), display or DisplaySettings()
    if path.suffix.lower() in SCENE_EXTENSIONS:
        return load_scene_file(path, partial(load_mesh, strict=strict))
    if path.suffix.lower() == ".hbc":  # a lone billboard cloud, placed as a lone mesh is
        cloud = load_cloud(path)  # by what it shows: its rectangles reach past the mesh
        shown = cloud.shown_points(ALPHA_OPAQUE)
        place = fit_view(shown if len(shown) else cloud.corners.reshape(-1, 3), display)
        obj = BillboardObject(cloud, Material(), place, name=path.stem)
        return Scene(objects=[], lights=[Light()], billboards=[obj])
    mesh = load_mesh(path, strict)
    obj = SceneObject(mesh, Material(), fit_view(mesh.vertices, display), name=mesh.name)
    return Scene(objects=[obj], lights=[Light()])
