"""What every ``holo-*`` command line shares: argparse types, size options, help text.

Values are checked where argparse parses them, so a bad one gets argparse's one-line
usage error (exit status 2) before any work starts::

    p.add_argument("--zones", type=int_range(1, 64), default=5)
    p.add_argument("--size", type=size, default=(320, 240), metavar="WxH")
    p.add_argument("--pub", type=endpoint(bind=True))
    p.add_argument("--scenes", type=comma_list(scene_name), default="game,cyclic")

Sizes are spelled one way everywhere, ``--size WxH`` (columns x rows, ``320x240``);
:func:`add_size_option` also accepts the old ``--cols N`` / ``--rows N`` as hidden
aliases that still work and say they are deprecated.  :func:`plain_help` turns the
reStructuredText of a module docstring into plain text for ``--help``.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
import textwrap
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from service.base.addresses import check_endpoint
from service.base.errors import SettingsError
from service.base.signals import EXIT_RULE

T = TypeVar("T")

__all__ = [
    "add_size_option",
    "comma_list",
    "endpoint",
    "exit_rule_epilog",
    "float_range",
    "int_range",
    "output_problem",
    "plain_help",
    "size",
]

#: Largest width or height a size may have (as :class:`service.display.DisplaySettings`).
MAX_SIDE = 8192


def _named(fn: Callable[[str], T], name: str) -> Callable[[str], T]:
    """Give a type function the name argparse shows in ``invalid NAME value``."""
    fn.__name__ = name
    return fn


def int_range(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """An argparse type: an integer in ``[lo, hi]`` (None: unbounded that side)."""

    def parse(text: str) -> int:
        try:
            value = int(text, 0) if text.strip().lower().startswith("0x") else int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"want an integer, got {text!r}") from None
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f"must be {_bounds(lo, hi)}, got {value}")
        return value

    return _named(parse, "integer")


def float_range(lo: float | None = None, hi: float | None = None, *,
                lo_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"want a number, got {text!r}") from None
        low_bad = lo is not None and (value <= lo if lo_open else value < lo)
        if not math.isfinite(value) or low_bad or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(
                f"must be {_bounds(lo, hi, lo_open)}, got {text}")
        return value

    return _named(parse, "number")


def _bounds(lo: float | None, hi: float | None, lo_open: bool = False) -> str:
    low = "" if lo is None else (f"> {lo}" if lo_open else f">= {lo}")
    if hi is None:
        return low or "a number"
    if lo is None:
        return f"<= {hi}"
    return f"in ({lo}, {hi}]" if lo_open else f"from {lo} to {hi}"


def size(text: str) -> tuple[int, int]:
    """An argparse type: ``WxH`` (``320x240``) as ``(cols, rows)``, each 1 to 8192."""
    m = re.fullmatch(r"\s*([0-9]+)\s*[xX]\s*([0-9]+)\s*", text)
    if m is None:
        raise argparse.ArgumentTypeError(f"want WxH, e.g. 320x240, got {text!r}")
    cols, rows = int(m.group(1)), int(m.group(2))
    if not (1 <= cols <= MAX_SIDE and 1 <= rows <= MAX_SIDE):
        raise argparse.ArgumentTypeError(f"width and height must be 1 to {MAX_SIDE}, got {text}")
    return cols, rows


size.__name__ = "size"


def comma_list(item: Callable[[str], T], *, unique: bool = True) -> Callable[[str], list[T]]:
    """An argparse type: comma-separated items, each parsed by ``item`` (at least one)."""

    def parse(text: str) -> list[T]:
        parts = [p.strip() for p in text.split(",")]
        if not text.strip() or any(not p for p in parts):
            raise argparse.ArgumentTypeError(f"want a comma-separated list, got {text!r}")
        values = [item(p) for p in parts]
        if unique and len(set(map(repr, values))) < len(values):
            raise argparse.ArgumentTypeError(f"repeated item in {text!r}")
        return values

    return _named(parse, "list")


def endpoint(bind: bool = True) -> Callable[[str], str]:
    """An argparse type: a ZeroMQ address (:func:`service.base.addresses.check_endpoint`)."""

    def parse(text: str) -> str:
        try:
            return check_endpoint(text, bind)
        except SettingsError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    return _named(parse, "address")


class _SizePart(argparse.Action):
    """``--cols N`` / ``--rows N``: one side of ``dest`` (a (cols, rows) pair), deprecated."""

    def __init__(self, option_strings: Sequence[str], dest: str, index: int = 0,
                 size_dest: str = "size", **kw: Any) -> None:
        super().__init__(option_strings, dest, **kw)
        self.index, self.size_dest = index, size_dest

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        side = "W" if self.index == 0 else "H"
        print(f"{parser.prog}: {option_string} is deprecated; use --size WxH "
              f"({side} = {values})", file=sys.stderr)
        current = getattr(namespace, self.size_dest)
        current = list(size(current) if isinstance(current, str) else current)
        current[self.index] = values
        setattr(namespace, self.size_dest, tuple(current))


def add_size_option(p: argparse.ArgumentParser, default: tuple[int, int], help: str,
                    *, old_cols_rows: bool = False, flag: str = "--size") -> None:
    """``--size WxH`` (``args.size`` = (cols, rows)); ``old_cols_rows`` adds hidden aliases.

    With ``old_cols_rows``, ``--cols N`` and ``--rows N`` still set one side each, not
    shown in ``--help``, with a one-line deprecation warning on stderr.  Options are
    applied left to right, so a later ``--size`` wins over an earlier ``--cols``.
    """
    dest = flag.lstrip("-").replace("-", "_")
    # a string default goes through ``size`` too, and --help shows it as WxH (also
    # under ArgumentDefaultsHelpFormatter, which sees %(default)s and adds nothing)
    p.add_argument(flag, type=size, default=f"{default[0]}x{default[1]}", metavar="WxH",
                   help=f"{help} (default: %(default)s)")
    if old_cols_rows:
        for index, name in enumerate(("--cols", "--rows")):
            p.add_argument(name, dest=f"_deprecated_{name[2:]}", action=_SizePart,
                           index=index, size_dest=dest, type=int_range(1, MAX_SIDE),
                           help=argparse.SUPPRESS)


_ROLE = re.compile(r":[a-z]+(?::[a-z]+)?:`~?([^`<]*?)(?:\s*<[^>]*>)?`")
_LITERAL = re.compile(r"``(.+?)``", re.DOTALL)
_EMPHASIS = re.compile(r"(?<![\w*])(\*{1,2})(\S(?:[^*\n]*?\S)?)\1(?![\w*])")


def plain_help(text: str | None) -> str:
    """A docstring's reStructuredText markup removed, for ``--help``.

    A role such as ``:func:`name``` becomes ``name`` (with ``~`` only the last dotted
    part), double backquotes and ``*emphasis*`` stars are dropped, and a line ending
    ``::`` keeps one colon.
    """
    if not text:
        return ""
    out = _ROLE.sub(lambda m: m.group(1).rsplit(".", 1)[-1] if "~" in m.group(0)
                    else m.group(1), text)
    out = _LITERAL.sub(r"\1", out)
    out = _EMPHASIS.sub(r"\2", out)
    return re.sub(r"(\w)::$", r"\1:", out, flags=re.MULTILINE)


def exit_rule_epilog(failed: str | None = None) -> str:
    """The exit rule for an ``--help`` epilog, wrapped to 79 columns.

    Wrapped here so that it reads the same under argparse's raw formatters (which
    keep an epilog's lines as they are) as under the default one.

    Parameters
    ----------
    failed : str or None
        What exit status 1 means for this command (``"a frame went over its
        budget."``), or None where the command has no status 1.

    Returns
    -------
    str
        ``service.base.signals.EXIT_RULE``, then ``" 1: FAILED"`` when given.
    """
    text = EXIT_RULE if failed is None else f"{EXIT_RULE} 1: {failed}"
    return textwrap.fill(text, width=79)


def output_problem(path: str, *, folder: bool = False) -> str | None:
    """Why ``path`` cannot be written as an output, or None when it can.

    Checked before a command starts its work, so a typo in ``--out`` costs a one-line
    error (status 2) rather than a render or a build thrown away at the end.

    Parameters
    ----------
    path : str
        The output file (``folder=False``) or the output folder (``folder=True``, made
        with its parents if missing).
    folder : bool
        Whether ``path`` names a folder.

    Returns
    -------
    str or None
        ``"PATH: ..."`` saying what is wrong, or None.
    """
    target = os.path.abspath(path)
    if folder and os.path.exists(target) and not os.path.isdir(target):
        return f"{path}: is a file, not a folder"
    if not folder and os.path.isdir(target):
        return f"{path}: is a folder, not a file"
    # the nearest part of the path that exists must be a folder we may write in
    parent = target if folder else os.path.dirname(target)
    if not folder and not os.path.exists(parent):
        return f"{path}: no folder {os.path.dirname(path)} (make it first)"
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        return f"{path}: {parent} is a file, not a folder"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"{path}: cannot write in {parent} (permission denied)"
    return None


def os_error_text(exc: OSError) -> str:
    """``PATH: REASON`` for an OSError (``str(exc)`` reads ``[Errno 2] ...: 'PATH'``)."""
    if exc.filename is not None and exc.strerror:
        return f"{exc.filename}: {exc.strerror}"
    return exc.strerror or str(exc)
