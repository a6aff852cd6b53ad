"""Every command's --help: plain text (no reStructuredText markup) and the exit rule.

The commands are read from pyproject.toml's [project.scripts], and holo-bench's
benchmarks from its table, so a new command or benchmark is scanned without
editing this file.
"""

from __future__ import annotations

import importlib
import re
import tomllib

import pytest
from testkit import ROOT

from service.commands.holo_bench import BENCHES

SCRIPTS = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
#: ``x``, :func:`x`, *emphasis* (not 3*4 or **kwargs-like text).
MARKUP = re.compile(r"``|:[a-z]+:`|(?<![\w*])\*[A-Za-z][^*\n]*\*(?![\w*])")
#: Commands without the rule in their help: they run no loop and take no signal.
NO_RULE: set[str] = set()


def _help(entry: str, argv: list[str], capsys) -> str:
    module, func = entry.split(":")
    main = getattr(importlib.import_module(module), func)
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's --help
        rc = exc.code
    assert rc in (0, None)
    return capsys.readouterr().out


def _commands() -> list:
    out = []
    for name, entry in SCRIPTS.items():
        out.append(pytest.param(name, entry, ["--help"], id=name))
    for bench in BENCHES:
        name = f"holo-bench {bench}"
        out.append(pytest.param(name, SCRIPTS["holo-bench"], [bench, "--help"], id=name))
    return out


@pytest.mark.parametrize(("name", "entry", "argv"), _commands())
def test_help_has_no_markup(name, entry, argv, capsys):
    text = _help(entry, argv, capsys)
    assert text.strip()
    found = MARKUP.findall(text)
    assert not found, f"{name} --help shows markup: {found[:5]}"


@pytest.mark.parametrize(("name", "entry", "argv"),
                         [c for c in _commands() if c.values[0] not in NO_RULE])
def test_help_states_the_exit_rule(name, entry, argv, capsys):
    """Every command's --help, and every ``holo-bench NAME --help``, ends with the rule."""
    text = " ".join(_help(entry, argv, capsys).split())
    assert "Ctrl-C (SIGINT) 130" in text and "SIGTERM 143" in text, name


@pytest.mark.parametrize(("name", "entry", "argv"), _commands())
def test_help_gives_no_flag_a_boolean_default(name, entry, argv, capsys):
    """holo-service's --no-warmup read "(default: True)": which way is on?"""
    text = " ".join(_help(entry, argv, capsys).split())
    assert "(default: True)" not in text and "(default: False)" not in text, name


#: ``--opt VALUE`` in a usage line or an option list.
OPTION_VALUE = re.compile(r"(--[a-z][a-z0-9-]*)[ =]([A-Z][A-Z0-9_]*)(?![\w,])")
#: Options whose argparse default placeholder says what the value is.
CLEAR_DEFAULTS = {"--name": "NAME"}


@pytest.mark.parametrize(("name", "entry", "argv"), _commands())
def test_help_gives_no_option_argparse_default_placeholder(name, entry, argv, capsys):
    """``--out OUT`` says nothing; ``--out DIR`` does (docs/command-line.md, Placeholders)."""
    text = _help(entry, argv, capsys)
    echoed = sorted({f"{opt} {value}" for opt, value in OPTION_VALUE.findall(text)
                     if value == opt[2:].replace("-", "_").upper()
                     and CLEAR_DEFAULTS.get(opt) != value})
    assert not echoed, f"{name} --help: give these a metavar: {echoed}"


def test_command_line_doc_lists_every_command():
    """docs/command-line.md's table of commands names every console script."""
    text = (ROOT / "docs" / "command-line.md").read_text()
    table = text.split("## The commands", 1)[1].split("\n## ", 1)[0]
    missing = [name for name in SCRIPTS if f"| `{name}` |" not in table]
    assert not missing, f"add to docs/command-line.md's table: {missing}"
