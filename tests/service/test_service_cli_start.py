"""holo-service's main when the service cannot start: one line, exit 2, nothing bound."""

from __future__ import annotations

import zmq

from service.base.signals import EXIT_USAGE
from service.commands.holo_service import main


def test_a_display_too_large_is_one_line_and_exit_2(capsys):
    rc = main(["--control", "tcp://127.0.0.1:0", "--frames", "tcp://127.0.0.1:0",
               "--no-warmup", "--zones", "64", "--size", "4000x4000"])
    err = capsys.readouterr().err
    assert rc == EXIT_USAGE
    assert err == "holo-service: 64 zones of 4000x4000 are 1,024,000,000 pixels " \
                  "(at most 67,108,864)\n"


def test_an_address_in_use_is_one_line_and_exit_2(capsys):
    ctx = zmq.Context.instance()
    taken = ctx.socket(zmq.REP)
    try:
        port = taken.bind_to_random_port("tcp://127.0.0.1")
        rc = main(["--control", f"tcp://127.0.0.1:{port}", "--frames", "tcp://127.0.0.1:0",
                   "--no-warmup"])
    finally:
        taken.close(linger=0)
    err = capsys.readouterr().err
    assert rc == EXIT_USAGE and err.count("\n") == 1
    assert err.startswith("holo-service: cannot bind: ") and "another holo-service" in err
