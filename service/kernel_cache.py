"""Numba's cache and its blind spot: kernels built from code in other files.

Numba keys a cached kernel on its own source file alone (its size and time), so a
kernel that inlines or calls a jitted function from another module keeps its old
machine code after that module changes: the next process runs the old code, and
nothing says so (numba's "Notes on caching"; seen with numba 0.68.1: a kernel
inlining ``f(x) = x + 1`` from another file still returned the old result after
``f`` became ``x + 2``).  Most kernels here do that (``fixed_point.advance``,
``propagate.step``, ``show.show_row``), so an edit, a ``git checkout`` or a merge
could leave the service, the tests or a benchmark running code that is no longer
in the tree.

:func:`stale_kernels` finds the cache files of every kernel whose module imports,
directly or through other modules of the package, a source file changed after the
kernel was compiled; :func:`drop_stale` removes them, so the next call compiles
afresh.  ``holo-warmup`` (and so ``make test``, ``make demo`` and the service's own
warm-up) and the test session run it first.  A fresh clone has no cache and so
nothing to drop.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numba

__all__ = ["StaleKernel", "cache_dir_of", "drop_stale", "fingerprint", "is_warm",
           "kernel_ready", "mark_warm", "module_imports", "stale_kernels", "stamp_path"]

#: The package whose kernels are checked (all of the project's numba code is in it).
PACKAGE = "service"


@dataclass(frozen=True)
class StaleKernel:
    """One kernel's cache files, older than a source file its module depends on.

    Attributes
    ----------
    module : str
        The kernel's module (``service.galilean.finish``).
    files : tuple of Path
        Its index (``.nbi``) and machine code (``.nbc``) files.
    changed : tuple of str
        The modules it depends on that changed after it was compiled.
    """

    module: str
    files: tuple[Path, ...]
    changed: tuple[str, ...]


def _modules(root: Path, package: str) -> dict[str, Path]:
    """Module name -> source file, for every ``.py`` file of ``package`` under ``root``."""
    out = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = path.relative_to(root).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


#: An import statement anywhere in a file (indented ones, inside functions, too):
#: ``import a.b``, ``from a.b import c, d`` and ``from .b import (c, d)``.
_IMPORT = re.compile(
    r"^[ \t]*(?:import[ \t]+([\w.]+)|from[ \t]+(\.*[\w.]*)[ \t]+import[ \t]+(\([^)]*\)|[^\n]*))",
    re.MULTILINE,
)


def _imported(source: str, name: str, is_package: bool) -> set[str]:
    """Absolute names a module's ``import`` statements refer to.

    A regular expression, not :mod:`ast`: parsing and walking the package's trees
    took seconds, and this runs before every test session and warm-up.  A line that
    only looks like an import (in a string) can add a dependency, never lose one.
    """
    here = (name if is_package else name.rpartition(".")[0]).split(".")
    found: set[str] = set()
    for plain, module, names in _IMPORT.findall(source):
        if plain:
            found.add(plain)
            continue
        level = len(module) - len(module.lstrip("."))
        base = here[: len(here) - level + 1] if level else []  # from .x, ..x
        stem = ".".join([*base, module.lstrip(".")] if module.lstrip(".") else base)
        found.add(stem)
        for item in names.strip("()").replace("\n", " ").split(","):
            word = item.split("#")[0].split()
            if word:
                found.add(f"{stem}.{word[0]}")
    return found


def module_imports(root: Path, package: str = PACKAGE) -> dict[str, set[str]]:
    """Each module of ``package`` -> the modules of ``package`` it imports directly.

    ``from a.b import c`` counts ``a.b`` and, when it is a module, ``a.b.c``;
    imports inside functions count too (a kernel may use what a function imports).
    """
    modules = _modules(root, package)
    graph = {}
    for name, path in modules.items():
        try:
            source = path.read_text(encoding="utf-8", errors="replace")
        except OSError:
            source = ""
        names = _imported(source, name, path.name == "__init__.py")
        graph[name] = {n for n in names if n in modules and n != name}
    return graph


def _closure(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """Every module -> all the modules it reaches through ``graph`` (itself excluded)."""
    out = {}
    for start in graph:
        seen, todo = set(), list(graph[start])
        while todo:
            m = todo.pop()
            if m not in seen and m != start:
                seen.add(m)
                todo.extend(graph.get(m, ()))
        out[start] = seen
    return out


def cache_dir_of(source: Path) -> Path:
    """Where numba keeps the cache of the kernels in ``source`` (``NUMBA_CACHE_DIR`` aware)."""
    root = os.environ.get("NUMBA_CACHE_DIR")
    if not root:
        return source.parent / "__pycache__"
    # deferred: numba's private cache locator, needed only with NUMBA_CACHE_DIR set
    from numba.core.caching import _CacheLocator

    return Path(root) / _CacheLocator.get_suitable_cache_subpath(str(source))


def _kernels(source: Path) -> dict[str, list[Path]]:
    """A source file's cached kernels: index file name -> its index and data files."""
    folder, stem = cache_dir_of(source), source.stem
    try:
        files = [p for p in folder.iterdir() if p.name.startswith(stem + ".")]
    except OSError:
        return {}
    out: dict[str, list[Path]] = {}
    for index in (p for p in files if p.suffix == ".nbi"):
        key = index.name[: -len(".nbi")]
        out[index.name] = [index, *(p for p in files
                                    if p.suffix == ".nbc" and p.name.startswith(key + "."))]
    return out


def _mtime(path: Path) -> int:
    with contextlib.suppress(OSError):
        return path.stat().st_mtime_ns
    return 0


def stale_kernels(root: Path | None = None, package: str = PACKAGE) -> list[StaleKernel]:
    """The cached kernels compiled before a change to a module their module depends on.

    Parameters
    ----------
    root : Path, optional
        The folder holding ``package`` (default: the installed package's parent).

    Returns
    -------
    list of StaleKernel
        Oldest file of each kernel against the newest dependency; empty when the
        cache is empty or current.
    """
    root = Path(__file__).resolve().parent.parent if root is None else root
    modules = _modules(root, package)
    deps = _closure(module_imports(root, package))
    stamps = {name: _mtime(path) for name, path in modules.items()}
    stale = []
    for name, path in modules.items():
        for files in _kernels(path).values():
            compiled = min(_mtime(f) for f in files)
            changed = tuple(sorted(d for d in deps[name] if stamps[d] > compiled))
            if changed:
                stale.append(StaleKernel(name, tuple(files), changed))
    return stale


def drop_stale(root: Path | None = None, package: str = PACKAGE) -> list[StaleKernel]:
    """Remove the cache files of :func:`stale_kernels`; returns the kernels dropped.

    A file that cannot be removed (a read-only cache) is left; numba then loads the
    old code, as it would have without this check.
    """
    stale = stale_kernels(root, package)
    for kernel in stale:
        for path in kernel.files:
            with contextlib.suppress(OSError):
                path.unlink()
    return stale


def stamp_path() -> Path:
    """Where the warm-cache stamp lives: beside numba's cache."""
    root = os.environ.get("NUMBA_CACHE_DIR")
    base = Path(root) if root else Path(__file__).resolve().parent / "__pycache__"
    return base / "holo-warmup-stamp.json"


def fingerprint() -> dict[str, str]:
    """What the cache was filled for: the ``service`` sources, numba and Python."""
    pkg = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted(pkg.rglob("*.py")):
        st = path.stat()
        h.update(f"{path.relative_to(pkg)}:{st.st_mtime_ns}:{st.st_size}\n".encode())
    return {"sources": h.hexdigest(), "numba": numba.__version__, "python": sys.version}


def is_warm() -> bool:
    """Whether a warm-up found every kernel cached since the sources last changed."""
    try:
        return json.loads(stamp_path().read_text()) == fingerprint()
    except (OSError, ValueError):
        return False


def mark_warm() -> None:
    """Write the stamp (after a warm-up that filled, or found, every kernel cached)."""
    path = stamp_path()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps(fingerprint()))
        os.replace(tmp, path)
    except OSError:
        pass  # a read-only cache: the next start goes through the child again


def kernel_ready(dispatcher: Any, args: tuple) -> bool:
    """Whether calling ``dispatcher(*args)`` would compile nothing.

    True when this process holds the kernel for these argument types, or numba's
    cache has it (its index names the signature, for the kernel's current source):
    the call then loads it instead of compiling.  A caller with a slower kernel
    that needs no compile can run that one until this is True (the Galilean
    stage's plain scatter, compiled in the background phase: docs/compile-time.md).

    Parameters
    ----------
    dispatcher : numba Dispatcher
        An ``@njit(cache=True)`` kernel.
    args : tuple
        The arguments it would be called with (only their numba types count).

    Returns
    -------
    bool
        False too when the kernel has no file cache, or its index cannot be read.
    """
    sig = tuple(dispatcher.typeof_pyval(a) for a in args)
    if sig in dispatcher.overloads:
        return True
    cache = getattr(dispatcher, "_cache", None)
    if not getattr(cache, "_enabled", False):
        return False
    try:  # numba's own key and index (numba.core.caching.Cache._load_overload)
        key = cache._index_key(sig, dispatcher.targetctx.codegen())
        return key in cache._cache_file._load_index()
    except Exception:  # noqa: BLE001 -- a torn or foreign index, numba internals moved
        return False
