"""The packages import each other one way only (README, "Layout").

Every module's imports (function-local ones included) are read with ``ast`` and
checked against the layer table below, so a new module is checked without editing
this file.  From the bottom up:

* **base** - ``service.base``: ``errors``, ``signals``, ``heap``, ``addresses``, ``cli_args``:
  the exception hierarchy, the exit rule, the allocator knob, address and argparse
  types.  They import nothing of ours but each other.
* **protocols** - ``drivers.protocols``, ``drivers.events``: pure codecs and the events
  they make.  Base only.
* **drivers** - the rest of ``drivers``: readers, filters, recording, publisher,
  ``pty_link``.  Base and protocols only (never the render service).
* **sim_devices** - simulated devices: base, protocols and ``drivers.pty_link``.
* **service** - the render pipeline, the Galilean stage, the ZeroMQ service: may use
  drivers (the service subscribes to devices and filters poses), never sim_devices
  or game.
* **game** - a client of the service.
* **top** - commands (each package's ``commands`` folder) and benchmarks
  (``service.bench``): anything; and nothing below them imports them.
"""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("service", "drivers", "sim_devices", "game")
BASE = ("service.base",)
PROTOCOLS = ("drivers.protocols", "drivers.events")
#: layer -> the prefixes its modules may import (besides their own package's layer).
ALLOWED = {
    "base": BASE,
    "protocols": BASE + PROTOCOLS,
    "drivers": BASE + PROTOCOLS + ("drivers",),
    "sim_devices": BASE + PROTOCOLS + ("drivers.pty_link", "sim_devices"),
    "service": ("service", "drivers"),
    "game": ("game", "service", "drivers"),
    "top": PACKAGES,
}


def _name(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


def _ours(names: set[str]) -> set[str]:
    return {n for n in names if n.split(".")[0] in PACKAGES}


def _imports(tree: ast.Module) -> set[str]:
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
    return _ours(found)


def _is_command(name: str, scripts: set[str]) -> bool:
    """A command: a module of a package's ``commands`` folder (each console script's).

    ``service.net.worker`` also runs as ``python -m``, but it is the service's own worker
    process, started by the service: not a command.
    """
    return ".commands." in name or name in scripts


def test_every_console_script_is_in_a_commands_folder():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    for script, entry in scripts.items():
        module = entry.split(":")[0]
        assert ".commands." in module, f"{script} runs {module}, outside a commands folder"
        # named after the script, so a newcomer finds holo-render in holo_render.py
        assert script.replace("-", "_").startswith(module.rsplit(".", 1)[1]), script


def _modules() -> dict[str, tuple[set[str], bool]]:
    """Every module -> (the modules of ours it imports, whether it is a command)."""
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    commands = {entry.split(":")[0] for entry in scripts.values()}
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            tree = ast.parse(path.read_text(), str(path))
            name = _name(path)
            out[name] = (_imports(tree), _is_command(name, commands))
    return out


MODULES = _modules()


def _is_module(name: str) -> bool:
    return name in MODULES


def layer(name: str) -> str:
    """The layer a module belongs to."""
    is_command = MODULES[name][1]
    if is_command or name.startswith("service.bench"):
        return "top"
    if name.startswith(BASE):
        return "base"
    if name.startswith(PROTOCOLS):
        return "protocols"
    return name.split(".")[0]


def _within(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def test_every_module_is_read():
    assert {"service.net.server", "drivers.reader", "sim_devices.tracker", "game.rules"} <= set(
        MODULES)
    assert layer("service.commands.holo_render") == "top" and layer("service.base.errors") == "base"


@pytest.mark.parametrize("name", sorted(MODULES))
def test_imports_go_down_only(name):
    imports, _ = MODULES[name]
    allowed = ALLOWED[layer(name)]
    # a name imported from a module (``from drivers.protocols import hatire``) counts by
    # its module; names that are not modules are dropped
    modules = {i for i in imports if _is_module(i)}
    wrong = sorted(i for i in modules if not _within(i, allowed))
    assert not wrong, f"{name} ({layer(name)} layer) imports {wrong}"


@pytest.mark.parametrize("name", sorted(n for n in MODULES if layer(n) != "top"))
def test_nothing_below_the_top_imports_a_command_or_a_benchmark(name):
    imports, _ = MODULES[name]
    top = sorted(i for i in imports if _is_module(i) and layer(i) == "top")
    assert not top, f"{name} imports {top}"


def test_the_checker_catches_an_upward_import():
    tree = ast.parse("def f():\n    from sim_devices.tracker import TrackerSim\n")
    imports = {i for i in _imports(tree) if _is_module(i)}
    assert imports == {"sim_devices.tracker"}
    assert not _within("sim_devices.tracker", ALLOWED["drivers"])


def test_every_exception_class_joins_the_one_hierarchy():
    import importlib
    import inspect

    from service.base.errors import HoloError

    outside = []
    for name in MODULES:
        module = importlib.import_module(name)
        for cls_name, cls in inspect.getmembers(module, inspect.isclass):
            # private control flow and warnings aside
            if (cls.__module__ == name and issubclass(cls, Exception)
                    and not issubclass(cls, (HoloError, Warning))
                    and not cls_name.startswith("_")):
                outside.append(f"{name}.{cls_name}")
    assert not outside, f"not HoloErrors: {outside}"


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of ``graph`` (module -> modules it imports), as module lists."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = [stack.pop()]
            while comp[-1] != v:
                comp.append(stack.pop())
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _graph() -> dict[str, set[str]]:
    """Every module -> the modules of ours it imports (inside functions too).

    A module's own packages are left out: importing ``a.b.c`` runs ``a/b/__init__``
    first, which is not a cycle of the code's making.
    """
    return {name: {i for i in imports if _is_module(i) and i != name
                   and not name.startswith(i + ".")}
            for name, (imports, _) in MODULES.items()}


def test_no_import_cycles():
    # an import inside a function hides a cycle until run time; there are none
    assert _cycles(_graph()) == []


def test_the_cycle_finder_finds_a_cycle_through_a_function_import():
    a = _imports(ast.parse("from service.lod.cache import read_chain\n"))
    b = _imports(ast.parse("def f():\n    from service.lod.state import LodState\n"))
    graph = {"service.lod.state": {i for i in a if _is_module(i)},
             "service.lod.cache": {i for i in b if _is_module(i)}}
    assert _cycles(graph) == [["service.lod.cache", "service.lod.state"]]


def test_the_readme_layout_table_names_every_package_folder():
    readme = (ROOT / "README.md").read_text()
    table = readme[readme.index("## Layout"):readme.index("The packages import each other")]
    folders = sorted({str(p.parent.relative_to(ROOT)) for package in PACKAGES
                      for p in (ROOT / package).rglob("__init__.py")})
    missing = [f for f in folders if f"`{f}/`" not in table]
    assert not missing, f"README's layout table does not name {missing}"


def _catches_import_error(handler: ast.ExceptHandler) -> bool:
    """Whether an ``except`` clause catches ImportError (alone or in a tuple)."""
    types = handler.type.elts if isinstance(handler.type, ast.Tuple) else [handler.type]
    return any(isinstance(t, ast.Name) and t.id in ("ImportError", "ModuleNotFoundError")
               for t in types)


def _unexplained_imports(source: str) -> list[int]:
    """Lines of imports inside functions that give no reason for not being at the top.

    A reason is a ``# deferred: ...`` comment on the import's line or on the line
    just above its block of imports; an import inside ``try`` with an ``except
    ImportError`` (an optional dependency) explains itself.
    """
    lines = source.splitlines()
    tree = ast.parse(source)
    guarded = {n.lineno for t in ast.walk(tree) if isinstance(t, ast.Try)
               and any(_catches_import_error(h) for h in t.handlers)
               for b in t.body for n in ast.walk(b) if isinstance(n, ast.Import | ast.ImportFrom)}
    bad = []
    for fn in ast.walk(tree):
        if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(fn):
            if not isinstance(node, ast.Import | ast.ImportFrom) or node.lineno in guarded:
                continue
            above = node.lineno - 1
            while above > 0 and lines[above - 1].lstrip().startswith(("from ", "import ")):
                above -= 1
            said = "# deferred:" in lines[node.lineno - 1] or (
                above > 0 and lines[above - 1].lstrip().startswith("# deferred:"))
            if not said:
                bad.append(node.lineno)
    return sorted(set(bad))


@pytest.mark.parametrize("name", sorted(MODULES))
def test_imports_inside_functions_say_why(name):
    path = ROOT / (name.replace(".", "/") + ".py")
    if not path.exists():
        path = ROOT / name.replace(".", "/") / "__init__.py"
    bad = _unexplained_imports(path.read_text())
    assert not bad, (f"{path.relative_to(ROOT)}: imports inside functions at lines {bad} give no "
                     "reason (move them to the top, or say '# deferred: why' above them)")


def test_the_import_reason_check_catches_a_silent_import():
    assert _unexplained_imports("def f():\n    import json\n") == [2]
    assert _unexplained_imports("def f():\n    # deferred: heavy\n    import json\n") == []
    assert _unexplained_imports(
        "def f():\n    try:\n        import x\n    except ImportError:\n        x = None\n") == []
