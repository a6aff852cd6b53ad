"""The billboard-cloud file, ``.hbc`` (``docs/file-formats.md``, "Billboard clouds").

An uncompressed zip holding ``header.json`` and one ``.npy`` file per array of
:class:`~service.simplify.billboard.BillboardCloud`.  Arrays are read with
``allow_pickle=False``; nothing in the file is ever unpickled or executed.  A file
that is not a zip, lacks a member, has an unknown version, or whose arrays have the
wrong shape, type or disagree with each other raises
:class:`~service.errors.MeshFileError` with one line saying what is wrong.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np

from service.errors import MeshFileError
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
    eps = header.get("eps")
    if not isinstance(eps, int | float) or not np.isfinite(eps) or eps <= 0:
        raise MeshFileError(path, "header.json", "eps must be a positive number")
    return header


def _array(z: zipfile.ZipFile, path: str, name: str, sizes: dict) -> np.ndarray:
    dtype, shape = ARRAYS[name]
    try:
        arr = np.lib.format.read_array(io.BytesIO(z.read(f"{name}.npy")), allow_pickle=False)
    except KeyError:
        raise MeshFileError(path, f"{name}.npy", "missing") from None
    except (ValueError, OSError, EOFError) as exc:
        raise MeshFileError(path, f"{name}.npy", f"unreadable array ({exc})") from None
    if arr.dtype != dtype:
        raise MeshFileError(path, f"{name}.npy", f"dtype {arr.dtype}, want {np.dtype(dtype)}")
    want = tuple(sizes.get(s, s) for s in shape)
    if -3 in want:  # the texel count comes from tex_offset
        want = tuple(arr.shape[0] if s == -3 else s for s in want)
    if arr.shape != want:
        raise MeshFileError(path, f"{name}.npy", f"shape {arr.shape}, want {want}")
    return arr


def _check(path: str, c: dict) -> None:
    """Arrays that parse but disagree with each other."""
    if not (np.isfinite(c["corners"]).all() and np.isfinite(c["planes"]).all()):
        raise MeshFileError(path, "corners.npy", "non-finite coordinates")
    sizes = LAYERS * c["tex_shape"].prod(axis=1) if c["tex_shape"].size else np.zeros(0, np.int64)
    if (c["tex_shape"] < 1).any() or c["tex_offset"][0] != 0 or not np.array_equal(
            np.diff(c["tex_offset"]), sizes):
        raise MeshFileError(path, "tex_offset.npy", "does not match tex_shape")
    if c["tex_offset"][-1] != c["rgba"].shape[0] or c["rgba"].shape[0] != c["normal"].shape[0]:
        raise MeshFileError(path, "rgba.npy", "texel count does not match tex_offset")


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
            sizes = {-1: header["billboards"], -2: header["billboards"] + 1}
            arrays = {name: _array(z, p, name, sizes) for name in ARRAYS}
    except zipfile.BadZipFile as exc:
        raise MeshFileError(p, "", f"not a billboard-cloud zip or truncated ({exc})") from None
    except (zipfile.LargeZipFile, EOFError) as exc:
        raise MeshFileError(p, "", f"truncated or unreadable ({exc})") from None
    _check(p, arrays)
    return BillboardCloud(**arrays, eps=float(header["eps"]),
                          source_faces=header["source_faces"],
                          build_s=float(header.get("build_s", 0.0)))
