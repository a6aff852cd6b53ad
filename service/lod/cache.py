"""Chains cached on disk by the mesh's hash, built once across processes under a lock file.

The format is in ``docs/file-formats.md``: ``<hash>.npz`` arrays plus a ``<hash>.json``
header, no pickle.
"""

from __future__ import annotations

import contextlib
import json
import os
import warnings
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np

from service.base.errors import HoloError
from service.lod.chain import LodChain, build_uncached, mesh_key
from service.lod.settings import (
    CACHE_ENV,
    CHAIN_VERSION,
    COLOUR_ANGLES,
    LodCacheWarning,
    LodSettings,
    Progress,
)
from service.npy_file import read_npz
from service.render.mesh import Mesh, Shading


def cache_dir() -> Path:
    """The chain cache folder.

    ``$HOLO_LOD_CACHE`` if set, else ``$XDG_CACHE_HOME/holo-realizer/lod`` (by default
    ``~/.cache/holo-realizer/lod``).
    """
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "holo-realizer" / "lod"


def build_chain(mesh: Mesh, settings: LodSettings | None = None,
                cache: Path | None | bool = True, notes: list | None = None,
                progress: Progress | None = None) -> LodChain:
    """The LOD chain of ``mesh``, read from the cache or built (and then cached).

    Builds of one chain are serialised across processes by a lock file
    (``<key>.lock`` in the cache folder, removed when the build ends): a second
    process asking for a chain being built waits for it and reads the cache instead
    of building it again.  A damaged
    or torn cache file is reported (``notes``, else a :class:`LodCacheWarning`) and
    rebuilt; an unwritable cache folder is reported and the chain used uncached.

    Parameters
    ----------
    mesh : Mesh
    settings : LodSettings, optional
        Its ``fractions`` set the levels.
    cache : Path, True or False
        The cache folder, True for :func:`cache_dir`, False for no cache.
    notes : list of str, optional
        Where to put what went wrong with the cache (instead of warnings: a
        background build's thread must not touch the warnings filters).
    progress : callable, optional
        ``progress(done, planned)`` after each decimation of a build.

    Returns
    -------
    LodChain
    """
    settings = settings or LodSettings()
    key = mesh_key(mesh, settings.recipe)
    folder = cache_dir() if cache is True else (Path(cache) if cache else None)
    if folder is None:
        return build_uncached(mesh, settings, key, progress)
    chain, _problem = _read_cache(folder, key, mesh)
    if chain is not None:
        _drop_stale_lock(folder, key)
        return chain
    return _build_locked(mesh, settings, folder, key, notes, progress)


def _build_locked(mesh: Mesh, settings: LodSettings, folder: Path, key: str,
                  notes: list | None, progress: Progress | None) -> LodChain:
    """Build the chain under its lock file and cache it (see :func:`build_chain`).

    Another process may have built it while this one waited for the lock: then it
    is read from the cache.
    """
    with _build_lock(folder, key):
        chain, problem = _read_cache(folder, key, mesh)  # built meanwhile by another?
        if chain is not None:
            return chain
        if problem:
            _note(notes, f"level-of-detail cache {folder / key}.* is damaged ({problem}); "
                  "rebuilding it")
        chain = build_uncached(mesh, settings, key, progress)
        if len(chain.levels) > 1:
            try:
                write_chain(folder, chain)
            except OSError as exc:  # a read-only or odd cache folder: go on without it
                _note(notes, f"level-of-detail cache not written ({folder}): {exc}")
    return chain


def _note(notes: list | None, message: str) -> None:
    """Report a cache problem: into ``notes`` when given, else as a warning."""
    if notes is None:
        warnings.warn(message, LodCacheWarning, stacklevel=3)
    else:
        notes.append(message)


@contextlib.contextmanager
def _build_lock(folder: Path, key: str) -> Iterator[None]:
    """Hold ``<folder>/<key>.lock`` exclusively (``flock``) while building one chain.

    The file is removed on the way out, while still held, so the cache keeps no lock
    files.  That is race-free with the usual check: a process that opened the file
    before it was removed and got the lock after finds that the path no longer names
    the file it holds (:func:`_lock_path`), and opens the path again.  Where the lock
    file cannot be made (no folder, no ``fcntl``) the build goes on unlocked: at worst
    two processes build the same chain and the later rename wins.  The lock goes with
    the process, so a builder that dies frees it (and its file stays until the next
    build of that chain removes it).
    """
    path = folder / f"{key}.lock"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fh = _lock_path(path, blocking=True)
    except (ImportError, OSError):
        yield
        return
    try:
        yield
    finally:
        _unlink_held(path, fh)


def _lock_path(path: Path, blocking: bool) -> BinaryIO | None:
    """Open ``path`` and ``flock`` it exclusively, making sure the path still names it.

    Returns the open file holding the lock, or None when ``blocking`` is false and
    another process holds it.  Raises ImportError without ``fcntl``, OSError when the
    file cannot be opened.
    """
    # deferred: POSIX only: the module still imports elsewhere
    import fcntl

    while True:
        fh = open(path, "ab")  # noqa: SIM115 (returned, holding the lock)
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
        except BlockingIOError:
            fh.close()
            return None
        try:
            if os.path.samestat(os.fstat(fh.fileno()), os.stat(path)):
                return fh
        except FileNotFoundError:  # removed by the holder we waited for
            pass
        fh.close()  # a file no longer at the path: lock the one that is there now


def _unlink_held(path: Path, fh: BinaryIO) -> None:
    """Remove a lock file this process holds, then release it."""
    with contextlib.suppress(OSError):
        path.unlink()
    fh.close()


def _drop_stale_lock(folder: Path, key: str) -> None:
    """Remove a ``<key>.lock`` left beside a cached chain, unless a process holds it.

    A builder that died leaves its file, and so did versions before the lock files
    were removed.
    """
    path = folder / f"{key}.lock"
    if not path.exists():
        return
    with contextlib.suppress(ImportError, OSError):
        fh = _lock_path(path, blocking=False)
        if fh is not None:
            _unlink_held(path, fh)


def write_chain(folder: Path, chain: LodChain) -> None:
    """Write a chain's cache files.

    ``<key>.npz`` holds mesh levels 1.. as ``vertices_k``, ``faces_k`` and the normals
    per-polygon light uses, ``shading_k``; each billboard
    level k is ``<key>.b<k>.hbc``; the header ``<key>.json`` comes last.  Written to
    temporary names and renamed, so a reader never sees half a file.
    """
    folder.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for k, m in enumerate(chain.levels[1:], start=1):
        if chain.kinds[k] == "billboard":
            from service.simplify.cloud_file import save_cloud  # deferred: as load's
            tmp_cloud = folder / f".{chain.key}.b{k}.{os.getpid()}.tmp.hbc"
            save_cloud(m, tmp_cloud)
            os.replace(tmp_cloud, folder / f"{chain.key}.b{k}.hbc")
            continue
        arrays[f"vertices_{k}"] = m.vertices
        arrays[f"faces_{k}"] = m.triangles
        if m.shading is not None:
            arrays[f"shading_{k}"] = m.shading.polygons
    header = {
        "format": "holo-lod-chain", "version": CHAIN_VERSION, "key": chain.key,
        "levels": len(chain.levels), "kinds": list(chain.kinds),
        "errors": chain.errors.tolist(), "triangles": chain.triangles.tolist(),
        "radius": chain.radius, "build_ms": round(chain.build_ms, 3),
        "turned": (chain.turned if chain.turned is not None
                   else np.zeros((len(chain.levels), len(COLOUR_ANGLES), 2))).tolist(),
        "area": chain.area,
    }
    npz, js = folder / f"{chain.key}.npz", folder / f"{chain.key}.json"
    tmp = folder / f".{chain.key}.{os.getpid()}.tmp.npz"
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    os.replace(tmp, npz)
    tmp_js = folder / f".{chain.key}.{os.getpid()}.tmp.json"
    tmp_js.write_text(json.dumps(header))
    os.replace(tmp_js, js)


def read_chain(folder: Path, key: str, mesh: Mesh) -> LodChain | None:
    """The cached chain of ``mesh`` under ``key``, or None if absent or damaged.

    A bad cache file is never an error: :func:`build_chain` reports it and rebuilds.
    """
    return _read_cache(folder, key, mesh)[0]


def _read_cache(folder: Path, key: str, mesh: Mesh) -> tuple[LodChain | None, str]:
    """``(chain, "")``, ``(None, "")`` when not cached, or ``(None, what is wrong)``."""
    npz, js = folder / f"{key}.npz", folder / f"{key}.json"
    have = (npz.is_file(), js.is_file())
    if have == (False, False):
        return None, ""
    if not all(have):  # the header is written last: a write cut short, or a file deleted
        return None, f"{(js if have[0] else npz).name} is missing"
    try:
        return _parse_cache(folder, key, mesh, json.loads(js.read_text())), ""
    except (OSError, ValueError, KeyError, TypeError, IndexError, ImportError, HoloError,
            EOFError, zipfile.BadZipFile) as exc:
        return None, f"{type(exc).__name__}: {exc}"[:200]


def _mesh_level(data: dict, k: int, name: str) -> Mesh:
    """Mesh level ``k`` of a chain's arrays, with the normals it is lit with.

    A level without them is an error (KeyError): every quadric level carries them
    since :data:`CHAIN_VERSION` 9, so a file without them is damaged.
    """
    level = Mesh.from_triangles(data[f"vertices_{k}"], data[f"faces_{k}"], name)
    shading = Shading(np.asarray(data[f"shading_{k}"], np.float64))
    return Mesh(level.vertices, level.polygons, level.counts, name, shading=shading)


def _parse_cache(folder: Path, key: str, mesh: Mesh, head: dict) -> LodChain:
    """The chain from its header and arrays; ValueError (or another) when they disagree."""
    if not isinstance(head, dict) or head.get("version") != CHAIN_VERSION or head.get("key") != key:
        raise ValueError("the header is not this chain's (format version or key differ)")
    n, kinds = int(head["levels"]), tuple(head["kinds"])
    levels: list = [mesh]
    data = read_npz(folder / f"{key}.npz")
    for k in range(1, n):
        if kinds[k] == "billboard":
            # deferred: clouds load the compiled simplifier (chain._decimated's reason)
            from service.simplify.cloud_file import load_cloud

            levels.append(load_cloud(folder / f"{key}.b{k}.hbc"))
            continue
        levels.append(_mesh_level(data, k, f"{mesh.name}@{k}"))
    errors = np.asarray(head["errors"], np.float64)
    tris = np.asarray(head["triangles"], np.int64)
    turned = np.asarray(head["turned"], np.float64)
    meshes = np.array([kind != "billboard" for kind in kinds])
    if (errors.shape != (n,) or tris.shape != (n,) or len(kinds) != n
            or turned.shape != (n, len(COLOUR_ANGLES), 2)
            or not np.all((turned >= 0) & (turned <= 1))
            or not np.all(np.diff(errors[meshes]) >= 0)):
        raise ValueError("the header's levels, errors, triangles and turned shares disagree")
    return LodChain(tuple(levels), errors, tris, kinds, float(head["radius"]), 0.0, key,
                    turned=turned, area=float(head["area"]))
