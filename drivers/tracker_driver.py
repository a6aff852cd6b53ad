"""Head tracker driver: the host's start, stop and reset commands.

:class:`TrackerDriver` plugs into a :class:`~drivers.reader.DeviceReader` as its
hooks.  Each time the port opens (the first time, after a read error and after a
watchdog reopen) it sends the start command, optionally preceded by the reset
command; on a clean stop it sends the stop command before the port closes.  A
device that streams unasked ignores the commands (opentrack's Hatire sketches
mostly do); one that waits for a start (``holo-sim tracker --wait-start``, sketches
that wait for a character) needs them, and a device plugged back in waits again.

Commands per protocol:

* ``hatire``: single bytes, configurable (:class:`~drivers.protocols.hatire.HatireCommands`;
  defaults ``S`` start, ``s`` stop, ``R`` reset);
* ``native``: command frames (type ``0x10`` start, ``0x11`` stop, ``0x12`` reset;
  ``docs/native-protocol.md``);
* ``opentrack``: none (its UDP output streams unasked and takes no commands), so
  the hooks send nothing.

The commands are host-to-device bytes only: they are not recorded in a session log
and give no event.
"""

from __future__ import annotations

import argparse

import serial

from drivers.events import Event
from drivers.protocols import hatire, native
from drivers.reader import DeviceReader, canonical_protocol
from service.base.errors import SettingsError

COMMAND_NAMES = ("start", "stop", "reset")


def command_byte(text: str) -> bytes:
    """A command byte as given on a command line: one character, or ``0xNN``.

    Raises
    ------
    SettingsError
        Anything else (an argparse ``type=`` reports it as a usage error).
    """
    if len(text) == 1 and ord(text) < 256:
        return text.encode("latin-1")
    if text.lower().startswith("0x") and len(text) == 4:
        try:
            return bytes((int(text, 16),))
        except ValueError:
            pass
    raise SettingsError(f"a command is one character or 0xNN, not {text!r}")


def add_command_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--hatire-start C``, ``--hatire-stop C`` and ``--hatire-reset C``.

    Defaults are :class:`~drivers.protocols.hatire.HatireCommands`'; read the
    parsed values back with :func:`commands_from_args`.
    """
    defaults = hatire.HatireCommands()
    for name in COMMAND_NAMES:
        default = getattr(defaults, name)
        parser.add_argument(f"--hatire-{name}", type=command_byte, default=default,
                            metavar="C", help=f"Hatire {name} command: one character or "
                            f"0xNN (default: {default.decode('latin-1')})")


def commands_from_args(args: argparse.Namespace) -> hatire.HatireCommands:
    """The Hatire commands given by :func:`add_command_options`' options."""
    return hatire.HatireCommands(*(getattr(args, f"hatire_{n}") for n in COMMAND_NAMES))


class TrackerDriver:
    """Hooks for a tracker reader (see the module docstring).

    Parameters
    ----------
    protocol : {"hatire", "native", "opentrack"}
        The tracker's byte protocol (opentrack: no commands are sent).
    commands : HatireCommands or None
        Hatire command bytes (default ``S`` / ``s`` / ``R``); ignored for native.
    reset_on_open : bool
        Send the reset command before the start command on every open.

    Attributes
    ----------
    sent : dict of str to int
        How many times each command was written.
    """

    def __init__(self, protocol: str = "hatire", commands: hatire.HatireCommands | None = None,
                 reset_on_open: bool = False) -> None:
        self.protocol = canonical_protocol(protocol)
        if self.protocol not in ("hatire", "native", "opentrack"):
            raise SettingsError(f"not a tracker protocol: {protocol!r}")
        self.commands = commands or hatire.HatireCommands()
        self.reset_on_open = reset_on_open
        self.sent = dict.fromkeys(COMMAND_NAMES, 0)

    def command(self, name: str) -> bytes:
        """The bytes of command ``name`` (``"start"``, ``"stop"`` or ``"reset"``)."""
        if self.protocol == "hatire":
            return hatire.encode_command(name, self.commands)
        return native.encode_command(name)

    # -- hooks (reader thread) ------------------------------------------------------
    def on_open(self, reader: DeviceReader) -> None:
        """Ask the freshly opened device to stream (reset first if configured).

        Raises
        ------
        serial.SerialException
            A write failed (the reader then treats the device as lost).
        """
        if self.protocol == "opentrack":
            return
        if self.reset_on_open:
            self.send(reader, "reset")
        self.send(reader, "start")

    def on_events(self, reader: DeviceReader, events: list[Event]) -> None:
        """Nothing to react to."""

    def on_stop(self, reader: DeviceReader) -> None:
        """Clean stop: ask the device to stop streaming (best effort)."""
        if self.protocol != "opentrack":
            self.send(reader, "stop")

    def send(self, reader: DeviceReader, name: str) -> None:
        """Write command ``name`` to ``reader``'s port.

        Raises
        ------
        serial.SerialException
            The port is closed or the write failed.
        """
        if not reader.write(self.command(name)):
            raise serial.SerialException(f"tracker {name} command could not be written")
        self.sent[name] += 1
