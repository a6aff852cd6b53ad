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
:class:`~service.errors.MeshFileError` naming the file and the line or element.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np

from service.billboard_render import BillboardObject
from service.errors import MeshFileError
from service.loaders.obj import load_obj, save_obj
from service.loaders.ply import load_ply, save_ply
from service.loaders.scene_file import load_scene_file
from service.loaders.thesis_object import load_thesis_object, save_thesis_object
from service.mesh import Mesh
from service.scene import Light, Material, Scene, SceneObject, Transform
from service.simplify.cloud_file import load_cloud

MESH_LOADERS = {".hobj": load_thesis_object, ".ply": load_ply, ".obj": load_obj}
"""Mesh readers by lower-case file extension."""

SCENE_EXTENSIONS = (".toml",)
FIT_WIDTH = 1.6
"""A lone mesh loaded as a scene is scaled so its largest extent is this (world units)."""

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


def load_scene(path: str | Path, strict: bool = False) -> Scene:
    """Read a scene file, or a single mesh file as a one-object scene.

    A lone mesh gets the default :class:`Material` and :class:`Light`, and is centred
    and scaled to fit ``FIT_WIDTH`` world units (inside the default display width 2).

    Parameters
    ----------
    path : str or Path
    strict : bool
        Passed to :func:`load_mesh` for every mesh file.

    Returns
    -------
    Scene
    """
    path = Path(path)
    if path.suffix.lower() in SCENE_EXTENSIONS:
        return load_scene_file(path, partial(load_mesh, strict=strict))
    if path.suffix.lower() == ".hbc":  # a lone billboard cloud, placed as a lone mesh is
        cloud = load_cloud(path)
        box = Mesh.from_triangles(cloud.corners.reshape(-1, 3), [[0, 1, 2]])
        obj = BillboardObject(cloud, Material(), fit_transform(box), name=path.stem)
        return Scene(objects=[], lights=[Light()], billboards=[obj])
    mesh = load_mesh(path, strict)
    obj = SceneObject(mesh, Material(), fit_transform(mesh), name=mesh.name)
    return Scene(objects=[obj], lights=[Light()])
