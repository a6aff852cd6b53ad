"""Arrays and scenes on the wire: JSON headers plus raw buffers (``docs/protocol.md`` 1.4).

An array travels as one raw little-endian buffer frame, described in the header's
``arrays`` list (``{"dtype", "shape", "encoding": "raw"}``) and referred to from the JSON with
``{"$array": i}``.  Buffers above :data:`ZERO_COPY_BYTES` are sent without a copy.
The only serialisations are JSON and raw buffers (never Python object serialisation).

Scenes are encoded inline with the same mechanism (:func:`scene_to_wire`,
:func:`scene_from_wire`); meshes shared by several objects travel once, and so do
billboard clouds (``billboards``: textures and quads as arrays, see
:func:`billboard_from_wire`).
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import zmq

from service.base.errors import MeshError, MessageError, SettingsError
from service.billboard_render import BillboardObject
from service.render.mesh import MAX_POLYGONS as MESH_MAX_POLYGONS
from service.render.mesh import Mesh
from service.render.scene import Light, Material, MotionState, Scene, SceneObject, Transform
from service.simplify.billboard import BillboardCloud
from service.simplify.cloud_file import array_problem, arrays_problem

#: pyzmq copies frames below this size anyway; larger ones go zero-copy.
ZERO_COPY_BYTES = 65536
#: wire dtype name -> numpy dtype (little endian only).
DTYPES: dict[str, np.dtype] = {
    "uint8": np.dtype("<u1"),
    "int8": np.dtype("|i1"),
    "bool": np.dtype("|b1"),
    "int16": np.dtype("<i2"),
    "int32": np.dtype("<i4"),
    "int64": np.dtype("<i8"),
    "float32": np.dtype("<f4"),
    "float64": np.dtype("<f8"),
}
NAMES = {v: k for k, v in DTYPES.items()}
MAX_DIMS = 4
MAX_ARRAYS = 1024
#: object names (and device addresses) are at most this many characters.
MAX_NAME = 256
#: buffer encodings of version 1: ``raw`` only (C order, little endian, uncompressed).
ENCODINGS = ("raw",)


def describe(arr: np.ndarray, name: str | None = None) -> dict[str, Any]:
    """The descriptor of one array (``dtype``, ``shape``, ``encoding``, optional ``name``)."""
    desc: dict[str, Any] = {"dtype": NAMES[arr.dtype], "shape": list(arr.shape), "encoding": "raw"}
    if name is not None:
        desc["name"] = name
    return desc


def as_wire(arr: np.ndarray) -> np.ndarray:
    """The array as a C-contiguous little-endian array of a wire dtype.

    Raises
    ------
    MessageError
        ``bad_array`` for a dtype the protocol does not carry.
    """
    a = np.asarray(arr)
    if a.dtype.byteorder == ">":
        a = a.astype(a.dtype.newbyteorder("<"))
    if a.dtype not in NAMES:
        raise MessageError("bad_array", f"dtype {a.dtype} cannot be sent")
    return np.ascontiguousarray(a)


def encode(
    header: dict[str, Any], arrays: list[np.ndarray], names: list[str] | None = None
) -> list[Any]:
    """Header JSON plus buffers, ready for ``send_multipart``.

    Parameters
    ----------
    header : dict
        JSON-able; gets an ``arrays`` list when ``arrays`` is not empty.
    arrays : list of ndarray
    names : list of str, optional
        Stored as each descriptor's ``name``.

    Returns
    -------
    list
        ``[header bytes, buffer, ...]``; buffers are memoryviews (no copy here).
    """
    wire = [as_wire(a) for a in arrays]
    if wire:
        header = {
            **header,
            "arrays": [
                describe(a, None if names is None else names[i]) for i, a in enumerate(wire)
            ],
        }
    return [json.dumps(header, separators=(",", ":")).encode(), *[memoryview(a) for a in wire]]


def send(sock: zmq.Socket, frames: list[Any], timeout_ms: int = 1000) -> bool:
    """Send a multipart message, buffers above 64 KiB zero-copy.

    Returns False (nothing sent) when the socket would block past ``timeout_ms``
    (0: never block, as for a PUB socket, which drops past its HWM anyway).  The
    poll also makes libzmq process its pending commands (a reader's "write
    again" after a full pipe), so a PUB socket does not drop a message needlessly.
    """
    if not sock.poll(timeout_ms, zmq.POLLOUT):
        return False
    last = len(frames) - 1
    more, done = zmq.SNDMORE | zmq.NOBLOCK, zmq.NOBLOCK
    try:
        for i, f in enumerate(frames):
            big = isinstance(f, memoryview) and f.nbytes >= ZERO_COPY_BYTES
            sock.send(f, more if i < last else done, copy=not big)
    except zmq.Again:
        return False
    return True


def _shape(desc: dict[str, Any], i: int, max_dims: int) -> tuple[int, ...]:
    shape = desc.get("shape")
    if not isinstance(shape, list):
        raise MessageError("bad_array", f"arrays[{i}].shape must be a list of ints")
    if len(shape) > max_dims:
        raise MessageError(
            "too_large", f"arrays[{i}] has {len(shape)} dimensions (max {max_dims})"
        )
    if not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape):
        raise MessageError("bad_array", f"arrays[{i}].shape must hold non-negative ints")
    return tuple(shape)


def _encoding(desc: dict[str, Any], i: int) -> None:
    """Check a descriptor's optional ``encoding`` (absent means ``raw``)."""
    enc = desc.get("encoding", "raw")
    if enc not in ENCODINGS:
        raise MessageError(
            "bad_message", f"arrays[{i}].encoding must be one of {list(ENCODINGS)}, got {enc!r}"
        )


def decode_arrays(
    descs: object, buffers: list[Any], max_bytes: int, max_dims: int = MAX_DIMS
) -> list[np.ndarray]:
    """Arrays from descriptors and raw buffers (read-only views, no copy).

    ``max_dims`` is 4 for requests; internal traffic (band replies) allows more.

    Raises
    ------
    MessageError
        ``bad_frames`` when the counts differ, ``bad_array`` for a bad dtype, shape
        or byte count, ``bad_message`` for an ``encoding`` other than ``raw``,
        ``too_large`` past ``max_bytes`` per array, ``max_dims`` dimensions or
        :data:`MAX_ARRAYS` arrays.
    """
    if descs is None:
        descs = []
    if not isinstance(descs, list):
        raise MessageError("bad_message", "arrays must be a list of descriptors")
    if len(descs) > MAX_ARRAYS:
        raise MessageError("too_large", f"{len(descs)} arrays (max {MAX_ARRAYS})")
    if len(descs) != len(buffers):
        raise MessageError(
            "bad_frames", f"{len(descs)} array descriptors but {len(buffers)} buffer frames"
        )
    out = []
    for i, (desc, buf) in enumerate(zip(descs, buffers, strict=True)):
        if not isinstance(desc, dict) or not isinstance(desc.get("dtype"), str) \
                or desc["dtype"] not in DTYPES:
            raise MessageError("bad_array", f"arrays[{i}].dtype must be one of {sorted(DTYPES)}")
        _encoding(desc, i)
        dtype, shape = DTYPES[desc["dtype"]], _shape(desc, i, max_dims)
        nbytes = math.prod(shape) * dtype.itemsize
        if nbytes > max_bytes:
            raise MessageError("too_large", f"arrays[{i}] has {nbytes} bytes (max {max_bytes})")
        data = memoryview(buf)
        if data.nbytes != nbytes:
            raise MessageError("bad_array", f"arrays[{i}] needs {nbytes} bytes, got {data.nbytes}")
        out.append(np.frombuffer(data, dtype).reshape(shape))
    return out


def resolve(obj: Any, arrays: list[np.ndarray]) -> Any:
    """Replace every ``{"$array": i}`` in a JSON value by ``arrays[i]``.

    Raises
    ------
    MessageError
        ``bad_message`` for a bad index or an array referred to twice or never.
    """
    used = [False] * len(arrays)

    def walk(v: Any) -> Any:
        if isinstance(v, dict):
            if "$array" in v:
                i = v["$array"]
                if not (isinstance(i, int) and 0 <= i < len(arrays)) or used[i]:
                    raise MessageError("bad_message", f"bad or repeated array reference {i!r}")
                used[i] = True
                return arrays[i]
            return {k: walk(x) for k, x in v.items()}
        if isinstance(v, list):
            return [walk(x) for x in v]
        return v

    out = walk(obj)
    if not all(used):
        raise MessageError("bad_message", "an array buffer is not referred to")
    return out


def extract(obj: Any) -> tuple[Any, list[np.ndarray]]:
    """Inverse of :func:`resolve`: arrays replaced by references, and the arrays."""
    arrays: list[np.ndarray] = []

    def walk(v: Any) -> Any:
        if isinstance(v, np.ndarray):
            arrays.append(v)
            return {"$array": len(arrays) - 1}
        if isinstance(v, dict):
            return {k: walk(x) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [walk(x) for x in v]
        return v

    return walk(obj), arrays


# ------------------------------------------------------------- field checks
def number(v: Any, name: str, lo: float = -np.inf, hi: float = np.inf) -> float:
    """A finite number in [lo, hi] (``bad_message`` / ``not_finite`` otherwise)."""
    if isinstance(v, bool) or not isinstance(v, int | float | np.floating | np.integer):
        raise MessageError("bad_message", f"{name} must be a number")
    x = float(v)
    if not np.isfinite(x):
        raise MessageError("not_finite", f"{name} must be finite")
    if not lo <= x <= hi:
        raise MessageError("bad_message", f"{name} must be in [{lo}, {hi}], got {x}")
    return x


def integer(v: Any, name: str, lo: int, hi: int) -> int:
    """An int in [lo, hi]."""
    if isinstance(v, bool) or not isinstance(v, int | np.integer) or not lo <= int(v) <= hi:
        raise MessageError("bad_message", f"{name} must be an integer in [{lo}, {hi}]")
    return int(v)


def string(v: Any, name: str, max_len: int = 4096) -> str:
    """A string of at most ``max_len`` characters."""
    if not isinstance(v, str):
        raise MessageError("bad_message", f"{name} must be a string")
    if len(v) > max_len:
        raise MessageError("too_large", f"{name} is longer than {max_len} characters")
    return v


def vector(v: Any, name: str, n: int) -> np.ndarray:
    """A finite float vector of length ``n`` from a list or a float array, shape (n,)."""
    if isinstance(v, np.ndarray):
        if v.dtype.kind != "f" or v.shape != (n,):
            raise MessageError("bad_array", f"{name} must be a float array of shape ({n},)")
        a = v.astype(np.float64)
    elif isinstance(v, list) and len(v) == n:
        a = np.array([number(x, name) for x in v], np.float64)
    else:
        raise MessageError("bad_message", f"{name} must be {n} numbers")
    if not np.all(np.isfinite(a)):
        raise MessageError("not_finite", f"{name} must be finite")
    return a


def float_array(v: Any, name: str, cols: int, max_rows: int) -> np.ndarray:
    """A finite float array of shape (N, cols), N <= max_rows, as float64."""
    if not isinstance(v, np.ndarray) or v.dtype.kind != "f" or v.ndim != 2 or v.shape[1] != cols:
        raise MessageError("bad_array", f"{name} must be a float array of shape (N, {cols})")
    if v.shape[0] > max_rows:
        raise MessageError("too_large", f"{name} has more than {max_rows} rows")
    if not np.all(np.isfinite(v)):
        raise MessageError("not_finite", f"{name} holds NaN or infinity")
    return v.astype(np.float64)


def int_array(v: Any, name: str, ndim: int, max_rows: int) -> np.ndarray:
    """An int32/int64 array with ``ndim`` dimensions and <= max_rows rows, as int64."""
    if not isinstance(v, np.ndarray) or v.dtype.kind != "i" or v.ndim != ndim:
        raise MessageError("bad_array", f"{name} must be an int array with {ndim} dimensions")
    if v.shape[0] > max_rows:
        raise MessageError("too_large", f"{name} has more than {max_rows} rows")
    return v.astype(np.int64)


# ------------------------------------------------------------------ scenes
MAX_VERTICES = 2_000_000
MAX_POLYGONS = MESH_MAX_POLYGONS
MAX_OBJECTS = 4096
MOTION_FIELDS = ("velocity", "acceleration", "angular_velocity", "angular_acceleration")


def mesh_from_wire(spec: Any, name: str) -> Mesh:
    """A mesh from ``{"vertices", "triangles"}`` or ``{"vertices", "polygons", "counts"}``."""
    if not isinstance(spec, dict):
        raise MessageError("bad_message", f"{name} must be an object")
    verts = float_array(spec.get("vertices"), f"{name}.vertices", 3, MAX_VERTICES)
    try:
        if "triangles" in spec:
            tri = int_array(spec["triangles"], f"{name}.triangles", 2, MAX_POLYGONS)
            if tri.shape[1] != 3:
                raise MessageError("bad_array", f"{name}.triangles must have shape (T, 3)")
            return Mesh.from_triangles(verts, tri, name)
        polys = int_array(spec.get("polygons"), f"{name}.polygons", 2, MAX_POLYGONS)
        counts = int_array(spec.get("counts"), f"{name}.counts", 1, MAX_POLYGONS)
        return Mesh(verts, polys, counts, name)
    except (MeshError, SettingsError, ValueError) as exc:
        raise MessageError("bad_message", f"{name}: {exc}") from exc


def material_from_wire(spec: Any, name: str) -> Material:
    """A :class:`Material` from its JSON fields (missing ones take defaults)."""
    if spec is None:
        return Material()
    if not isinstance(spec, dict):
        raise MessageError("bad_message", f"{name} must be an object")
    kw: dict[str, Any] = {}
    if "colour" in spec:
        kw["colour"] = tuple(vector(spec["colour"], f"{name}.colour", 3))
    for key in ("ambient", "diffuse", "specular", "shininess"):
        if key in spec:
            kw[key] = number(spec[key], f"{name}.{key}", 0.0, 1e4)
    try:
        return Material(**kw)
    except (SettingsError, ValueError) as exc:
        raise MessageError("bad_message", f"{name}: {exc}") from exc


def transform_from_wire(spec: dict[str, Any], name: str, t: Transform) -> Transform:
    """``t`` with the ``position``, ``orientation`` and ``scale`` of ``spec`` applied."""
    pos = vector(spec["position"], f"{name}.position", 3) if "position" in spec else t.position
    q = t.orientation
    if "orientation" in spec:
        q = vector(spec["orientation"], f"{name}.orientation", 4)
        with np.errstate(over="ignore"):  # [1e308] * 4: refused below, not a warning
            norm = float(np.linalg.norm(q))
        if not 0.5 < norm < 2.0:
            raise MessageError("bad_message", f"{name}.orientation must be a unit quaternion")
        q = q / norm
    scale = number(spec["scale"], f"{name}.scale", 1e-9, 1e9) if "scale" in spec else t.scale
    return Transform(pos, q, scale)


def apply_fields(obj: SceneObject, spec: dict[str, Any], name: str) -> SceneObject:
    """The object with the pose/motion fields of ``spec`` applied (others kept)."""
    m = obj.motion
    motion = {
        k: vector(spec[k], f"{name}.{k}", 3) if k in spec else getattr(m, k) for k in MOTION_FIELDS
    }
    return SceneObject(obj.mesh, obj.material, transform_from_wire(spec, name, obj.transform),
                       MotionState(**motion), obj.name)


def object_from_wire(spec: Any, name: str) -> SceneObject:
    """An inline object (``mesh``, ``material``, ``name`` and pose/motion fields)."""
    if not isinstance(spec, dict):
        raise MessageError("bad_message", f"{name} must be an object")
    label = string(spec.get("name", ""), f"{name}.name", MAX_NAME)
    mesh = spec.get("mesh")
    mesh = mesh if isinstance(mesh, Mesh) else mesh_from_wire(mesh, f"{name}.mesh")
    base = SceneObject(
        mesh, material_from_wire(spec.get("material"), f"{name}.material"), name=label
    )
    return apply_fields(base, spec, name)


def light_from_wire(spec: Any, name: str) -> Light:
    """A :class:`Light` from ``kind``, ``vector``, ``colour``, ``intensity``."""
    if not isinstance(spec, dict):
        raise MessageError("bad_message", f"{name} must be an object")
    try:
        return Light(
            string(spec.get("kind", "directional"), f"{name}.kind", 32),
            vector(spec.get("vector", [0.3, 0.5, 1.0]), f"{name}.vector", 3),
            tuple(vector(spec.get("colour", [1, 1, 1]), f"{name}.colour", 3)),
            number(spec.get("intensity", 1.0), f"{name}.intensity", 0.0, 1e6),
        )
    except SettingsError as exc:
        raise MessageError("bad_message", f"{name}: {exc}") from exc


def _list(v: Any, name: str, max_len: int) -> list:
    if not isinstance(v, list):
        raise MessageError("bad_message", f"{name} must be a list")
    if len(v) > max_len:
        raise MessageError("too_large", f"{name} has more than {max_len} entries")
    return v


#: The arrays of a billboard cloud on the wire (those of the ``.hbc`` file).
CLOUD_ARRAYS = ("corners", "planes", "tex_shape", "tex_offset", "rgba", "normal")
MAX_BILLBOARDS = 65536
MAX_TEXELS = 64_000_000


def cloud_from_wire(spec: Any, name: str) -> Any:
    """A :class:`~service.simplify.billboard.BillboardCloud` from its inline form.

    ``{"corners", "planes", "tex_shape", "tex_offset", "rgba", "normal"}`` (arrays of
    the dtypes and shapes of ``docs/file-formats.md``'s ``.hbc`` arrays, ``normal``
    int8) plus ``eps`` and ``source_faces``.  The arrays are checked as the file
    reader checks them (shapes, offsets against texture sizes, finite unit planes),
    so the renderer's texel indexing stays inside them.

    Raises
    ------
    MessageError
        ``bad_message`` / ``bad_array`` / ``too_large`` naming the field.
    """
    if not isinstance(spec, dict):
        raise MessageError("bad_message", f"{name} must be an object")
    planes = spec.get("planes")
    if not isinstance(planes, np.ndarray) or planes.ndim != 2:
        raise MessageError("bad_array", f"{name}.planes must be a float64 array of shape (P, 4)")
    if planes.shape[0] > MAX_BILLBOARDS:
        raise MessageError("too_large", f"{name} has more than {MAX_BILLBOARDS} billboards")
    arrays = {}
    for key in CLOUD_ARRAYS:
        arr = spec.get(key)
        if not isinstance(arr, np.ndarray):
            raise MessageError("bad_array", f"{name}.{key} must be an array")
        problem = array_problem(key, arr, planes.shape[0])
        if problem is not None:
            raise MessageError("bad_array", f"{name}.{key}: {problem}")
        if key in ("rgba", "normal") and arr.shape[0] > MAX_TEXELS:  # before the copy
            raise MessageError("too_large", f"{name} has more than {MAX_TEXELS} texels")
        arrays[key] = np.array(arr)  # writable: the kernels are compiled for those
    problem = arrays_problem(arrays)
    if problem is not None:
        raise MessageError("bad_array", f"{name}.{problem[0]}: {problem[1]}")
    return BillboardCloud(**arrays, eps=number(spec.get("eps"), f"{name}.eps", 1e-300),
                          source_faces=integer(spec.get("source_faces", 0),
                                               f"{name}.source_faces", 0, MAX_POLYGONS))


def billboard_from_wire(spec: Any, name: str, clouds: dict[int, Any]) -> Any:
    """A billboard-cloud object: ``cloud`` (or ``cloud_ref``), ``material``, ``name``, pose.

    ``cloud_ref`` names an earlier entry of ``billboards`` whose cloud it shares.
    Billboard clouds carry no motion.
    """
    if not isinstance(spec, dict):
        raise MessageError("bad_message", f"{name} must be an object")
    if "cloud_ref" in spec:
        ref = spec["cloud_ref"]
        if isinstance(ref, bool) or not (isinstance(ref, int) and ref in clouds):
            raise MessageError("bad_message", f"{name}.cloud_ref must name an earlier billboard")
        cloud = clouds[ref]
    else:
        cloud = cloud_from_wire(spec.get("cloud"), f"{name}.cloud")
    return BillboardObject(cloud, material_from_wire(spec.get("material"), f"{name}.material"),
                           transform_from_wire(spec, name, Transform()),
                           string(spec.get("name", ""), f"{name}.name", MAX_NAME))


def _billboards_from_wire(spec: dict[str, Any]) -> list:
    boards = _list(spec.get("billboards", []), "scene.billboards", MAX_OBJECTS)
    clouds: dict[int, Any] = {}
    out = []
    for i, b in enumerate(boards):
        obj = billboard_from_wire(b, f"scene.billboards[{i}]", clouds)
        clouds[i] = obj.cloud
        out.append(obj)
    return out


def scene_from_wire(spec: Any) -> Scene:
    """A :class:`Scene` from the inline form ``{"objects", "lights", "ambient", "billboards"}``."""
    if not isinstance(spec, dict):
        raise MessageError("bad_message", "scene must be an object")
    objs = _list(spec.get("objects", []), "scene.objects", MAX_OBJECTS)
    lights = _list(spec.get("lights", [{}]), "scene.lights", 64)
    meshes: dict[int, Mesh] = {}
    objects = []
    for i, o in enumerate(objs):
        name = f"scene.objects[{i}]"
        if isinstance(o, dict) and "mesh_ref" in o:
            ref = o["mesh_ref"]
            if not (isinstance(ref, int) and ref in meshes):
                raise MessageError("bad_message", f"{name}.mesh_ref must name an earlier object")
            o = {**o, "mesh": meshes[ref]}
        obj = object_from_wire(o, name)
        meshes[i] = obj.mesh
        objects.append(obj)
    return Scene(
        objects,
        [light_from_wire(x, f"scene.lights[{i}]") for i, x in enumerate(lights)],
        number(spec.get("ambient", 1.0), "scene.ambient", 0.0, 1.0),
        billboards=_billboards_from_wire(spec),
    )


def _pose(o: Any) -> dict[str, Any]:
    """Name, pose and material of a mesh or billboard-cloud object."""
    m = o.material
    return {
        "name": o.name,
        "position": o.transform.position.tolist(),
        "orientation": o.transform.orientation.tolist(),
        "scale": float(o.transform.scale),
        "material": {
            "colour": list(m.colour),
            "ambient": m.ambient,
            "diffuse": m.diffuse,
            "specular": m.specular,
            "shininess": m.shininess,
        },
    }


def _fields(o: SceneObject) -> dict[str, Any]:
    return {**_pose(o), **{k: getattr(o.motion, k).tolist() for k in MOTION_FIELDS}}


def billboards_to_wire(boards: list) -> list[dict[str, Any]]:
    """The inline form of billboard-cloud objects; a shared cloud travels once."""
    first: dict[int, int] = {}
    out = []
    for i, b in enumerate(boards):
        spec = _pose(b)
        c = b.cloud
        if id(c) in first:
            spec["cloud_ref"] = first[id(c)]
        else:
            first[id(c)] = i
            spec["cloud"] = {**{k: getattr(c, k) for k in CLOUD_ARRAYS}, "eps": float(c.eps),
                             "source_faces": int(c.source_faces)}
        out.append(spec)
    return out


def scene_to_wire(scene: Scene) -> dict[str, Any]:
    """The inline form of a scene (arrays as ndarrays; see :func:`extract`).

    A mesh shared by several objects is sent once: later objects carry
    ``mesh_ref`` (the index of the first object with it) instead of ``mesh``;
    billboard-cloud objects likewise (``billboards``, ``cloud_ref``).
    """
    first: dict[int, int] = {}
    objects = []
    for i, o in enumerate(scene.objects):
        spec = _fields(o)
        if id(o.mesh) in first:
            spec["mesh_ref"] = first[id(o.mesh)]
        else:
            first[id(o.mesh)] = i
            spec["mesh"] = {
                "vertices": o.mesh.vertices,
                "polygons": o.mesh.polygons,
                "counts": o.mesh.counts,
            }
        objects.append(spec)
    lights = [
        {
            "kind": lt.kind,
            "vector": lt.vector.tolist(),
            "colour": list(lt.colour),
            "intensity": lt.intensity,
        }
        for lt in scene.lights
    ]
    out = {"objects": objects, "lights": lights, "ambient": float(scene.ambient)}
    if scene.billboards:
        out["billboards"] = billboards_to_wire(scene.billboards)
    return out
