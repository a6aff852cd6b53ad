"""The billboard-cloud file, ``.hbc`` (``docs/file-formats.md``, "Billboard clouds").

An uncompressed zip holding ``header.json`` and one ``.npy`` file per array of
:class:`~service.simplify.billboard.BillboardCloud`.  Arrays are read with
``allow_pickle=False``; nothing in the file is ever unpickled or executed.  A file
that is not a zip, lacks a member, has an unknown version, or whose arrays have the
wrong shape, type or disagree with each other raises
:class:`~service.base.errors.MeshFileError` with one line saying what is wrong.
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from pathlib import Path

import numpy as np

from service.base.errors import MeshFileError
from service.npy_file import ZIP_ERRORS, read_npy
from service.simplify.billboard import LAYERS, BillboardCloud

FORMAT = "holo-billboard-cloud"
VERSION = 1
#: array name -> (dtype, shape with -1 for P, -2 for P + 1, -3 for texels N)
ARRAYS = {
    "corners": (np.float64, (-1, 4, 3)),
    "planes": (np.float64, (-1, 4)),
    "tex_shape": (np.int64, (-1, 2)),
    "tex_offset": (np.int64, (-2,)),
    "rgba": (np.uint8, (-3, 4)),
    "normal": (np.int8, (-3, 3)),
}


def save_cloud(cloud: BillboardCloud, path: str | Path) -> None:
    """Write ``cloud`` to ``path`` (an ``.hbc`` file)."""
    header = {"format": FORMAT, "version": VERSION, "billboards": cloud.n_billboards,
              "layers": LAYERS,
              "eps": cloud.eps, "source_faces": cloud.source_faces, "build_s": cloud.build_s,
              "arrays": list(ARRAYS)}
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED) as z:
        z.writestr("header.json", json.dumps(header, indent=1))
        for name in ARRAYS:
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(getattr(cloud, name)),
                                      allow_pickle=False)
            z.writestr(f"{name}.npy", buf.getvalue())


def _header(z: zipfile.ZipFile, path: str) -> dict:
    try:
        header = json.loads(z.read("header.json"))
    except KeyError:
        raise MeshFileError(path, "", "not a billboard cloud (no header.json)") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise MeshFileError(path, "header.json", f"not JSON ({exc})") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise MeshFileError(path, "header.json", f"format is not {FORMAT!r}")
    if header.get("version") != VERSION:
        raise MeshFileError(path, "header.json",
                            f"version {header.get('version')!r} (this reader knows {VERSION})")
    if header.get("layers", LAYERS) != LAYERS:
        raise MeshFileError(path, "header.json", f"layers must be {LAYERS}")
    for key in ("billboards", "source_faces"):
        if not isinstance(header.get(key), int) or header[key] < 0:
            raise MeshFileError(path, "header.json", f"{key} must be a whole number >= 0")
    eps = _number(header.get("eps"))
    if eps is None or eps <= 0:
        raise MeshFileError(path, "header.json", "eps must be a positive number")
    build_s = _number(header.get("build_s", 0.0))
    if build_s is None or build_s < 0:
        raise MeshFileError(path, "header.json", "build_s must be a number >= 0")
    return {**header, "eps": eps, "build_s": build_s}


def _number(value: object) -> float | None:
    """``value`` as a finite float, or None (not a number, a bool, inf, NaN, past float)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        out = float(value)
    except OverflowError:  # a JSON integer of 400 digits
        return None
    return out if math.isfinite(out) else None


#: Largest texture side (rows or columns) of one billboard a reader accepts.
MAX_SIDE = 1 << 16


def array_problem(name: str, arr: np.ndarray, n_billboards: int) -> str | None:
    """What is wrong with one cloud array's dtype or shape (None: nothing).

    ``n_billboards`` is P; the texel count N of ``rgba`` and ``normal`` is theirs.
    """
    dtype, shape = ARRAYS[name]
    if arr.dtype != dtype:
        return f"dtype {arr.dtype}, want {np.dtype(dtype)}"
    sizes = {-1: n_billboards, -2: n_billboards + 1}
    want = tuple(sizes.get(s, s) for s in shape)
    if -3 in want:  # the texel count comes from tex_offset
        want = tuple(arr.shape[0] if s == -3 and arr.ndim else s for s in want)
    if arr.shape != want:
        return f"shape {arr.shape}, want {want}"
    return None


def arrays_problem(c: dict) -> tuple[str, str] | None:
    """Arrays that parse but disagree with each other: (array name, what), or None.

    Checks finite corners and planes, unit plane normals, non-degenerate rectangles,
    texture sides in 1..:data:`MAX_SIDE` and offsets that match them and the texel
    arrays, so that a renderer indexing texels by them stays inside the arrays.
    """
    if not (np.isfinite(c["corners"]).all() and np.isfinite(c["planes"]).all()):
        return "corners", "non-finite coordinates"
    if c["planes"].size and np.abs(np.linalg.norm(c["planes"][:, :3], axis=1) - 1).max() > 1e-3:
        return "planes", "plane normals are not unit vectors"
    corners = c["corners"]
    sides = np.stack([corners[:, 1] - corners[:, 0], corners[:, 3] - corners[:, 0]], axis=1)
    if (np.linalg.norm(sides, axis=2) <= 0).any():
        return "corners", "a billboard rectangle has a zero-length side"
    shape = c["tex_shape"]
    if (shape < 1).any() or (shape > MAX_SIDE).any():
        return "tex_offset", f"tex_shape sides must be 1-{MAX_SIDE}"
    sizes = LAYERS * shape.prod(axis=1) if shape.size else np.zeros(0, np.int64)
    if c["tex_offset"][0] != 0 or not np.array_equal(np.diff(c["tex_offset"]), sizes):
        return "tex_offset", "does not match tex_shape"
    if c["tex_offset"][-1] != c["rgba"].shape[0] or c["rgba"].shape[0] != c["normal"].shape[0]:
        return "rgba", "texel count does not match tex_offset"
    return None


def _array(z: zipfile.ZipFile, path: str, name: str, n_billboards: int) -> np.ndarray:
    try:
        arr = read_npy(z.read(f"{name}.npy"))
    except KeyError:
        raise MeshFileError(path, f"{name}.npy", "missing") from None
    except ValueError as exc:
        raise MeshFileError(path, f"{name}.npy", f"unreadable array ({exc})") from None
    problem = array_problem(name, arr, n_billboards)
    if problem is not None:
        raise MeshFileError(path, f"{name}.npy", problem)
    return arr


def _check(path: str, c: dict) -> None:
    """Arrays that parse but disagree with each other."""
    problem = arrays_problem(c)
    if problem is not None:
        raise MeshFileError(path, f"{problem[0]}.npy", problem[1])


def load_cloud(path: str | Path) -> BillboardCloud:
    """Read an ``.hbc`` file.

    Raises
    ------
    MeshFileError
        Not a zip, truncated, missing or malformed member, unknown version.
    """
    p = str(path)
    try:
        with zipfile.ZipFile(path) as z:
            header = _header(z, p)
            arrays = {name: _array(z, p, name, header["billboards"]) for name in ARRAYS}
    except zipfile.BadZipFile as exc:
        raise MeshFileError(p, "", f"not a billboard-cloud zip or truncated ({exc})") from None
    except ZIP_ERRORS as exc:  # NotImplementedError: a damaged member's compression field
        raise MeshFileError(p, "", f"truncated or unreadable ({exc})") from None
    _check(p, arrays)
    return BillboardCloud(**arrays, eps=header["eps"], source_faces=header["source_faces"],
                          build_s=header["build_s"])
