"""``holo-service --help``: every option's default is shown."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest
from testkit import ROOT

from service.commands.holo_service import build_parser


def _help_entries() -> dict[str, str]:
    """``holo-service --help`` run as a command: option -> its entry, lines joined."""
    script = Path(sys.executable).with_name("holo-service")
    cmd = [str(script)] if script.exists() else [sys.executable, "-m",
                                                 "service.commands.holo_service"]
    out = subprocess.run(
        [*cmd, "--help"], cwd=ROOT, capture_output=True, text=True, timeout=60, check=True
    ).stdout
    entries: dict[str, str] = {}
    current = None
    for line in out.split("options:", 1)[1].splitlines():
        if line.startswith("  -"):
            current = line.split()[0].rstrip(",")
            entries[current] = ""
        if current is not None:
            entries[current] += " " + " ".join(line.split())
    return entries


def test_help_shows_the_default_addresses_and_refresh_rate():
    entries = _help_entries()
    assert "(default: tcp://127.0.0.1:5555)" in entries["--control"]
    assert "(default: tcp://127.0.0.1:5556)" in entries["--frames"]
    assert "(default: 60" in entries["--refresh"]
    assert "default: tcp://127.0.0.1:5557" in entries["--worker-address"]


def test_help_shows_every_default():
    entries = _help_entries()
    for action in build_parser()._actions:
        if action.default is argparse.SUPPRESS or action.help is argparse.SUPPRESS:
            continue  # --help itself, and the hidden --cols/--rows aliases of --size
        option = action.option_strings[0]
        if action.nargs == 0:  # a flag: its help says what it does, "default: True" would not
            assert "default:" not in entries[option], entries[option]
            continue
        # a None default is explained in words ("default: none", or what happens)
        shown = "default:" if action.default is None else f"default: {action.default}"
        assert shown in entries[option], f"{option}: {shown!r} not in {entries[option]!r}"


def test_bad_settings_are_refused_before_the_service_says_it_runs():
    """``--refresh 0`` and friends: one error line, exit 2, no ready line, no traceback."""
    for bad in (["--refresh", "0"], ["--refresh", "-1"], ["--render-timeout", "0"],
                ["--workers", "-1"], ["--scene", "nosuch"]):
        out = subprocess.run(
            [sys.executable, "-m", "service.commands.holo_service", "--control", "tcp://127.0.0.1:0",
             "--frames", "tcp://127.0.0.1:0", *bad],
            cwd=ROOT, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert out.returncode == 2, (bad, out.stderr)
        assert "Traceback" not in out.stderr and "control tcp" not in out.stderr, out.stderr
        assert bad[0] in out.stderr or bad[1] in out.stderr, out.stderr
        errors = [ln for ln in out.stderr.splitlines() if not ln.startswith(("usage", " "))]
        assert len(errors) == 1, out.stderr


def test_a_bad_setting_from_python_is_refused_before_any_socket():
    from service.base.errors import SettingsError
    from service.net.server import Service
    from service.net.state import ServiceConfig

    with pytest.raises(SettingsError, match="refresh_hz"):
        Service(ServiceConfig(control="tcp://127.0.0.1:0", frames="tcp://127.0.0.1:0",
                              refresh_hz=0.0))
