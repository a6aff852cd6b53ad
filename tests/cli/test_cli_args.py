"""Shared command-line pieces: argparse types, sizes and their old spellings, addresses,
scene names, default ports that do not collide, plain help text."""

from __future__ import annotations

import argparse

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.commands import holo_devices as cli_devices
from drivers.commands import holo_replay as cli_replay
from drivers.commands import holo_view as cli_view
from drivers.publisher import Publisher
from service.base.addresses import DEFAULT_PORTS, check_endpoint, default_address
from service.base.cli_args import (
    add_size_option,
    comma_list,
    endpoint,
    float_range,
    int_range,
    plain_help,
    size,
)
from service.base.errors import SettingsError
from service.builtin_scenes import SCENES, builtin_scene, canonical_scene_name, scene_name
from service.commands import holo_service as cli_service
from service.net.state import DEFAULT_WORKER_ADDRESS


@given(st.integers(1, 8192), st.integers(1, 8192))
def test_size_reads_every_valid_wxh(w, h):
    assert size(f"{w}x{h}") == (w, h) and size(f" {w}X{h} ") == (w, h)


@pytest.mark.parametrize("text", ["abc", "320", "320x", "x240", "0x240", "320x0", "9000x10",
                                  "-1x5", "3.5x4", "320*240", ""])
def test_size_refuses_the_rest(text):
    with pytest.raises(argparse.ArgumentTypeError):
        size(text)


def test_number_types_name_the_bound():
    assert int_range(1, 64)("64") == 64 and int_range(0)("0xff") == 255
    with pytest.raises(argparse.ArgumentTypeError, match="from 1 to 64"):
        int_range(1, 64)("0")
    with pytest.raises(argparse.ArgumentTypeError, match="integer"):
        int_range(1)("two")
    assert float_range(0, lo_open=True)("0.5") == 0.5
    for bad in ("0", "-1", "nan", "inf", "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            float_range(0, lo_open=True)(bad)
    assert comma_list(int_range(1, 64))("1, 5,9") == [1, 5, 9]
    for bad in ("1,,5", "", "1,1", "1,0"):
        with pytest.raises(argparse.ArgumentTypeError):
            comma_list(int_range(1, 64))(bad)


def _size_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="tool")
    add_size_option(p, (160, 120), "pixels per zone", old_cols_rows=True)
    return p


def test_size_option_keeps_cols_and_rows_as_hidden_deprecated_aliases(capsys):
    p = _size_parser()
    assert p.parse_args([]).size == (160, 120)
    assert p.parse_args(["--size", "64x48"]).size == (64, 48)
    assert capsys.readouterr().err == ""
    assert p.parse_args(["--cols", "32", "--rows", "24"]).size == (32, 24)
    err = capsys.readouterr().err
    assert "--cols is deprecated; use --size WxH" in err and "--rows is deprecated" in err
    assert p.parse_args(["--rows", "24"]).size == (160, 24)
    assert p.parse_args(["--cols", "32", "--size", "64x48"]).size == (64, 48)  # later wins
    assert p.parse_args(["--size", "64x48", "--cols", "32"]).size == (32, 48)
    help_text = p.format_help()
    assert "--size WxH" in help_text and "--cols" not in help_text and "--rows" not in help_text


@pytest.mark.parametrize("argv", [["--cols", "0"], ["--rows", "x"], ["--size", "abc"]])
def test_size_option_errors_are_usage_errors(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        _size_parser().parse_args(argv)
    assert exc.value.code == 2 and "error: argument" in capsys.readouterr().err


@given(st.integers(1, 65535))
def test_every_real_port_is_an_address(port):
    for bind in (True, False):
        assert check_endpoint(f"tcp://127.0.0.1:{port}", bind) == f"tcp://127.0.0.1:{port}"


@given(st.integers(65536, 10**7))
def test_ports_past_65535_are_refused(port):
    # libzmq would silently bind port % 65536
    with pytest.raises(SettingsError, match="1-65535"):
        check_endpoint(f"tcp://127.0.0.1:{port}")


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:0", "tcp://*:*", "tcp://127.0.0.1:*",
                                     "tcp://[::1]:5560", "ipc:///tmp/holo.sock",
                                     "inproc://devices", "tcp://eth0:5560"])
def test_bind_addresses(address):
    assert check_endpoint(address, bind=True) == address


@pytest.mark.parametrize(("address", "bind", "why"), [
    ("tcp://127.0.0.1:99999", True, "not a port number"),
    ("tcp://127.0.0.1:0", False, "not a port number"),  # nothing to connect to
    ("tcp://127.0.0.1:*", False, "not a port number"),
    ("tcp://127.0.0.1", True, "HOST:PORT"),
    ("tcp://:5560", True, "HOST:PORT"),
    ("127.0.0.1:5560", True, "not a ZeroMQ address"),
    ("udpx://a:1", True, "unknown transport"),
    ("ipc://", True, "needs a name"),
    ("tcp://h:５５６０", True, "not a port number"),  # full-width digits
])
def test_bad_addresses_are_named(address, bind, why):
    with pytest.raises(SettingsError, match=why):
        check_endpoint(address, bind)
    with pytest.raises(argparse.ArgumentTypeError, match=why):
        endpoint(bind)(address)


def test_pub_with_a_port_past_65535_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        cli_devices.main(["--tracker", "loop://", "--pub", "tcp://127.0.0.1:99999"])
    assert exc.value.code == 2
    assert "--pub: 'tcp://127.0.0.1:99999': port '99999'" in capsys.readouterr().err


def test_the_publisher_itself_refuses_a_bad_port():
    with pytest.raises(SettingsError):
        Publisher("tcp://127.0.0.1:99999")
    with pytest.raises(SettingsError):
        Publisher("tcp://127.0.0.1:0", pose_address="tcp://127.0.0.1:70000")


def test_default_ports_of_every_command_do_not_collide():
    service = cli_service.build_parser().parse_args([])
    devices = cli_devices.build_parser().parse_args(["--tracker", "x", "--pub", "--pub-pose"])
    replay = cli_replay.build_parser().parse_args(["f", "--pub", "--pub-pose"])
    view = cli_view.build_parser().parse_args([])
    assert (devices.pub, devices.pub_pose) == (default_address("devices"),
                                              default_address("pose"))
    # holo-replay stands in for holo-devices, so it uses the same ports
    assert (replay.pub, replay.pub_pose) == (devices.pub, devices.pub_pose)
    assert view.address == devices.pub
    bound = [service.control, service.frames, DEFAULT_WORKER_ADDRESS, devices.pub,
             devices.pub_pose]
    assert len(set(bound)) == len(bound) == len(set(DEFAULT_PORTS.values()))
    assert {int(a.rsplit(":", 1)[1]) for a in bound} == set(DEFAULT_PORTS.values())


def test_pub_pose_needs_pub(capsys):
    for main, argv in ((cli_devices.main, ["--tracker", "loop://"]),
                       (cli_replay.main, ["x.hlog"])):
        with pytest.raises(SystemExit) as exc:
            main([*argv, "--pub-pose", "tcp://127.0.0.1:0"])
        assert exc.value.code == 2 and "--pub-pose needs --pub" in capsys.readouterr().err


@pytest.mark.parametrize("spelling", ["sphere-torus", "sphere_torus", "Sphere_Torus"])
def test_scene_names_take_underscores_for_hyphens(spelling):
    assert canonical_scene_name(spelling) == "sphere-torus" == scene_name(spelling)
    scene = builtin_scene(spelling)
    assert [o.name for o in scene.objects] == ["sphere", "torus"]


def test_unknown_scene_lists_the_canonical_names():
    with pytest.raises(SettingsError, match="known: game, sphere-torus"):
        builtin_scene("nosuch")
    with pytest.raises(argparse.ArgumentTypeError, match="unknown scene 'nosuch'"):
        scene_name("nosuch")
    assert all("_" not in name for name in SCENES)  # one canonical spelling


def test_plain_help_drops_the_markup():
    text = ("``holo-bench galilean``: see :func:`thought_case` and :class:`~a.b.Stage`,\n"
            "an *extrapolated* refresh, 3*4 and **kwargs.\nExamples::\n")
    assert plain_help(text) == ("holo-bench galilean: see thought_case and Stage,\n"
                                "an extrapolated refresh, 3*4 and **kwargs.\nExamples:\n")
    assert plain_help(None) == ""


def test_size_default_reads_as_wxh_in_help_under_every_formatter(capsys):
    for formatter in (argparse.HelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
        p = argparse.ArgumentParser(prog="tool", formatter_class=formatter)
        add_size_option(p, (160, 120), "pixels per zone", old_cols_rows=True)
        text = " ".join(p.format_help().split())
        assert "pixels per zone (default: 160x120)" in text and "(160, 120)" not in text
        assert p.parse_args([]).size == (160, 120)
        assert p.parse_args(["--rows", "24"]).size == (160, 24)  # from the default
