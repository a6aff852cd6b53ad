"""Benchmark: byte arrival to event published, through the real driver path.

Usage::

    python -m service.bench.latency_bench --out DIR [--frames N] [--rate HZ]
                                    [--protocol NAME,...] [--transport pty|loop|udp]
                                    [--wiring inline|hub|inline,hub]

The benchmark writes one tracker frame at a time into the master side of a pty pair
(or a ``loop://`` port; or, for ``--protocol opentrack``, sends it as one UDP datagram
to a reader listening on ``opentrack-udp://127.0.0.1:PORT``, ``--transport udp``,
which opentrack's poses imply; ``--protocol opentrack,native`` times both side by side,
frames round-robin); a :class:`~drivers.reader.DeviceReader` reads the slave side
on its thread and the pose goes out through :class:`~drivers.publisher.Publisher`
(tcp://127.0.0.1) wired as in ``holo-devices`` (``inline``: published on the reader
thread; ``hub``: the older hand-off to a consumer thread, kept for comparison).  A
SUB socket in the benchmark's thread receives it.  One frame is in flight at a time,
sent on an absolute schedule at ``--rate``, so each sample is the latency of an idle
system, not of a queue.  Half a period after each frame the benchmark also times a
bare pyzmq PUB -> SUB hop (same context, same message size) as a reference taken
under the same load.

Per frame it records :func:`time.monotonic_ns` at four points: ``write`` (just before
the bytes are written), ``arrival`` (the reader's receive stamp, the event's
``t_ns``: the moment the first byte came back from the port), ``published`` (the
moment the publisher's ``send`` returned, stamped on the publishing thread) and
``received`` (the SUB socket returned the message).  Figures, in ms:

* ``published``: arrival -> published (the issue's target: p99 <= 2 ms);
* ``received``: arrival -> received by a subscriber in this process;
* ``bare_hop``: a bare PUB send -> SUB receive, nothing else in the path;
* ``to_arrival``: write -> arrival (kernel pty + reader wake-up);
* ``total``: write -> received.

Writes ``latency.csv`` (one row per frame, ns), ``latency.json`` (p50 / p90 / p95 /
p99 / max / mean of every figure, settings, host) and ``latency.png`` (CDFs and
tails of published / received / bare hop with the 2 ms target) into ``--out`` and prints a
summary.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import queue
import socket
import sys
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import serial
import zmq

from drivers.events import Event, PoseEvent
from drivers.protocols import hatire, native, opentrack
from drivers.publisher import Publisher
from drivers.reader import DeviceReader, EventHub, Item, ReaderSettings
from drivers.udp_port import UdpPort
from service.base.cli_args import exit_rule_epilog, float_range, int_range, plain_help
from service.bench.charts import save_chart

TARGET_P99_MS = 2.0
#: protocol -> frame encoder taking the frame number.
ENCODERS: dict[str, Callable[[int], bytes]] = {
    "native": lambda k: native.encode_pose(k, k * 1000, (1.0, 2.0, 3.0), (1.0, 0.0, 0.0, 0.0)),
    "hatire": lambda k: hatire.encode_pose(k, 10.0, 5.0, 1.0, 1.0, 2.0, 3.0),
    # opentrack has no frame counter: the frame number travels as x, in whole centimetres
    "opentrack": lambda k: opentrack.encode_raw(k, 2.0, 3.0, 10.0, 5.0, 1.0),
}
#: protocol -> frame counter modulus.
SEQ_MOD = {"native": 1 << 32, "hatire": 1000, "opentrack": 500}
#: protocol -> the frame number of a pose, from its ``seq`` and ``x`` (default: ``seq``).
FRAME_OF: dict[str, Callable[[int, float], int]] = {
    "opentrack": lambda seq, x_mm: round(x_mm / 10.0),
}
#: x-axis ticks of the charts (ms).
TICKS_MS = (0.02, 0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100)
#: per-frame stamps, in CSV column order.
STAMPS = ("write", "arrival", "published", "received")
#: figure name -> (from stamp, to stamp) or None for the bare hop.
FIGURES: dict[str, tuple[str, str] | None] = {
    "published": ("arrival", "published"),
    "received": ("arrival", "received"),
    "bare_hop": None,
    "to_arrival": ("write", "arrival"),
    "total": ("write", "received"),
}
PERCENTILES = (50, 90, 95, 99)
WIRINGS = ("inline", "hub")


@dataclass
class Transport:
    """Where frames are written and what the reader opens."""

    url: str
    opener: Callable[..., Any]
    write: Callable[[bytes], Any]
    close: Callable[[], None]


def pty_transport() -> Transport:
    """A pty pair: the benchmark writes the master, the reader opens the slave path."""
    master, slave = os.openpty()
    tty.setraw(slave)

    def close() -> None:
        for fd in (master, slave):
            os.close(fd)

    return Transport(os.ttyname(slave), serial.serial_for_url,
                     lambda data: os.write(master, data), close)


def loop_transport() -> Transport:
    """A ``loop://`` port shared by the writer and the reader."""
    port = serial.serial_for_url("loop://", timeout=0.05)
    return Transport("loop://", lambda url, **kw: port, port.write, port.close)


def udp_transport() -> Transport:
    """A UDP listener on 127.0.0.1 (the reader's port) and a socket sending it datagrams."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:  # a free port (racy)
        probe.bind(("127.0.0.1", 0))
        port_no = probe.getsockname()[1]
    url = f"opentrack-udp://127.0.0.1:{port_no}"
    port = UdpPort(url)
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def close() -> None:
        out.close()
        port.close()

    return Transport(url, lambda url, **kw: port,
                     lambda data: out.sendto(data, ("127.0.0.1", port_no)), close)


TRANSPORTS = {"pty": pty_transport, "loop": loop_transport, "udp": udp_transport}
#: protocol -> the only transport it comes over (others: any but these).
TRANSPORT_OF = {"opentrack": "udp"}


class TimedPublisher(Publisher):
    """A :class:`Publisher` that stamps the moment each pose's send returned.

    ``sent`` receives ``(seq, arrival t_ns, published ns)`` per pose, put after the
    stamp so the queue costs nothing in the figure.
    """

    def __init__(self, address: str, frame_of: Callable[[int, float], int]) -> None:
        super().__init__(address)
        self.frame_of = frame_of
        self.sent: queue.SimpleQueue[tuple[int, int, int]] = queue.SimpleQueue()

    def _pose(self, ev: PoseEvent) -> None:
        super()._pose(ev)
        now = time.monotonic_ns()
        self.sent.put((self.frame_of(ev.seq, ev.x), ev.t_ns, now))


def frame_of(protocol: str) -> Callable[[int, float], int]:
    """How to tell a pose's frame number (:data:`FRAME_OF`, else its ``seq``)."""
    return FRAME_OF.get(protocol, lambda seq, x_mm: seq)


class Pipeline:
    """Reader thread -> publisher, wired ``inline`` (as ``holo-devices``) or via a hub.

    Parameters
    ----------
    transport : Transport
    protocol : str
    wiring : str
        ``inline``: the reader's sink publishes at once, on the reader thread, then
        queues the item for the other listeners; ``hub``: the reader only queues and a
        consumer thread publishes (one thread hand-off more).
    """

    def __init__(self, transport: Transport, protocol: str, wiring: str) -> None:
        self.transport = transport
        self.wiring = wiring
        self.hub = EventHub()
        self.publisher = TimedPublisher("tcp://127.0.0.1:0", frame_of(protocol))
        pub = self.publisher
        self._listeners: list[Callable[[Item, list[Event]], None]] = []
        sink: Callable[[Item, list[Event]], None] = self.hub.put
        if wiring == "inline":
            sink = pub.sink(self.hub.put)
        else:
            self._listeners.append(lambda item, events: pub.publish_all(events))
        settings = ReaderSettings(transport.url, protocol, watchdog_s=None)
        self.reader = DeviceReader(settings, sink, opener=transport.opener)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._consume, name="bench-consume",
                                        daemon=True)

    def _consume(self) -> None:
        while not self._stop.is_set():
            self.hub.dispatch(self._listeners, 0.05)
            self.publisher.service()

    def start(self) -> Pipeline:
        """Start the reader and the consumer thread."""
        self.reader.start()
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop and join both threads; close the publisher and the transport."""
        self.reader.stop()
        self._stop.set()
        self._thread.join(5.0)
        self.publisher.close()
        self.transport.close()


class BareHop:
    """A bare PUB -> SUB pair over tcp://127.0.0.1, driven from the calling thread."""

    def __init__(self, ctx: zmq.Context, size: int) -> None:
        self.pub = ctx.socket(zmq.PUB)
        self.pub.setsockopt(zmq.LINGER, 0)
        self.pub.bind("tcp://127.0.0.1:0")
        self.sub = ctx.socket(zmq.SUB)
        self.sub.setsockopt(zmq.LINGER, 0)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"pose")
        self.sub.connect(self.pub.getsockopt_string(zmq.LAST_ENDPOINT))
        self.size = size
        self.k = 0

    def once(self, timeout_ms: int) -> int | None:
        """Send one message; ns from before the send to its receipt, or None."""
        self.k += 1
        body = f"{self.k:012d}".encode().ljust(self.size, b" ")
        t0 = time.monotonic_ns()
        self.pub.send_multipart((b"pose", body))
        deadline = t0 + timeout_ms * 1_000_000
        while True:
            left = (deadline - time.monotonic_ns()) // 1_000_000
            if left <= 0 or not self.sub.poll(max(1, left)):
                return None
            frames = self.sub.recv_multipart()
            now = time.monotonic_ns()
            if frames[1] == body:
                return now - t0

    def warm_up(self) -> None:
        """Send until a message gets through (the subscription has propagated)."""
        for _ in range(1000):
            if self.once(20) is not None:
                return
        raise RuntimeError("bare hop never connected")

    def close(self) -> None:
        """Close both sockets."""
        self.sub.close()
        self.pub.close()


class Probe:
    """One pipeline, its transport and the SUB socket that watches it."""

    def __init__(self, transport_name: str, protocol: str, wiring: str) -> None:
        self.pipe = Pipeline(TRANSPORTS[transport_name](), protocol, wiring).start()
        self.sub = zmq.Context.instance().socket(zmq.SUB)
        self.sub.setsockopt(zmq.LINGER, 0)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"pose")
        self.sub.connect(self.pipe.publisher.address)
        self.encode, self.mod = ENCODERS[protocol], SEQ_MOD[protocol]
        self.frame_of = frame_of(protocol)
        self.k = 0
        self.body_size = 0

    def frame(self, timeout_ms: int) -> dict[str, int] | None:
        """Write one frame and follow it to the subscriber; its stamps or None (lost)."""
        k = self.k = (self.k + 1) % self.mod
        t_write = time.monotonic_ns()
        self.pipe.transport.write(self.encode(k))
        got = self._receive(k, timeout_ms)
        sent = self._published(k, timeout_ms)
        if got is None or sent is None:
            return None
        return {"write": t_write, "arrival": sent[0], "published": sent[1], "received": got}

    def _receive(self, seq: int, timeout_ms: int) -> int | None:
        deadline = time.monotonic_ns() + timeout_ms * 1_000_000
        while True:
            left = (deadline - time.monotonic_ns()) // 1_000_000
            if left <= 0 or not self.sub.poll(max(1, left)):
                return None
            _topic, body = self.sub.recv_multipart()
            now = time.monotonic_ns()
            d = json.loads(body)
            if self.frame_of(d["seq"], d["x"]) == seq:
                self.body_size = len(body)
                return now

    def _published(self, seq: int, timeout_ms: int) -> tuple[int, int] | None:
        deadline = time.monotonic() + timeout_ms / 1000
        while (left := deadline - time.monotonic()) > 0:
            try:
                got_seq, arrival, published = self.pipe.publisher.sent.get(timeout=left)
            except queue.Empty:
                return None
            if got_seq == seq:
                return arrival, published
        return None

    def warm_up(self) -> None:
        """Send frames until the subscriber gets one (port open, subscription made)."""
        tick = threading.Event()
        for _ in range(1000):
            if self.pipe.reader.connected:
                if self.frame(100) is not None:
                    return
            else:
                tick.wait(0.01)
        raise RuntimeError("no pose reached the subscriber during warm-up")

    def close(self) -> None:
        """Close the SUB socket and the pipeline."""
        self.sub.close()
        self.pipe.close()


def measure(frames: int, rate_hz: float, specs: dict[str, tuple[str, str, str]]
            ) -> dict[str, Any]:
    """Run the benchmark.

    Frames go round-robin to one pipeline per spec, so pipelines compared in one run
    see the same load; a bare hop follows each frame half a period later.

    Parameters
    ----------
    specs : dict
        label -> ``(protocol, transport, wiring)`` of each pipeline.

    Returns
    -------
    dict
        ``rows``: label -> list of per-frame stamp dicts; ``bare_hop``: ns samples;
        ``lost``: label -> frames that never arrived (``"bare_hop"`` included).
    """
    labels = list(specs)
    probes = [Probe(t, p, w) for p, t, w in specs.values()]
    hop: BareHop | None = None
    rows: dict[str, list[dict[str, int]]] = {w: [] for w in labels}
    lost = {w: 0 for w in (*labels, "bare_hop")}
    hops: list[int] = []
    try:
        for p in probes:
            p.warm_up()
        hop = BareHop(zmq.Context.instance(), probes[0].body_size)
        hop.warm_up()
        period_ns, start = round(1e9 / rate_hz), time.monotonic_ns()
        tick = threading.Event()

        def wait_until(target: int) -> None:
            while (now := time.monotonic_ns()) < target:
                tick.wait((target - now) / 1e9)

        for i in range(frames * len(probes)):
            label, probe = labels[i % len(probes)], probes[i % len(probes)]
            wait_until(start + i * period_ns)
            stamps = probe.frame(1000)
            if stamps is None:
                lost[label] += 1
            else:
                rows[label].append(stamps)
            wait_until(start + i * period_ns + period_ns // 2)
            ns = hop.once(1000)
            if ns is None:
                lost["bare_hop"] += 1
            else:
                hops.append(ns)
    finally:
        if hop is not None:
            hop.close()
        for p in probes:
            p.close()
    return {"rows": rows, "bare_hop": np.array(hops, dtype=np.int64), "lost": lost}


def figures(rows: list[dict[str, int]], hops: np.ndarray) -> dict[str, np.ndarray]:
    """Figure name -> ns samples (see :data:`FIGURES`)."""
    stamps = {s: np.array([r[s] for r in rows], dtype=np.int64) for s in STAMPS}
    out: dict[str, np.ndarray] = {}
    for name, span in FIGURES.items():
        out[name] = hops if span is None else stamps[span[1]] - stamps[span[0]]
    return out


def summarise(samples: np.ndarray) -> dict[str, float]:
    """p50 / p90 / p95 / p99 / max / mean in milliseconds (empty without samples)."""
    if samples.size == 0:
        return {}
    ms = samples / 1e6
    out = {f"p{q}_ms": float(np.percentile(ms, q)) for q in PERCENTILES}
    out.update(max_ms=float(ms.max()), mean_ms=float(ms.mean()), n=int(ms.size))
    return out


def write_csv(path: Path, rows: dict[str, list[dict[str, int]]], hops: np.ndarray) -> None:
    """One row per frame: wiring, the four stamps (ns) and the bare hop after it (ns)."""
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["wiring", "frame", *(f"{s}_ns" for s in STAMPS)])
        for wiring, frames in rows.items():
            for i, r in enumerate(frames):
                w.writerow([wiring, i, *(r[s] for s in STAMPS)])
        for i, ns in enumerate(hops):
            w.writerow(["bare_hop", i, 0, 0, int(ns), 0])


def plot(curves: dict[str, np.ndarray], path: Path, title: str) -> None:
    """CDFs (left) and tails (right: fraction of frames slower, log) with the 2 ms target.

    On the right the p99 of a curve is where it crosses the 1 % line.
    """
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 5))
    lo, hi = np.inf, 0.0
    for name, samples in curves.items():
        if samples.size == 0:
            continue
        ms = np.sort(samples / 1e6)
        lo, hi = min(lo, ms[0]), max(hi, ms[-1])
        frac = np.arange(1, ms.size + 1) / ms.size
        label = (f"{name}: p50 {np.percentile(ms, 50):.3f}  p95 {np.percentile(ms, 95):.3f}"
                 f"  p99 {np.percentile(ms, 99):.3f} ms")
        ax1.plot(ms, frac, label=label)
        ax2.plot(ms[:-1], 1 - frac[:-1], label=label)
    ax1.set_ylabel("fraction of frames <= latency")
    ax2.set_yscale("log")
    ax2.set_ylabel("fraction of frames slower (log)")
    ax2.axhline(0.01, color="grey", linewidth=0.7)
    ax2.axhline(0.05, color="grey", linewidth=0.4, linestyle=":")
    ticks = [v for v in TICKS_MS if lo / 2 <= v <= hi * 2]
    for ax in (ax1, ax2):
        ax.set_xscale("log")
        ax.set_xlabel("latency (ms)")
        ax.axvline(TARGET_P99_MS, color="red", linestyle="--", label="p99 target 2 ms")
        ax.set_xticks(ticks, [f"{v:g}" for v in ticks])
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax1.legend(fontsize=7, loc="lower right")
    fig.suptitle(title)
    fig.tight_layout()
    save_chart(fig, path, dpi=110)


def _line(name: str, s: dict[str, float]) -> str:
    if not s:
        return f"  {name:22s} no samples"
    return (f"  {name:22s} p50 {s['p50_ms']:7.3f}  p95 {s['p95_ms']:7.3f}  "
            f"p99 {s['p99_ms']:7.3f}  max {s['max_ms']:7.3f} ms")


def main(argv: list[str] | None = None) -> int:
    """Run the latency benchmark; returns 0 (whether the target was met is reported)."""
    ap = argparse.ArgumentParser(prog="holo-bench latency",
                                 description=plain_help(__doc__.splitlines()[0]),
                                 epilog=exit_rule_epilog())
    ap.add_argument("--out", metavar="DIR", required=True, type=Path, help="output folder")
    ap.add_argument("--frames", metavar="N", type=int_range(1), default=2000,
                    help="frames to time per pipeline (protocol x wiring)")
    ap.add_argument("--rate", metavar="HZ", type=float_range(0, lo_open=True), default=200.0,
                    help="frames per second")
    ap.add_argument("--protocol", metavar="NAME,...", default="native",
                    help=f"tracker protocols timed side by side, from: {', '.join(ENCODERS)} "
                    "(default: %(default)s)")
    ap.add_argument("--transport", choices=tuple(TRANSPORTS), default=None,
                    help="default: udp for opentrack, else pty")
    ap.add_argument("--wiring", metavar="NAME,...", default="inline",
                    help="comma-separated pipelines timed side by side, from: "
                    f"{', '.join(WIRINGS)} (default: %(default)s, as holo-devices)")
    args = ap.parse_args(argv)
    wirings = tuple(args.wiring.split(","))
    if not wirings or not set(wirings) <= set(WIRINGS) or len(set(wirings)) < len(wirings):
        ap.error(f"--wiring takes distinct names from {', '.join(WIRINGS)}")
    protocols = tuple(args.protocol.split(","))
    if not set(protocols) <= set(ENCODERS) or len(set(protocols)) < len(protocols):
        ap.error(f"--protocol takes distinct names from {', '.join(ENCODERS)}")
    if args.transport == "udp" and set(protocols) != {"opentrack"}:
        ap.error("--transport udp goes with --protocol opentrack alone")
    transport = {p: TRANSPORT_OF.get(p) or args.transport or "pty" for p in protocols}
    specs = {(w if len(protocols) == 1 else f"{p} {w}"): (p, transport[p], w)
             for p in protocols for w in wirings}
    args.out.mkdir(parents=True, exist_ok=True)
    res = measure(args.frames, args.rate, specs)
    wirings = tuple(specs)  # the pipelines' labels from here on
    over = ", ".join(f"{p} over {t}" for p, t in transport.items())
    hops = res["bare_hop"]
    per = {w: figures(res["rows"][w], hops) for w in wirings}
    head = per[wirings[0]]["published"]
    report: dict[str, Any] = {
        "settings": {"frames": args.frames, "rate_hz": args.rate, "protocol": args.protocol,
                     "transport": ",".join(transport[p] for p in protocols),
                     "wirings": list(wirings)},
        "host": {"python": sys.version.split()[0], "platform": platform.platform(),
                 "cpus": os.cpu_count(), "load_avg": list(os.getloadavg())},
        "target_p99_ms": TARGET_P99_MS,
        "headline": f"{wirings[0]}: arrival -> published",
        "lost": res["lost"],
        "bare_hop": summarise(hops),
        "wirings": {w: {name: summarise(v) for name, v in figs.items() if name != "bare_hop"}
                    for w, figs in per.items()},
    }
    report["target_met"] = bool(head.size) and bool(
        np.percentile(head, 99) / 1e6 <= TARGET_P99_MS)
    (args.out / "latency.json").write_text(json.dumps(report, indent=1))
    write_csv(args.out / "latency.csv", res["rows"], hops)
    curves = {f"{w}: arrival -> published": per[w]["published"] for w in wirings}
    curves.update({f"{w}: arrival -> SUB received": per[w]["received"] for w in wirings})
    curves["bare PUB -> SUB hop"] = hops
    if any(v.size for v in curves.values()):
        plot(curves, args.out / "latency.png",
             f"{over}, {args.frames} frames per pipeline at "
             f"{args.rate:g} Hz, load {os.getloadavg()[0]:.1f}")
    print(f"latency {over}, lost {res['lost']}:")
    for w in wirings:
        for name in ("published", "received", "to_arrival"):
            print(_line(f"{w} {name}", report["wirings"][w][name]))
    print(_line("bare hop", report["bare_hop"]))
    s = report["wirings"][wirings[0]]["published"]
    print(f"target: arrival -> published p99 <= {TARGET_P99_MS:g} ms "
          f"{'met' if report['target_met'] else 'MISSED'} "
          f"(p99 {s.get('p99_ms', float('nan')):.3f} ms)  -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
