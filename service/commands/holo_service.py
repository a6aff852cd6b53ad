"""``holo-service``: the render service (``docs/service.md``, ``docs/protocol.md``).

Usage::

    holo-service [--control ADDR] [--frames ADDR] [--devices ADDR] [--workers N]
                 [--refresh HZ] [--curve-keys DIR] [--scene NAME] ...
    holo-service --make-keys DIR        (same as holo-service-keys DIR)

The first stderr line names the bound addresses (``holo-service: control ADDR
frames ADDR session S``).  The service then warms up: a child process compiles
every numba kernel into the cache (minutes on a first run, seconds after) while the
service answers every request with "warming up n/m" and keeps sending heartbeats;
``holo-service: ready ...`` follows when it renders.  ``--no-warmup`` skips that
(kernels then compile when first used, stalling the service on an empty cache).
The service runs until a ``shutdown`` request, SIGINT or SIGTERM.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import zmq

from service.base.cli_args import add_size_option, endpoint, float_range, int_range, plain_help
from service.base.errors import HoloError
from service.base.signals import EXIT_OK, EXIT_RULE, EXIT_USAGE, stop_on_signals
from service.builtin_scenes import scene_name
from service.display import DisplaySettings
from service.lod.options import add_colour_option, colour_budget, colour_given
from service.lod.settings import lod_from
from service.net.curve_keys import make_keys
from service.process import setup_frame_process
from service.readiness import Warmup
from service.render.pipeline import RenderSettings

if TYPE_CHECKING:
    from service.net.server import Service
    from service.net.state import ServiceConfig


class _DefaultsHelp(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """``--help`` as written, with every default; a None default is explained in words."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None or action.nargs == 0:  # a flag: "(default: True)" misleads
            return action.help
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    """The command line (``--help`` shows every default)."""
    ap = argparse.ArgumentParser(
        prog="holo-service",
        description=plain_help(__doc__),
        epilog=EXIT_RULE,
        formatter_class=_DefaultsHelp,
    )
    _add_addresses(ap)
    _add_rendering(ap)
    _add_display(ap)
    return ap


def _add_addresses(ap: argparse.ArgumentParser) -> None:
    """Sockets, devices and keys."""
    ap.add_argument(
        "--control", default="tcp://127.0.0.1:5555", type=endpoint(bind=True), metavar="ADDR",
        help="control ROUTER address"
    )
    ap.add_argument(
        "--frames", default="tcp://127.0.0.1:5556", type=endpoint(bind=True), metavar="ADDR",
        help="frame PUB address"
    )
    ap.add_argument(
        "--devices",
        default=None,
        type=endpoint(bind=False),
        metavar="ADDR",
        help="holo-devices PUB address for the viewer's pose and input (default: none)",
    )
    ap.add_argument(
        "--io-threads",
        type=int_range(1, 64),
        metavar="N",
        default=2,
        help="libzmq I/O threads (2: the frame stream gets one of its own, so frames do "
        "not queue behind workers' multi-MB replies)",
    )
    ap.add_argument(
        "--worker-address",
        default=None,
        type=endpoint(bind=True),
        metavar="ADDR",
        help="broker backend address workers connect to (default: tcp://127.0.0.1:5557, "
        "used when --workers > 0).  Giving it starts the broker even with --workers 0, for "
        "workers on other hosts; renders run in process until one connects",
    )
    ap.add_argument(
        "--curve-keys",
        default=None,
        metavar="DIR",
        help="CurveZMQ key directory (default: none; required for a non-loopback address)",
    )
    ap.add_argument(
        "--make-keys",
        default=None,
        metavar="DIR",
        help="make CurveZMQ keys in DIR and exit (default: none, run the service)",
    )


def _add_rendering(ap: argparse.ArgumentParser) -> None:
    """Workers, rates and timeouts."""
    ap.add_argument(
        "--workers",
        type=int_range(0),
        metavar="N",
        default=1,
        help="render worker processes behind the LRU broker, supervised: one that dies or "
        "stops answering is replaced (0: render in the service's own process, where numba "
        "kernels hold the GIL and delay refreshes)",
    )
    ap.add_argument(
        "--split",
        choices=("frames", "bands"),
        default="frames",
        help="with workers: each renders whole updates for successive rendezvous, several "
        "in flight (frames), or every worker a band of hololines of each update (bands)",
    )
    ap.add_argument(
        "--refresh", type=float_range(1, 240), default=60.0, metavar="HZ", help="refresh rate, Hz"
    )
    ap.add_argument(
        "--max-update-hz",
        type=float_range(0),
        metavar="HZ",
        default=0.0,
        help="cap on renders per second (0: as fast as possible)",
    )
    ap.add_argument(
        "--no-warmup",
        dest="warmup",
        action="store_false",
        default=True,
        help="serve at once, without the warm-up child; kernels compile when first used "
        "(the service stalls, heartbeats included, on an empty numba cache)",
    )
    ap.add_argument(
        "--render-timeout",
        type=float_range(0, lo_open=True),
        metavar="S",
        default=5.0,
        help="seconds a worker may hold one render job: past it the worker counts as "
        "stuck (killed and replaced if local) and the job is resent",
    )


def _add_display(ap: argparse.ArgumentParser) -> None:
    """Scene and display at start, pose scale."""
    ap.add_argument(
        "--scene",
        default=None,
        type=scene_name,
        metavar="NAME",
        help="built-in scene to load at start: game, demo, sphere-torus, cyclic or threaded "
        "(default: none; a scene file is loaded by a client's load_scene request)",
    )
    ap.add_argument(
        "--scene-dir",
        action="append",
        default=None,
        metavar="DIR",
        help="directory load_scene/load_object paths must lie in (repeatable; "
        "default: none, so any file the service can read)",
    )
    ap.add_argument("--zones", type=int_range(1, 64), default=5, metavar="N",
                    help="view zones, 1-64")
    add_size_option(ap, (160, 120), "galpixel columns x hololines per zone",
                    old_cols_rows=True)
    ap.add_argument(
        "--angle", type=float_range(0, 60), default=16.0, metavar="DEG",
        help="view angle across the zones, degrees, 0-60"
    )
    ap.add_argument(
        "--pose-scale",
        metavar="X",
        type=float_range(0, lo_open=True),
        default=0.001,
        help="world units per tracker position unit",
    )
    ap.add_argument(
        "--lod-error", type=float_range(0, None, lo_open=True), default=None, metavar="PX",
        help="turn level of detail on: each object drawn with its cheapest simplified mesh "
        "whose predicted screen error stays under PX pixels (e.g. 0.5) (default: off)",
    )
    ap.add_argument(
        "--budget-ms", type=float_range(0, None, lo_open=True), default=None, metavar="MS",
        help="level of detail with a time budget per render: when the measured cost model "
        "predicts more, the smallest and farthest objects go coarser than --lod-error "
        "(0.5 px unless given) allows (default: none)",
    )
    add_colour_option(ap)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``holo-service``."""
    args = build_parser().parse_args(argv)
    if args.make_keys:
        return _print_keys(args.make_keys)
    problem = _keys_problem(args.curve_keys)
    if problem:
        print(f"holo-service: --curve-keys {problem}", file=sys.stderr)
        return EXIT_USAGE
    # OpenMP threads that spin while waiting steal the core the refresh thread and the
    # other processes need: with one busy process beside it, a 5-zone game render took
    # 16 ms spinning against 12 ms passive (unloaded, passive is ~1.2x slower).  Set
    # before the first parallel kernel loads libgomp; workers inherit it.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    setup_frame_process()  # heap reuse and one BLAS thread (service.process)
    service = _start(args)
    if service is None:
        return EXIT_USAGE
    return _serve(service)


def _start(args: argparse.Namespace) -> Service | None:
    """The service, its sockets bound; None when it cannot start (said on stderr)."""
    # deferred: --help and usage errors answer before pygame and the numba kernels load
    from service.net.server import Service

    try:
        # warm up before serving (service.readiness): the kernels compile in a child
        # while every request gets "warming up"; --no-warmup: ready at once
        service = Service(_config(args), log=_log, warmup=Warmup(_log) if args.warmup else None)
    except (HoloError, OSError) as exc:
        print(f"holo-service: {exc}", file=sys.stderr)
        return None
    except zmq.ZMQError as exc:  # address in use...
        print(f"holo-service: cannot bind: {exc} (another holo-service running? "
              "--control, --frames and --worker-address pick other ports)", file=sys.stderr)
        return None
    except Exception as exc:
        print(f"holo-service: {type(exc).__name__}: {exc}", file=sys.stderr)
        return None
    return service


def _config(args: argparse.Namespace) -> ServiceConfig:
    """The service's settings from the command line."""
    # deferred: --help and usage errors answer before pygame and the numba kernels load
    from service.net.state import ServiceConfig

    return ServiceConfig(
        control=args.control,
        frames=args.frames,
        devices=args.devices,
        workers=max(0, args.workers),
        worker_address=args.worker_address,
        refresh_hz=args.refresh,
        curve_keys=args.curve_keys,
        render_timeout_s=args.render_timeout,
        split=args.split,
        io_threads=args.io_threads,
        max_update_hz=args.max_update_hz,
        scene=args.scene,
        display=DisplaySettings(args.zones, args.angle, *args.size),
        pose_scale=args.pose_scale,
        render=RenderSettings(lod=lod_from(args.lod_error, args.budget_ms, colour_budget(args),
                                           colour_given(args))),
        scene_dirs=tuple(args.scene_dir or ()),
    )


def _serve(service: Service) -> int:
    """Run the service until it is stopped; the exit status (130/143 on a signal)."""
    _log(
        f"control {service.control_address} frames {service.stream.address} "
        f"session {service.session}"
    )
    if not service.ready:
        _log("warming up: numba kernels load or compile before the first frame; requests get "
             "warming_up until ready")
    # The refresh thread must get the GIL soon after its tick: a 1 ms switch interval
    # (default 5 ms) bounds how long a busy thread holds it against a waiting one.
    sys.setswitchinterval(0.001)
    with stop_on_signals(service.stop_event) as received:
        service.run()
    if received.signum is not None:
        _log(f"stopped ({received.name})")
    return received.exit_status(EXIT_OK)


def _keys_problem(directory: str | None) -> str | None:
    """What a ``--curve-keys`` folder lacks (zmq.auth says it in two unprefixed lines)."""
    if directory is None:
        return None
    folder = Path(directory)
    missing = [name for name in ("server.key_secret", "authorized")
               if not (folder / name).exists()]
    if missing:
        return (f"{directory}: no {' or '.join(missing)} (make the keys with "
                f"holo-service-keys {directory})")
    return None


def _log(line: str) -> None:
    """One line on stderr, ``holo-service: ...``."""
    print(f"holo-service: {line}", file=sys.stderr, flush=True)


#: The files ``make_keys`` writes; one already there is never overwritten.
KEY_FILES = ("server.key", "server.key_secret", "client.key", "client.key_secret",
             "authorized/client.key")


def _print_keys(directory: str, prog: str = "holo-service") -> int:
    """Make the keys in ``directory`` and print where each is; 2 if it cannot."""
    folder = Path(directory)
    if folder.exists() and not folder.is_dir():  # mkdir's own word here is "File exists"
        print(f"{prog}: {directory}: not a folder; name a folder for the keys",
              file=sys.stderr)
        return EXIT_USAGE
    there = [name for name in KEY_FILES if (folder / name).exists()]
    if there:  # a new server key would lock out every client given the old one
        print(f"{prog}: {directory} already holds keys ({', '.join(there)}); "
              "delete them or name another folder", file=sys.stderr)
        return EXIT_USAGE
    try:
        made = make_keys(directory)
    except OSError as exc:
        print(f"{prog}: {directory}: cannot write the keys: {exc.strerror}", file=sys.stderr)
        return EXIT_USAGE
    for name, path in made.items():
        print(f"{name}: {path}")
    return EXIT_OK


def keys_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``holo-service-keys DIR``."""
    ap = argparse.ArgumentParser(
        prog="holo-service-keys",
        description="Make CurveZMQ keys for holo-service: DIR/server.key (give it to "
        "clients and workers), DIR/server.key_secret (keep it on the service's host), a "
        "client key pair and DIR/authorized/ (the client keys the service admits).",
        epilog=EXIT_RULE + " Keys already in DIR are never overwritten (status 2).",
    )
    ap.add_argument("directory", metavar="DIR", help="folder for the keys (made if missing)")
    return _print_keys(ap.parse_args(argv).directory, "holo-service-keys")


if __name__ == "__main__":
    raise SystemExit(main())
