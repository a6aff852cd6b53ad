"""``holo-up CONFIG.toml``: start the render service, devices and simulators from one file.

As a VRPN server's config names every device a server runs, one TOML file names what
to start; ``holo-up`` starts each in order, wires the addresses between them and
prints where each listens::

    holo-up examples/holo-up.toml
    holo-up examples/holo-up.toml --dry-run     # check the file, print the commands

Tables (each optional; at least one):

- ``[sim.tracker]``, ``[sim.dials]``: ``holo-sim tracker`` / ``holo-sim dials`` on a
  pty (or ``tcp = PORT``; the tracker also ``udp = "HOST:PORT"``, opentrack's UDP
  poses); the path or URL each prints is what ``holo-devices`` opens.
- ``[devices]``: ``holo-devices``.  ``tracker`` / ``dials`` name real ports; left
  out, the simulator of the same name is used.  It always publishes: ``pub``
  (default ``tcp://127.0.0.1:5560``).
- ``[service]``: ``holo-service``, whose ``devices`` is the publisher above unless
  given.
- ``[up]``: ``start_timeout`` (seconds each program has to say it is ready,
  default 120).

Every other key is that program's option: ``key = value`` is ``--key value`` (``_``
for ``-``), ``true`` a bare flag, a list repeats the option, and ``args = [...]``
is passed as it is.  Everything is checked by the programs' own option parsers
before anything starts; relative paths are relative to the current directory.

Each program's output lines are copied to stderr, prefixed with its name; stdout
has ``holo-up``'s own lines: where each program listens, then ``holo-up: running``.
Ctrl-C or SIGTERM stops them all, the last started first, and exits 130 / 143 (the
rule of :mod:`service.base.signals`; SIGHUP, the terminal closing, 129): each program runs
in a process group of its own, so a Ctrl-C at the terminal reaches ``holo-up`` alone;
a program that fails or exits on its own stops the others too (exit status 1, naming
it and its last lines); a bad file is exit status 2 with one line naming the file and
the table.
"""

from __future__ import annotations

import argparse
import importlib
import os
import shlex
import signal
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from service.base.addresses import default_address
from service.base.cli_args import plain_help
from service.base.errors import HoloError, SettingsError
from service.base.signals import (
    EXIT_FAILED,
    EXIT_OK,
    EXIT_RULE,
    EXIT_USAGE,
    STOP_SIGNALS,
    end_process,
    exit_status,
    stop_on_signals,
)

#: Table -> (module run with ``python -m``, its parser's module, fixed arguments), in
#: start order: simulators, then the driver reading them, then the service using it.
PROGRAMS: dict[str, tuple[str, tuple[str, ...]]] = {
    "sim.tracker": ("sim_devices.commands.holo_sim", ("tracker",)),
    "sim.dials": ("sim_devices.commands.holo_sim", ("dials",)),
    "devices": ("drivers.commands.holo_devices", ()),
    "service": ("service.commands.holo_service", ()),
}
NAMES = {"sim.tracker": "holo-sim tracker", "sim.dials": "holo-sim dials",
         "devices": "holo-devices", "service": "holo-service"}
#: Keys holo-up fills in itself, by table -> (key, the table whose address it takes).
WIRED = {"devices": (("tracker", "sim.tracker"), ("dials", "sim.dials")),
         "service": (("devices", "devices"),)}
START_TIMEOUT_S = 120.0
#: Lines of a failed program shown in the error.
TAIL = 6


class ConfigError(SettingsError):
    """The config file is unreadable or names something the programs refuse."""


@dataclass
class Part:
    """One program to start.

    Attributes
    ----------
    table : str
        Its config table (``"devices"``...).
    argv : list of str
        Its options from the file (wired addresses are added at start).
    wired : dict
        Option -> table whose address fills it at start.
    """

    table: str
    argv: list[str]
    wired: dict[str, str] = field(default_factory=dict)

    @property
    def name(self) -> str:
        """``holo-devices``, ``holo-sim tracker``..."""
        return NAMES[self.table]

    def command(self, addresses: dict[str, str]) -> list[str]:
        """The command line, with the wired options from ``addresses``."""
        module, fixed = PROGRAMS[self.table]
        wired = [a for opt, t in self.wired.items() for a in (f"--{opt}", addresses[t])]
        return [sys.executable, "-m", module, *fixed, *self.argv, *wired]


def load_config(path: Path) -> dict[str, Any]:
    """The TOML file as a dict; :class:`ConfigError` naming the file (and line) if bad."""
    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:  # TOML is UTF-8; tomllib lets this one through
        raise ConfigError(f"{path}: not valid TOML: not UTF-8 text (byte {exc.start})") from None
    known = {"sim", "devices", "service", "up"}
    for key, value in doc.items():
        if key not in known or not isinstance(value, dict):
            raise ConfigError(f"{path}: unknown table [{key}]; known: [sim.tracker], "
                              "[sim.dials], [devices], [service], [up]")
    for key, value in doc.get("sim", {}).items():
        if key not in ("tracker", "dials") or not isinstance(value, dict):
            raise ConfigError(f"{path}: unknown table [sim.{key}]; known: [sim.tracker], "
                              "[sim.dials]")
    return doc


def options(where: str, table: dict[str, Any]) -> list[str]:
    """A table's keys as command-line options (see the module docstring)."""
    argv: list[str] = []
    for key, value in table.items():
        if key == "args":
            if not (isinstance(value, list) and all(isinstance(a, str) for a in value)):
                raise ConfigError(f"{where}: args must be a list of strings")
            continue
        flag = "--" + key.replace("_", "-")
        for item in value if isinstance(value, list) else [value]:
            if isinstance(item, bool):
                argv += [flag] if item else []
            elif isinstance(item, str | int | float):
                argv += [flag, str(item)]
            else:
                raise ConfigError(f"{where}: {key} = {item!r}: want a string, number, "
                                  "true/false or a list of them")
    return argv + list(table.get("args", []))


def tables(doc: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Config tables by name, in start order (only those present)."""
    flat = {f"sim.{k}": v for k, v in doc.get("sim", {}).items()}
    flat.update({k: doc[k] for k in ("devices", "service") if k in doc})
    return {t: flat[t] for t in PROGRAMS if t in flat}


def plan(doc: dict[str, Any], path: Path) -> list[Part]:
    """The programs to start, checked by their own parsers; :class:`ConfigError` if bad."""
    present = tables(doc)
    if not present:
        raise ConfigError(f"{path}: nothing to start; give [sim.tracker], [sim.dials], "
                          "[devices] and/or [service]")
    parts = []
    for table, body in present.items():
        where = f"{path} [{table}]"
        part = Part(table, options(where, body))
        for key, source in WIRED.get(table, ()):
            if source in present and key in body:
                raise ConfigError(f"{where}: give {key} or [{source}], not both")
            if source in present:
                part.wired[key] = source
        if table == "devices":
            part.argv += _devices_defaults(body, present)
        if table.startswith("sim.") and "tcp" not in body and "udp" not in body:
            part.argv += ["--pty"]
        check_options(part, where)
        parts.append(part)
    return parts


def _devices_defaults(body: dict[str, Any], present: dict[str, dict[str, Any]]) -> list[str]:
    """holo-devices always publishes, and reads a simulated tracker in its protocol."""
    out = [] if "pub" in body else ["--pub", default_address("devices")]
    sim_protocol = present.get("sim.tracker", {}).get("protocol")
    if sim_protocol is not None and "tracker_protocol" not in body:
        out += ["--tracker-protocol", str(sim_protocol)]
    return out


def check_options(part: Part, where: str) -> None:
    """Parse the part's command line with its program's own parser (nothing runs)."""
    module, fixed = PROGRAMS[part.table]
    parser: argparse.ArgumentParser = importlib.import_module(module).build_parser()

    def refuse(message: str) -> None:
        raise ConfigError(f"{where}: {part.name}: {message}")

    parser.error = refuse  # type: ignore[method-assign]  # raise instead of exiting
    placeholders = dict.fromkeys(part.wired.values(), "tcp://127.0.0.1:1")
    args = parser.parse_args(part.command(placeholders)[3:])
    if part.table == "devices" and not (args.tracker or args.dials):
        refuse("give tracker and/or dials, or a [sim.tracker] / [sim.dials] table")


#: Each program in a process group of its own (POSIX).  A Ctrl-C at the terminal
#: goes to the whole foreground group at once: the simulators then ended before
#: holo-devices, which reported them disconnected, and the tracker never got its stop
#: command.  Now holo-up alone gets it and stops them in order, the last started first.
OWN_GROUP: dict[str, int] = {"process_group": 0} if os.name == "posix" else {}

#: What stops holo-up: SIGINT, SIGTERM and, where there is one, SIGHUP (the terminal
#: closed), which the programs, in their own groups, no longer get themselves.
UP_SIGNALS: tuple[int, ...] = STOP_SIGNALS + ((signal.SIGHUP,) if hasattr(signal, "SIGHUP")
                                              else ())


class Child:
    """A started program whose output lines are kept and copied to stderr.

    Parameters
    ----------
    part : Part
    command : list of str
    """

    def __init__(self, part: Part, command: list[str]) -> None:
        self.part = part
        self.lines: dict[str, list[str]] = {"out": [], "err": []}
        self.p = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  stdin=subprocess.DEVNULL, text=True, bufsize=1,
                                  **OWN_GROUP)
        self.threads = [threading.Thread(target=self._pump, args=(s, k), daemon=True)
                        for s, k in ((self.p.stdout, "out"), (self.p.stderr, "err"))]
        for t in self.threads:
            t.start()

    def _pump(self, stream: Any, key: str) -> None:
        for line in stream:
            line = line.rstrip("\n")
            self.lines[key].append(line)
            with _ECHO_LOCK:
                sys.stderr.write(f"[{self.part.name}] {line}\n")
                sys.stderr.flush()

    def tail(self) -> str:
        """Its last stderr lines, for an error message."""
        return " | ".join(self.lines["err"][-TAIL:]) or "(no output)"

    def stop(self) -> None:
        """Terminate (kill if it does not go), then let the output threads finish."""
        end_process(self.p)
        for t in self.threads:
            t.join(5.0)


_ECHO_LOCK = threading.Lock()


def _first(lines: list[str], pred: Callable[[str], bool]) -> str | None:
    return next((ln for ln in list(lines) if pred(ln)), None)


def _after(prefix: str) -> Callable[[str], str]:
    return lambda line: line.split(prefix, 1)[1].strip()


def _service_where(line: str) -> str:
    """``control ADDR frames ADDR`` from holo-service's first line."""
    return " ".join(line.split()[1:5])


#: Table -> (stream, test of the ready line, its address, where it listens in words).
READY: dict[str, tuple[str, Callable[[str], bool], Callable[[str], str],
                       Callable[[str], str]]] = {
    "sim.tracker": ("out", bool, str.strip, lambda ln: f"on {ln.strip()}"),
    "sim.dials": ("out", bool, str.strip, lambda ln: f"on {ln.strip()}"),
    "devices": ("err", lambda ln: "publishing on " in ln,
                lambda ln: _after("publishing on ")(ln).split()[0], _after("holo-devices: ")),
    "service": ("err", lambda ln: ln.startswith("holo-service: control"),
                lambda ln: ln.split()[2], _service_where),
}


class StartError(HoloError):
    """A program exited or stayed silent while starting, or failed later."""


class Launcher:
    """Start the parts in order, watch them, stop them all.

    Parameters
    ----------
    parts : list of Part
    start_timeout_s : float
        How long each program has to print its ready line.
    """

    def __init__(self, parts: list[Part], start_timeout_s: float = START_TIMEOUT_S) -> None:
        self.parts = parts
        self.start_timeout_s = start_timeout_s
        self.stop = threading.Event()
        self.children: list[Child] = []
        self.addresses: dict[str, str] = {}

    def start_all(self) -> bool:
        """Start each part once the one before it is ready; print where each listens.

        Returns False if a stop came meanwhile.
        """
        for part in self.parts:
            child = Child(part, part.command(self.addresses))
            self.children.append(child)
            line = self._wait_ready(child)
            if self.stop.is_set():
                return False
            _, _, address, where = READY[part.table]
            self.addresses[part.table] = address(line)
            print(f"holo-up: {part.name} {where(line)}", flush=True)
        return True

    def _wait_ready(self, child: Child) -> str:
        """The program's ready line ("" if a stop came first)."""
        stream, ready, _, _ = READY[child.part.table]
        deadline = time.monotonic() + self.start_timeout_s
        while not self.stop.is_set():
            line = _first(child.lines[stream], ready)
            if line is not None:
                return line
            if child.p.poll() is not None:
                raise StartError(f"{child.part.name} exited {child.p.returncode} while "
                                 f"starting: {child.tail()}")
            if time.monotonic() > deadline:
                raise StartError(f"{child.part.name} not ready within "
                                 f"{self.start_timeout_s:g} s: {child.tail()}")
            self.stop.wait(0.02)
        return ""

    def watch(self) -> None:
        """Return when stopped; raise :class:`StartError` when a program exits on its own."""
        while not self.stop.wait(0.1):
            for child in self.children:
                if child.p.poll() is not None and not self._stopped_meanwhile():
                    raise StartError(f"{child.part.name} exited {child.p.returncode}: "
                                     f"{child.tail()}")

    def _stopped_meanwhile(self) -> bool:
        """A Ctrl-C reaches the programs too; give our own stop a moment to be seen."""
        return self.stop.wait(0.5)

    def stop_all(self) -> None:
        """Stop every program, the last started first."""
        for child in reversed(self.children):
            child.stop()


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (also used for ``--help``)."""
    p = argparse.ArgumentParser(
        prog="holo-up",
        description="Start holo-service, simulated devices and holo-devices from one TOML "
        "file, wired together; Ctrl-C stops them all.",
        epilog=plain_help("The file's tables: [sim.tracker], [sim.dials], [devices], "
                          "[service], [up] (see examples/holo-up.toml and "
                          "docs/command-line.md). " + EXIT_RULE
                          + " 1: a program failed or exited on its own."))
    p.add_argument("config", type=Path, metavar="CONFIG", help="the TOML file")
    p.add_argument("--dry-run", action="store_true",
                   help="check the file and print the command lines; start nothing")
    return p


def prepare(path: Path) -> tuple[list[Part], float]:
    """Load and check a config file: the parts and the start timeout."""
    doc = load_config(path)
    timeout = doc.get("up", {}).get("start_timeout", START_TIMEOUT_S)
    extra = set(doc.get("up", {})) - {"start_timeout"}
    if extra:
        raise ConfigError(f"{path} [up]: unknown key {sorted(extra)[0]!r}; known: "
                          "start_timeout")
    if isinstance(timeout, bool) or not isinstance(timeout, int | float) or timeout <= 0:
        raise ConfigError(f"{path} [up]: start_timeout must be a number > 0, not {timeout!r}")
    return plan(doc, path), float(timeout)


def dry_run(parts: list[Part]) -> None:
    """Print each command line, wired addresses as ``<TABLE address>``."""
    shown = {t: f"<{NAMES[t]} address>" for t in PROGRAMS}
    for part in parts:
        cmd = part.command(shown)
        print(f"holo-up: {part.name}: {shlex.join(['python', *cmd[1:]])}")


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``holo-up``; returns the exit status (see the module docstring)."""
    args = build_parser().parse_args(argv)
    try:
        parts, timeout = prepare(args.config)
    except ConfigError as exc:
        print(f"holo-up: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if args.dry_run:
        dry_run(parts)
        return EXIT_OK
    launcher = Launcher(parts, timeout)
    status = EXIT_OK
    with stop_on_signals(launcher.stop, UP_SIGNALS) as got:
        try:
            if launcher.start_all():
                print("holo-up: running; Ctrl-C stops everything", flush=True)
                launcher.watch()
        except StartError as exc:
            status = EXIT_FAILED
            if not launcher.stop.is_set():
                print(f"holo-up: {exc}; stopping the others", file=sys.stderr, flush=True)
        finally:
            launcher.stop_all()
    return exit_status(got.signum, status)


if __name__ == "__main__":
    sys.exit(main())
