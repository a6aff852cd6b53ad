"""Scene files (``.toml``): several objects with placement, material and motion, and lights.

The format is documented with a full example in ``docs/file-formats.md``.  In short:
top-level ``ambient``, any number of ``[[light]]`` tables and at least one
``[[object]]`` table; an object takes its mesh from ``file = "path"`` (relative to
the scene file) or ``primitive = "sphere"`` with a ``params`` table.  Unknown keys
are errors, so a misspelt key is reported instead of silently ignored.  Objects and
lights are numbered from 1 in messages, in file order.
"""

from __future__ import annotations

import inspect
import re
import tomllib
from collections.abc import Callable
from pathlib import Path

import numpy as np

from service.base.errors import MeshFileError, SettingsError
from service.billboard_render import BillboardObject
from service.loaders._build import decode_text, read_bytes
from service.primitives import PRIMITIVES
from service.quality import MODES, parse_budget
from service.render.mesh import Mesh
from service.render.scene import (
    Light,
    Material,
    MotionState,
    Scene,
    SceneObject,
    Transform,
    euler_quaternion,
)
from service.simplify.cloud_file import load_cloud

TOP_KEYS = {"ambient", "light", "object", "quality"}
QUALITY_KEYS = ("mode", "max_error")
OBJECT_KEYS = {
    "name", "file", "primitive", "params", "position", "orientation", "rotation",
    "scale", "material", "motion",
}
MATERIAL_KEYS = {"colour": 3, "ambient": 0, "diffuse": 0, "specular": 0, "shininess": 0}
MOTION_KEYS = {"velocity": 3, "acceleration": 3, "angular_velocity": 3, "angular_acceleration": 3}
LIGHT_KEYS = {"kind": -1, "vector": 3, "direction": 3, "position": 3, "colour": 3, "intensity": 0}
LIGHT_VECTOR_ALIASES = ("vector", "direction", "position")
ALIASES = {"color": "colour"}


def _value(path: Path, where: str, key: str, value: object, size: int) -> object:
    """Check a value: a number (size 0), a list of ``size`` numbers, or a string (-1)."""
    if size < 0:
        ok = isinstance(value, str)
    elif size == 0:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
    else:
        ok = isinstance(value, list) and len(value) == size and all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in value
        )
    if not ok:
        want = {-1: "a string", 0: "a number"}.get(size, f"a list of {size} numbers")
        raise MeshFileError(str(path), where, f"{key} must be {want}, got {value!r:.60}")
    return value


def _table(path: Path, where: str, table: object, keys: dict) -> dict:
    """Check a table's keys and value types; return it with aliases resolved."""
    if not isinstance(table, dict):
        raise MeshFileError(str(path), where, f"expected a table, got {table!r:.60}")
    out = {}
    for key, value in table.items():
        key = ALIASES.get(key, key)
        if key not in keys:
            raise MeshFileError(str(path), where, f"unknown key {key!r} (known: {sorted(keys)})")
        out[key] = _value(path, f"{where}, {key}", key, value, keys[key])
    return out


def _make(path: Path, where: str, build: Callable, **kwargs: object) -> object:
    """Call a constructor, reporting its settings errors as file errors."""
    try:
        return build(**kwargs)
    except (SettingsError, TypeError, ValueError, ZeroDivisionError) as exc:
        raise MeshFileError(str(path), where, str(exc)) from None


def _primitive(path: Path, where: str, spec: dict) -> Mesh:
    name = _value(path, where, "primitive", spec["primitive"], -1)
    if name not in PRIMITIVES:
        raise MeshFileError(str(path), where, f"unknown primitive {name!r} ({sorted(PRIMITIVES)})")
    params = spec.get("params", {})
    if not isinstance(params, dict):
        raise MeshFileError(str(path), where, "params must be a table")
    allowed = set(inspect.signature(PRIMITIVES[name]).parameters)
    unknown = sorted(set(params) - allowed)
    if unknown:
        reason = f"primitive {name!r} has no parameter {unknown[0]!r} (has {sorted(allowed)})"
        raise MeshFileError(str(path), where, reason)
    return _make(path, where, PRIMITIVES[name], **params)


def _object_mesh(path: Path, where: str, spec: dict, load_mesh: Callable) -> Mesh:
    if ("file" in spec) == ("primitive" in spec):
        raise MeshFileError(str(path), where, "give exactly one of 'file' and 'primitive'")
    if "primitive" in spec:
        return _primitive(path, where, spec)
    return _load_named(path, where, _value(path, where, "file", spec["file"], -1), load_mesh)


def _load_named(path: Path, where: str, name: str, load: Callable) -> object:
    """``load`` the file an object names, beside the scene file.

    A missing one is named with the scene file and the object, not as a bare errno line.
    """
    target = path.parent / name
    if not target.is_file():
        what = "is not a file" if target.exists() else "not found"
        raise MeshFileError(str(path), where, f"file {name!r} {what} (looked for {target})")
    return load(target)


def _transform(path: Path, where: str, spec: dict) -> Transform:
    if "orientation" in spec and "rotation" in spec:
        raise MeshFileError(str(path), where, "give 'orientation' or 'rotation', not both")
    q = _value(path, where, "orientation", spec.get("orientation", [1.0, 0, 0, 0]), 4)
    if "rotation" in spec:
        yaw, pitch, roll = np.radians(_value(path, where, "rotation", spec["rotation"], 3))
        q = euler_quaternion(yaw, pitch, roll)
    position = _value(path, where, "position", spec.get("position", [0.0, 0, 0]), 3)
    scale = _value(path, where, "scale", spec.get("scale", 1.0), 0)
    return _make(path, where, Transform, position=position, orientation=q, scale=scale)


def _object(path: Path, i: int, spec: object, load_mesh: Callable) -> SceneObject:
    """Build the ``i``-th (from 1) object of a scene file."""
    where = f"object {i}"
    if not isinstance(spec, dict):
        raise MeshFileError(str(path), where, "each object must be a table")
    name = _value(path, where, "name", spec.get("name", f"object{i}"), -1)
    where = f"object {i} ({name})" if "name" in spec else where
    unknown = sorted(set(spec) - OBJECT_KEYS)
    if unknown:
        reason = f"unknown key {unknown[0]!r} (known: {sorted(OBJECT_KEYS)})"
        raise MeshFileError(str(path), where, reason)
    material = _table(path, f"{where}, material", spec.get("material", {}), MATERIAL_KEYS)
    if _is_cloud(spec):
        return _billboard_object(path, where, spec, material, name)
    mesh = _object_mesh(path, where, spec, load_mesh)
    motion = _table(path, f"{where}, motion", spec.get("motion", {}), MOTION_KEYS)
    return SceneObject(
        mesh=mesh,
        material=_make(path, f"{where}, material", Material, **material),
        transform=_transform(path, where, spec),
        motion=_make(path, f"{where}, motion", MotionState, **motion),
        name=name,
    )


def _is_cloud(spec: dict) -> bool:
    """Whether an object names a billboard-cloud file (``.hbc``) instead of a mesh."""
    return isinstance(spec.get("file"), str) and spec["file"].lower().endswith(".hbc")


def _billboard_object(path: Path, where: str, spec: dict, material: dict,
                      name: str) -> BillboardObject:
    """An object drawn as a billboard cloud (:mod:`service.billboard_render`)."""
    if "motion" in spec or "primitive" in spec:
        raise MeshFileError(str(path), where, "a billboard cloud takes no 'motion' or "
                            "'primitive' (it is drawn where it is placed)")
    cloud = _load_named(path, where, spec["file"], load_cloud)
    return BillboardObject(cloud=cloud,
                           material=_make(path, f"{where}, material", Material, **material),
                           transform=_transform(path, where, spec), name=name)


def _light(path: Path, i: int, spec: object) -> Light:
    """Build the ``i``-th (from 1) light of a scene file."""
    where = f"light {i}"
    table = _table(path, where, spec, LIGHT_KEYS)
    vectors = [k for k in LIGHT_VECTOR_ALIASES if k in table]
    if len(vectors) > 1:
        raise MeshFileError(str(path), where, f"give one of {LIGHT_VECTOR_ALIASES}, not several")
    if vectors:
        table["vector"] = table.pop(vectors[0])
    return _make(path, where, Light, **table)


def _parse_toml(path: Path) -> dict:
    text = decode_text(path, read_bytes(path))
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        found = re.search(r"\(at line (\d+)", msg)
        where = f"line {found.group(1)}" if found else ""
        raise MeshFileError(str(path), where, msg.split(" (at ")[0]) from None


def _array(path: Path, doc: dict, key: str) -> list:
    items = doc.get(key, [])
    if not isinstance(items, list):
        raise MeshFileError(str(path), key, f"write each {key} as a [[{key}]] table")
    return items


def load_scene_file(path: str | Path, load_mesh: Callable[[Path], Mesh]) -> Scene:
    """Read a TOML scene file.

    Parameters
    ----------
    path : str or Path
    load_mesh : callable
        Reads a mesh file (used for objects given by ``file``; paths are resolved
        relative to the scene file's folder).

    Returns
    -------
    Scene
        Its objects in file order; the default light if the file names none.

    Raises
    ------
    MeshFileError
        Naming the TOML line, or the object or light (from 1), at fault; errors in a
        referenced mesh file name that file.
    """
    path = Path(path)
    doc = _parse_toml(path)
    unknown = sorted(set(doc) - TOP_KEYS)
    if unknown:
        reason = f"unknown top-level key {unknown[0]!r} (known: {sorted(TOP_KEYS)})"
        raise MeshFileError(str(path), "", reason)
    items = [_object(path, i, s, load_mesh) for i, s in enumerate(_array(path, doc, "object"), 1)]
    objects = [o for o in items if isinstance(o, SceneObject)]
    billboards = [o for o in items if isinstance(o, BillboardObject)]
    if not items:
        raise MeshFileError(str(path), "", "the scene has no [[object]] tables")
    lights = [_light(path, i, s) for i, s in enumerate(_array(path, doc, "light"), 1)]
    ambient = _value(path, "ambient", "ambient", doc.get("ambient", 1.0), 0)
    return Scene(objects=objects, lights=lights or [Light()], ambient=float(ambient),
                 billboards=billboards,
                 quality=_quality(path, doc.get("quality", {})))


def _quality(path: Path, table: object) -> dict:
    """The ``[quality]`` table: ``mode`` ("fixed", "auto"), ``max_error`` (0.5, "0.5%", "40dB")."""
    if not isinstance(table, dict):
        raise MeshFileError(str(path), "quality", "quality must be a table")
    unknown = sorted(set(table) - set(QUALITY_KEYS))
    if unknown:
        raise MeshFileError(str(path), "quality",
                            f"unknown key {unknown[0]!r} (known: {sorted(QUALITY_KEYS)})")
    if table.get("mode", "fixed") not in MODES:
        raise MeshFileError(str(path), "quality, mode", f"mode must be one of {list(MODES)}")
    try:
        parse_budget(table.get("max_error", "0.5%"))
    except SettingsError as exc:
        raise MeshFileError(str(path), "quality, max_error", str(exc)) from None
    return dict(table)
