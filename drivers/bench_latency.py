"""Benchmark: byte arrival to event published, through the real driver path.

Usage::

    python -m drivers.bench_latency --out DIR [--frames N] [--rate HZ]
                                    [--protocol native|hatire] [--transport pty|loop]

What is timed: the benchmark writes one tracker frame at a time into the master side
of a pty pair (or a ``loop://`` port), stamping ``time.monotonic_ns()`` just before
the write; a :class:`~drivers.reader.DeviceReader` reads the slave side on its
thread, the hub's consumer thread publishes the pose through
:class:`~drivers.publisher.Publisher` (tcp://127.0.0.1), and a SUB socket in the
benchmark's thread stamps the time it receives the matching pose.  One frame is in
flight at a time, sent on an absolute schedule at ``--rate``, so each sample is the
latency of an idle system, not of a queue.

Per frame it records (ns):

* ``total``: write -> SUB received (the figure of merit; target p99 <= 2 ms);
* ``arrival``: write -> the reader's receive stamp (kernel pty + thread wake-up);
* ``publish``: receive stamp -> SUB received (decode, hub queue, JSON, ZeroMQ).

Writes ``latency.json`` (percentiles, settings, host) and ``latency.png``
(histogram and CDF of ``total`` with the 2 ms target) into ``--out`` and prints a
one-line summary.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
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

from drivers.protocols import hatire, native
from drivers.publisher import Publisher
from drivers.reader import DeviceReader, EventHub, ReaderSettings

TARGET_P99_MS = 2.0
#: protocol -> frame encoder taking the frame number.
ENCODERS: dict[str, Callable[[int], bytes]] = {
    "native": lambda k: native.encode_pose(k, k * 1000, (1.0, 2.0, 3.0), (1.0, 0.0, 0.0, 0.0)),
    "hatire": lambda k: hatire.encode_pose(k, 10.0, 5.0, 1.0, 1.0, 2.0, 3.0),
}
#: protocol -> frame counter modulus.
SEQ_MOD = {"native": 1 << 32, "hatire": 1000}
#: x-axis ticks of the charts (ms).
TICKS_MS = (0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100)


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


TRANSPORTS = {"pty": pty_transport, "loop": loop_transport}


class Pipeline:
    """Reader thread -> hub -> publisher thread, as in ``holo-devices``."""

    def __init__(self, transport: Transport, protocol: str) -> None:
        self.hub = EventHub()
        self.publisher = Publisher("tcp://127.0.0.1:0")
        settings = ReaderSettings(transport.url, protocol, poll_s=0.05, watchdog_s=None)
        self.reader = DeviceReader(settings, self.hub.put, opener=transport.opener)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._consume, name="bench-publish",
                                        daemon=True)

    def _consume(self) -> None:
        pub = self.publisher
        listeners = [lambda item, events: pub.publish_all(events)]
        while not self._stop.is_set():
            self.hub.dispatch(listeners, 0.05)
            pub.service()

    def start(self) -> Pipeline:
        """Start the reader and the publishing thread."""
        self.reader.start()
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop and join both threads; close the publisher."""
        self.reader.stop()
        self._stop.set()
        self._thread.join(5.0)
        self.publisher.close()


def _receive(sub: zmq.Socket, seq: int, timeout_ms: int) -> tuple[int, int] | None:
    """Wait for the pose with ``seq``: (receive time, the reader's stamp) or None."""
    deadline = time.monotonic_ns() + timeout_ms * 1_000_000
    while True:
        left = (deadline - time.monotonic_ns()) // 1_000_000
        if left <= 0 or not sub.poll(max(1, left)):
            return None
        _topic, body = sub.recv_multipart()
        now = time.monotonic_ns()
        msg = json.loads(body)
        if msg["seq"] == seq:
            return now, int(msg["t_ns"])


def _warm_up(pipe: Pipeline, sub: zmq.Socket, transport: Transport, encode) -> int:
    """Send frames until the subscriber gets one (connection and open done)."""
    for k in range(1000):
        if pipe.reader.connected:
            transport.write(encode(k))
            if _receive(sub, k, 100) is not None:
                return k + 1
        else:
            threading.Event().wait(0.01)
    raise RuntimeError("no pose reached the subscriber during warm-up")


def measure(frames: int, rate_hz: float, protocol: str, transport_name: str) -> dict[str, Any]:
    """Run the benchmark; returns per-frame samples (ns) and the loss count."""
    transport = TRANSPORTS[transport_name]()
    pipe = Pipeline(transport, protocol).start()
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"pose")
    sub.connect(pipe.publisher.address)
    encode, mod = ENCODERS[protocol], SEQ_MOD[protocol]
    total, arrival, lost = [], [], 0
    try:
        k0 = _warm_up(pipe, sub, transport, encode)
        period_ns, start = round(1e9 / rate_hz), time.monotonic_ns()
        tick = threading.Event()
        for i in range(frames):
            target = start + i * period_ns
            while (now := time.monotonic_ns()) < target:
                tick.wait((target - now) / 1e9)
            k = (k0 + i) % mod
            t_write = time.monotonic_ns()
            transport.write(encode(k))
            got = _receive(sub, k, 1000)
            if got is None:
                lost += 1
                continue
            total.append(got[0] - t_write)
            arrival.append(got[1] - t_write)
    finally:
        sub.close()
        pipe.close()
        transport.close()
    return {"total": np.array(total), "arrival": np.array(arrival), "lost": lost}


def summarise(samples: np.ndarray) -> dict[str, float]:
    """p50 / p90 / p99 / max / mean in milliseconds."""
    if samples.size == 0:
        return {}
    ms = samples / 1e6
    return {"p50_ms": float(np.percentile(ms, 50)), "p90_ms": float(np.percentile(ms, 90)),
            "p99_ms": float(np.percentile(ms, 99)), "max_ms": float(ms.max()),
            "mean_ms": float(ms.mean())}


def plot(total: np.ndarray, path: Path, title: str) -> None:
    """Histogram and CDF of the total latency with the target line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    ms = np.sort(total / 1e6)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    ax1.hist(ms, bins=np.geomspace(max(ms[0], 1e-3), ms[-1] * 1.01, 60))
    ax1.set_xscale("log")
    ax1.set_xlabel("byte written -> pose received by SUB (ms)")
    ax1.set_ylabel("frames")
    ax2.plot(ms, np.arange(1, ms.size + 1) / ms.size)
    ax2.set_xscale("log")
    ax2.set_xlabel("latency (ms)")
    ax2.set_ylabel("fraction of frames <= latency")
    ticks = [v for v in TICKS_MS if ms[0] / 2 <= v <= ms[-1] * 2]
    for ax in (ax1, ax2):
        ax.axvline(TARGET_P99_MS, color="red", linestyle="--", label="p99 target 2 ms")
        ax.set_xticks(ticks, [f"{v:g}" for v in ticks])
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.legend()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Run the latency benchmark; returns 0 (whether the target was met is reported)."""
    ap = argparse.ArgumentParser(prog="bench_latency", description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path, help="output folder")
    ap.add_argument("--frames", type=int, default=2000, help="frames to time")
    ap.add_argument("--rate", type=float, default=200.0, help="frames per second")
    ap.add_argument("--protocol", choices=tuple(ENCODERS), default="native")
    ap.add_argument("--transport", choices=tuple(TRANSPORTS), default="pty")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    res = measure(args.frames, args.rate, args.protocol, args.transport)
    total, arrival = res["total"], res["arrival"]
    report = {
        "settings": {"frames": args.frames, "rate_hz": args.rate, "protocol": args.protocol,
                     "transport": args.transport},
        "host": {"python": sys.version.split()[0], "platform": platform.platform(),
                 "cpus": os.cpu_count()},
        "lost": res["lost"], "target_p99_ms": TARGET_P99_MS,
        "total": summarise(total), "arrival": summarise(arrival),
        "publish": summarise(total - arrival),
    }
    report["target_met"] = bool(report["total"]) and report["total"]["p99_ms"] <= TARGET_P99_MS
    (args.out / "latency.json").write_text(json.dumps(report, indent=1))
    if total.size:
        plot(total, args.out / "latency.png",
             f"{args.protocol} over {args.transport}: {total.size} frames at {args.rate:g} Hz")
    t = report["total"]
    print(f"latency {args.protocol}/{args.transport}: p50 {t.get('p50_ms', float('nan')):.3f} ms"
          f"  p99 {t.get('p99_ms', float('nan')):.3f} ms  max {t.get('max_ms', float('nan')):.3f}"
          f" ms  lost {res['lost']}  target p99 <= {TARGET_P99_MS:g} ms "
          f"{'met' if report['target_met'] else 'MISSED'}  -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
