"""CurveZMQ keys for the service (``holo-service-keys DIR`` / ``holo-service --make-keys DIR``).

:func:`make_keys` writes, with ``zmq.auth.create_certificates``::

    DIR/server.key          the service's public key (give it to clients and workers)
    DIR/server.key_secret   the service's key pair (keep it on the service's host)
    DIR/client.key          a client key pair's public half
    DIR/client.key_secret   the client key pair (clients and workers load it)
    DIR/authorized/client.key   public keys the service accepts (add more here)

A service started with ``--curve-keys DIR`` makes its control ROUTER, frame PUB
and worker backend CURVE servers with ``server.key_secret`` and admits only the
clients whose public keys are in ``DIR/authorized`` (``zmq.auth``'s thread
authenticator).  Binding a non-loopback address without keys is refused.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from urllib.parse import urlparse

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1", "[::1]")


def make_keys(directory: str | Path) -> dict[str, Path]:
    """Create the server and client certificates and the authorized list.

    Returns
    -------
    dict of Path
        ``server_public``, ``server_secret``, ``client_public``, ``client_secret``,
        ``authorized``.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    # made in a private folder (mode 700, tempfile's) and made 600 there before they
    # move beside the public keys: no moment in which another user could read them
    with tempfile.TemporaryDirectory(dir=d, prefix=".keys-") as private:
        made: dict[str, Path] = {}
        for who in ("server", "client"):
            pub, sec = zmq.auth.create_certificates(private, who)
            Path(sec).chmod(0o600)
            for kind, path in (("public", Path(pub)), ("secret", Path(sec))):
                os.replace(path, d / path.name)
                made[f"{who}_{kind}"] = d / path.name
    auth = d / "authorized"
    auth.mkdir(exist_ok=True)
    shutil.copy(made["client_public"], auth / "client.key")
    return {**made, "authorized": auth}


def is_local(address: str) -> bool:
    """True for loopback TCP, ``ipc://`` and ``inproc://`` addresses."""
    url = urlparse(address)
    if url.scheme in ("ipc", "inproc"):
        return True
    host = address.split("://", 1)[-1].rsplit(":", 1)[0]
    return host in LOCAL_HOSTS or host.startswith("127.")


def curve_server(directory: str | Path) -> Callable[[zmq.Socket], None]:
    """A function that makes a socket a CURVE server with ``server.key_secret``."""
    public, secret = zmq.auth.load_certificate(Path(directory) / "server.key_secret")

    def secure(sock: zmq.Socket) -> None:
        sock.curve_secretkey = secret
        sock.curve_publickey = public
        sock.curve_server = True

    return secure


def start_authenticator(context: zmq.Context, directory: str | Path) -> ThreadAuthenticator:
    """Start ``zmq.auth``'s authenticator admitting the keys in ``DIR/authorized``."""
    auth = ThreadAuthenticator(context)
    auth.start()
    auth.configure_curve(domain="*", location=str(Path(directory) / "authorized"))
    return auth
