"""service.kernel_cache: kernels cached before a change to a module they use are dropped.

Each step runs the kernel in a fresh Python process (real numba, real cache files in
a temporary package), as a new service or test session would.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from service.kernel_cache import drop_stale, module_imports, stale_kernels

PARTS = {
    "__init__.py": "",
    "sub/__init__.py": "",
    "sub/inc.py": """
        import numba as nb

        @nb.njit(cache=True, inline="always")
        def inc(x):
            return x + 1
    """,
    "kern.py": """
        import numba as nb

        from .sub.inc import inc

        @nb.njit(cache=True)
        def kernel(x):
            return inc(x) * 10
    """,
    "other.py": """
        import numba as nb

        @nb.njit(cache=True)
        def alone(x):
            return x * 2
    """,
}


def _package(root: Path) -> None:
    for rel, text in PARTS.items():
        path = root / "pkgk" / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))


def _run(root: Path, env: dict) -> tuple[int, int]:
    code = "from pkgk.kern import kernel; from pkgk.other import alone; print(kernel(1), alone(1))"
    out = subprocess.run([sys.executable, "-c", code], cwd=root, env=env, capture_output=True,
                         text=True, timeout=120, check=True).stdout.split()
    return int(out[0]), int(out[1])


def _edit_inc(root: Path) -> None:
    """Make ``inc`` add 2, its file newer than every cache file."""
    path = root / "pkgk" / "sub" / "inc.py"
    path.write_text(path.read_text().replace("x + 1", "x + 2"))
    # a coarse file-system clock could stamp the edit as old as the cache: 1 ms newer
    later = max(p.stat().st_mtime_ns for p in root.rglob("*.nb[ic]")) + 1_000_000
    os.utime(path, ns=(later, later))


@pytest.mark.parametrize("own_cache_dir", [False, True], ids=["pycache", "NUMBA_CACHE_DIR"])
def test_stale_kernel_found_and_dropped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                        own_cache_dir: bool) -> None:
    _package(tmp_path)
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    env.pop("NUMBA_CACHE_DIR", None)
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    if own_cache_dir:
        env["NUMBA_CACHE_DIR"] = str(tmp_path / "nbcache")
        monkeypatch.setenv("NUMBA_CACHE_DIR", env["NUMBA_CACHE_DIR"])
    assert _run(tmp_path, env) == (20, 2)
    assert stale_kernels(tmp_path, "pkgk") == []  # a current cache: nothing to drop
    _edit_inc(tmp_path)
    # numba's blind spot, which the module exists for: the old machine code still runs
    assert _run(tmp_path, env) == (20, 2), (
        "numba now notices changes to other files: service.kernel_cache may be unneeded")
    stale = stale_kernels(tmp_path, "pkgk")
    assert [(k.module, k.changed) for k in stale] == [("pkgk.kern", ("pkgk.sub.inc",))]
    assert {p.suffix for p in stale[0].files} == {".nbi", ".nbc"}
    assert all(p.name.startswith("kern.kernel-") for p in stale[0].files)
    other = sorted(p.name for p in tmp_path.rglob("other.*.nb[ic]"))
    dropped = drop_stale(tmp_path, "pkgk")
    assert [k.module for k in dropped] == ["pkgk.kern"]
    assert not any(p.exists() for p in stale[0].files)
    assert sorted(p.name for p in tmp_path.rglob("other.*.nb[ic]")) == other  # kept
    assert _run(tmp_path, env) == (30, 2)  # compiled afresh from the new source
    assert stale_kernels(tmp_path, "pkgk") == []


def test_imports_found_in_every_form(tmp_path: Path) -> None:
    pkg = tmp_path / "pkgi"
    (pkg / "a").mkdir(parents=True)
    for rel in ("__init__.py", "a/__init__.py", "a/b.py", "a/c.py", "d.py", "e.py", "f.py"):
        (pkg / rel).write_text("")
    (pkg / "a" / "c.py").write_text(textwrap.dedent("""
        from . import b
        from ..d import x
        from pkgi.e import (
            y,  # a comment
            z,
        )

        def later():
            import pkgi.f
    """))
    graph = module_imports(tmp_path, "pkgi")
    assert graph["pkgi.a.c"] == {"pkgi.a", "pkgi.a.b", "pkgi.d", "pkgi.e", "pkgi.f"}
    assert graph["pkgi.d"] == set()


def test_service_package_graph_sees_the_kernels_helpers() -> None:
    graph = module_imports(Path(__file__).resolve().parents[2])
    assert "service.galilean.propagate" in graph["service.galilean.scatter_bands"]
    assert "service.galilean.fixed_point" in graph["service.galilean.propagate"]
    assert "service.galilean.show" in graph["service.galilean.finish"]


READY = """
import sys
from pkgk.other import alone
from service.kernel_cache import kernel_ready
before = kernel_ready(alone, (1,)), kernel_ready(alone, (1.0,))
if sys.argv[1] == "call":
    alone(1)
print(*before, kernel_ready(alone, (1,)))
"""


def test_kernel_ready_sees_the_process_and_the_cache(tmp_path: Path) -> None:
    """kernel_ready: True once compiled here or cached for those types and that source.

    Fresh processes on one cache: nothing cached; compiled and saved by one call;
    the next process finds the int64 signature but not a float64 one; an edit of
    the kernel's source makes the cached one stale.
    """
    _package(tmp_path)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "nbcache"),
               PYTHONPATH=os.pathsep.join([str(Path.cwd()), str(tmp_path)]))

    def ready(step: str) -> list[str]:
        return subprocess.run([sys.executable, "-c", READY, step], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=120,
                              check=True).stdout.split()

    assert ready("call") == ["False", "False", "True"]  # cold; compiled in process
    assert ready("look") == ["True", "False", "True"]  # cached for int64 only
    other = tmp_path / "pkgk" / "other.py"
    other.write_text(other.read_text().replace("x * 2", "x * 3"))
    os.utime(other, ns=(other.stat().st_mtime_ns + 10**9,) * 2)
    assert ready("look") == ["False", "False", "False"]  # the source changed: stale
