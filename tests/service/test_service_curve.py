"""CurveZMQ: documented key command, keyed clients served, keyless ones not, no open bind."""

from __future__ import annotations

import subprocess
import sys

from testkit import ROOT, free_port, launch_service, raw_request, wait_until

from service.net.client import FrameSubscriber, ServiceClient


def test_make_keys_and_curve_service(tmp_path):
    keys = tmp_path / "keys"
    out = subprocess.run(
        [sys.executable, "-m", "service.commands.holo_service", "--make-keys", str(keys)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    for name in (
        "server.key",
        "server.key_secret",
        "client.key",
        "client.key_secret",
        "authorized/client.key",
    ):
        assert (keys / name).is_file()
    svc = launch_service(  # on ports of its own choosing
        "--curve-keys", str(keys), "--scene", "game", "--zones", "2", "--size", "32x24",
        "--workers", "0",
    )  # fmt: skip
    try:
        with ServiceClient(
            svc.control, timeout_s=1.0, retries=30, curve_keys=keys
        ) as c:
            assert c.hello()["version"] == 1
            plain = raw_request(svc.control, {"v": 1, "type": "ping", "id": 1}, (), 1000)
            assert plain is None, "a client without keys must not be served"
            with FrameSubscriber(svc.frames, curve_keys=keys) as frames:
                assert wait_until(lambda: frames.next(0.5), 30), "no encrypted frames"
    finally:
        svc.stop()


def test_non_loopback_bind_needs_keys():
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "service.commands.holo_service",
            "--control",
            f"tcp://0.0.0.0:{free_port()}",
            "--workers",
            "0",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2 and "--curve-keys" in out.stderr


def test_make_keys_writes_secrets_private_and_leaves_no_temporary_folder(tmp_path):
    import stat

    from service.net.curve_keys import make_keys

    made = make_keys(tmp_path / "k")
    for name in ("server_secret", "client_secret"):
        assert stat.S_IMODE(made[name].stat().st_mode) == 0o600, name
        assert made[name].parent == tmp_path / "k"
    for name in ("server_public", "client_public"):
        assert made[name].is_file() and made[name].parent == tmp_path / "k"
    assert sorted(p.name for p in (tmp_path / "k").iterdir()) == [
        "authorized", "client.key", "client.key_secret", "server.key", "server.key_secret"]
    assert (made["authorized"] / "client.key").read_bytes() == made["client_public"].read_bytes()
