"""PtyLink's drain: a run that ends by itself must not close the pty on unread bytes."""

from __future__ import annotations

import os
import sys
import threading
import time

import pytest

from drivers.pty_link import PtyLink

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pty pairs need POSIX")


def test_bytes_in_transit_count_as_unread():
    # right after a write the kernel often still holds the bytes in the pty's work
    # queue (FIONREAD on the client's side says 0); closing then would lose them
    link = PtyLink()
    client = os.open(link.name, os.O_RDWR | os.O_NOCTTY)
    try:
        for n in range(500):
            link.write(bytes([n % 256]) * 40)
            assert link.unread(), f"write {n}: bytes in transit looked read"
            got = b""
            while len(got) < 40:
                got += os.read(client, 40 - len(got))
            assert not link.unread()
    finally:
        os.close(client)
        link.close()


def test_drain_waits_for_the_reader_and_returns_once_it_has_read_all():
    link = PtyLink()
    client = os.open(link.name, os.O_RDWR | os.O_NOCTTY)
    try:
        link.write(b"x" * 3000)
        start = time.monotonic()
        link.drain(timeout=0.2)  # nobody reads: the drain gives up at its deadline only
        assert time.monotonic() - start >= 0.2 and link.unread()
        got = bytearray()

        def read_all():
            while len(got) < 3000:
                got.extend(os.read(client, 4096))

        reader = threading.Thread(target=read_all, daemon=True)
        reader.start()
        link.drain(timeout=60)  # hang guard only
        reader.join(timeout=60)
        assert bytes(got) == b"x" * 3000 and not link.unread()
    finally:
        os.close(client)
        link.close()


def test_drain_gives_up_at_once_when_stopped():
    stop = threading.Event()
    link = PtyLink(stop=stop)
    try:
        link.write(b"y" * 100)
        stop.set()
        start = time.monotonic()
        link.drain(timeout=60)
        assert time.monotonic() - start < 30 and link.unread()
    finally:
        link.close()
