"""ZeroMQ addresses: the default ports of every command, and one endpoint check.

Default ports, all on 127.0.0.1 and chosen not to collide, so every command can run
at once on one machine with its defaults:

==========  =====  ==================================================================
name        port   what listens there
==========  =====  ==================================================================
control     5555   ``holo-service`` control ROUTER (requests)
frames      5556   ``holo-service`` frame PUB
workers     5557   ``holo-service`` broker backend (render workers connect)
devices     5560   ``holo-devices --pub`` / ``holo-replay --pub`` event PUB
pose        5561   ``holo-devices --pub-pose`` / ``holo-replay --pub-pose`` (poses only)
==========  =====  ==================================================================

``holo-replay`` stands in for ``holo-devices`` (a recorded session instead of live
devices), so it publishes on the same ports: clients need not know which one runs.

:func:`check_endpoint` is the one place an endpoint is validated (argparse types,
config files, the publisher itself): libzmq takes ``tcp://127.0.0.1:99999`` and
silently binds port 99999 mod 65536, so a port outside 1-65535 is refused here.
"""

from __future__ import annotations

import re

from service.base.errors import SettingsError

__all__ = ["DEFAULT_PORTS", "check_endpoint", "default_address", "host_port"]

DEFAULT_PORTS = {"control": 5555, "frames": 5556, "workers": 5557, "devices": 5560,
                 "pose": 5561}
#: Transports whose address ends in ``:PORT``.
_PORTED = ("tcp", "ws", "wss", "udp", "pgm", "epgm")
#: Transports whose address is a name or a path.
_NAMED = ("ipc", "inproc")
_SCHEME = re.compile(r"^([a-z]+)://(.*)$", re.IGNORECASE)
_HOST_PORT = re.compile(r"^(\[[0-9A-Fa-f:.%a-zA-Z]*\]|[^:\[\]/;]*):([^:/]*)(/.*)?$")


def default_address(name: str, host: str = "127.0.0.1") -> str:
    """``tcp://HOST:PORT`` for a name of :data:`DEFAULT_PORTS`."""
    return f"tcp://{host}:{DEFAULT_PORTS[name]}"


def check_endpoint(address: str, bind: bool = True) -> str:
    """Validate a ZeroMQ endpoint; return it unchanged.

    Parameters
    ----------
    address : str
        ``tcp://HOST:PORT`` (``[v6]`` hosts too, ``SOURCE;HOST:PORT`` for connects),
        ``ipc://PATH``, ``inproc://NAME``, ``ws://HOST:PORT/PATH``, ``wss://...``,
        ``udp://``, ``pgm://`` and ``epgm://`` with a port.
    bind : bool
        True for an address to bind, where port ``0`` or ``*`` asks for any free port
        (and ``*`` may stand for every interface); False for one to connect to, which
        needs a real port 1-65535.

    Raises
    ------
    SettingsError
        Naming what is wrong: no ``transport://``, an unknown transport, no host or
        port, a port that is not a number in 1-65535.
    """
    m = _SCHEME.match(address.strip()) if isinstance(address, str) else None
    if m is None:
        raise SettingsError(f"{address!r} is not a ZeroMQ address; want e.g. "
                            "tcp://127.0.0.1:5560")
    transport, rest = m.group(1).lower(), m.group(2)
    if transport in _NAMED:
        if not rest:
            raise SettingsError(f"{address!r}: {transport}:// needs a name or path")
        return address
    if transport not in _PORTED:
        known = ", ".join(t + "://" for t in (*_PORTED, *_NAMED))
        raise SettingsError(f"{address!r}: unknown transport {transport}:// (known: {known})")
    _check_host_port(address, rest.rsplit(";", 1)[-1], bind)
    return address


def host_port(text: str) -> tuple[str, int]:
    """``(host, port)`` of ``HOST:PORT`` or ``[V6]:PORT``: where UDP datagrams go.

    Raises
    ------
    SettingsError
        No host, or a port that is not a number in 1-65535.
    """
    host, _, port = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not host or not re.fullmatch(r"[0-9]{1,5}", port) or not 1 <= int(port) <= 65535:
        raise SettingsError(f"give HOST:PORT with a port in 1-65535, not {text!r}")
    return host, int(port)


def _check_host_port(address: str, rest: str, bind: bool) -> None:
    hp = _HOST_PORT.match(rest)
    if hp is None or not hp.group(1):
        raise SettingsError(f"{address!r}: want HOST:PORT after the transport, "
                            "e.g. tcp://127.0.0.1:5560")
    port = hp.group(2)
    if bind and port in ("*", "0"):
        return
    if not re.fullmatch(r"[0-9]{1,5}", port) or not 1 <= int(port) <= 65535:
        allowed = "1-65535, or 0 / * for any free port" if bind else "1-65535"
        raise SettingsError(f"{address!r}: port {port!r} is not a port number ({allowed})")
