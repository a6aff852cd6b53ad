"""Benchmark of the render service (``holo-bench service``).

Usage::

    python -m service.bench.service_bench --out DIR [--quick] [--seconds S]

Parts (each a real socket on 127.0.0.1; services are real ``holo-service``
subprocesses, killed at the end):

``transport``
    One frame (colour + depth of the default display, 5 x 120 x 160) published and
    received in lockstep, ours (:class:`~service.net.frame_stream.FrameStream` +
    :func:`~service.net.protocol.parse_reply`) against raw pyzmq zero-copy
    ``send_multipart`` of the same buffers.  Target: ours / raw <= 1.5 (p50).
``round_trip``
    ``ping`` and a 7-object ``update_objects`` through :class:`ServiceClient`, p50 / p99.
``game``
    Updates/s and refreshes/s with the game scene on the default display.
``workers``
    Updates/s against the worker count (0 = render in process, 1, 2, 3).
``motion_to_photon``
    A tracker pose written into a pty (native protocol) -> the device driver path
    (reader, publisher) -> the service (``--devices``) -> the first frame a
    subscriber receives whose header carries that pose, with renders capped at
    15 Hz.  Target: p95 <= 20 ms.

Writes ``service.json``, ``service_workers.csv`` and ``service.png`` into ``--out``
and prints a summary.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zmq

from drivers.protocols import native
from service.base.cli_args import comma_list, exit_rule_epilog, float_range, int_range, plain_help
from service.bench import chaos_bench
from service.bench.charts import save_chart
from service.bench.running import Running
from service.bench.running import port as _port
from service.net import protocol
from service.net.client import FrameSubscriber
from service.net.frame_stream import FrameStream

TRANSPORT_TARGET = 1.5
MTP_TARGET_MS = 20.0
SHAPE = (5, 120, 160)
ROOT = Path(__file__).resolve().parents[2]


def _pct(samples: list[float]) -> dict[str, float]:
    a = np.asarray(samples, float)
    if a.size == 0:
        return {"n": 0}
    return {
        "n": int(a.size),
        "p50": float(np.percentile(a, 50)),
        "p95": float(np.percentile(a, 95)),
        "p99": float(np.percentile(a, 99)),
        "mean": float(a.mean()),
        "max": float(a.max()),
    }


# ---------------------------------------------------------------- transport
def _lockstep(send, sub: zmq.Socket, receive, n: int) -> list[float]:
    """Milliseconds per frame, one in flight: send, then receive it."""
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        send()
        if not sub.poll(2000):
            raise RuntimeError("a frame was lost in the transport benchmark")
        receive(sub.recv_multipart(copy=False))
        out.append((time.perf_counter() - t0) * 1e3)
    return out


def _sub(ctx: zmq.Context, address: str) -> zmq.Socket:
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.connect(address)
    return sub


def _connected(send, sub: zmq.Socket) -> None:
    """Publish until the subscription is through (PUB drops before it)."""
    for _ in range(500):
        send()
        if sub.poll(20):
            while sub.poll(50):
                sub.recv_multipart()
            return
    raise RuntimeError("subscriber never connected")


def _raw_pair(pub: zmq.Socket, colour: np.ndarray, depth: np.ndarray) -> tuple:
    """Send and receive functions of the raw pyzmq baseline (zero-copy both ways)."""
    header = json.dumps(
        {
            "seq": 1,
            "arrays": [
                {"dtype": "uint8", "shape": list(colour.shape)},
                {"dtype": "float32", "shape": list(depth.shape)},
            ],
        }
    ).encode()

    def send() -> None:
        pub.send_multipart([b"frame", header, colour, depth], copy=False)

    def recv(frames: list) -> None:
        json.loads(frames[1].bytes)
        np.frombuffer(frames[2].buffer, np.uint8).reshape(colour.shape)
        np.frombuffer(frames[3].buffer, np.float32).reshape(depth.shape)

    return send, recv


def bench_transport(n: int) -> dict[str, Any]:
    """Ours against raw zero-copy pyzmq, same buffers, same sockets kind."""
    ctx = zmq.Context()
    rng = np.random.default_rng(0)
    colour = rng.integers(0, 255, (*SHAPE, 3), np.uint8)
    depth = rng.random(SHAPE).astype(np.float32)
    raw_pub = ctx.socket(zmq.PUB)
    raw_pub.setsockopt(zmq.LINGER, 0)
    raw_pub.bind("tcp://127.0.0.1:0")
    raw_sub = _sub(ctx, raw_pub.getsockopt_string(zmq.LAST_ENDPOINT))
    ours = FrameStream(ctx, "tcp://127.0.0.1:0", "bench")
    our_sub = _sub(ctx, ours.address)
    raw_send, raw_recv = _raw_pair(raw_pub, colour, depth)

    def our_send() -> None:
        ours.publish({"refresh": 1, "render_id": 1}, [colour, depth], ["colour", "depth"])

    def our_recv(frames: list) -> None:
        protocol.parse_reply([f.buffer for f in frames[1:]])

    try:
        _connected(raw_send, raw_sub)
        _connected(our_send, our_sub)
        raw, mine = [], []
        for _ in range(5):  # interleaved rounds: both see the same machine state
            raw += _lockstep(raw_send, raw_sub, raw_recv, n // 5)
            mine += _lockstep(our_send, our_sub, our_recv, n // 5)
    finally:
        for s in (raw_pub, raw_sub, our_sub):
            s.close(0)
        ours.close()
        ctx.term()
    r, m = _pct(raw), _pct(mine)
    return {
        "frame_bytes": int(colour.nbytes + depth.nbytes),
        "raw_ms": r,
        "ours_ms": m,
        "ratio_p50": m["p50"] / r["p50"],
        "ratio_mean": m["mean"] / r["mean"],
        "target": TRANSPORT_TARGET,
        "target_met": m["p50"] / r["p50"] <= TRANSPORT_TARGET,
    }


def bench_round_trip(n: int) -> dict[str, Any]:
    """Round trips (ms) of ping and update_objects against a service with the game scene."""
    with Running("--scene", "game", "--workers", "1", "--max-update-hz", "10") as svc:
        c = svc.client
        ping, update = [], []
        ups = [
            {"index": i, "position": [0.1 * i, 0.0, 0.0], "velocity": [0.0, 0.1, 0.0]}
            for i in range(7)
        ]
        for _ in range(n):
            t0 = time.perf_counter()
            c.ping()
            t1 = time.perf_counter()
            c.update_objects(ups)
            t2 = time.perf_counter()
            ping.append((t1 - t0) * 1e3)
            update.append((t2 - t1) * 1e3)
    return {"ping_ms": _pct(ping), "update_objects_ms": _pct(update), "ping_samples": ping}


def _rates(svc: Running, seconds: float) -> dict[str, float]:
    s0, t0 = svc.client.stats(), time.monotonic()
    threading.Event().wait(seconds)
    s1, t1 = svc.client.stats(), time.monotonic()
    dt = t1 - t0
    return {
        "updates_per_s": (s1["updates"] - s0["updates"]) / dt,
        "refreshes_per_s": (s1["refreshes"] - s0["refreshes"]) / dt,
        "incomplete_per_s": (s1["incomplete_updates"] - s0["incomplete_updates"]) / dt,
        "render_ms_p50": s1["render_ms_p50"],
        "refresh_ms_p50": s1["refresh_ms_p50"],
        "refresh_overruns": s1["refresh_overruns"] - s0["refresh_overruns"],
    }


def bench_workers(
    counts: list[int],
    seconds: float,
    splits: tuple[str, ...] = ("frames", "bands"),
    rounds: int = 1,
) -> list[dict[str, Any]]:
    """Updates/s and refreshes/s with the game scene per worker count and split.

    ``frames``: each worker renders whole updates for successive rendezvous (the
    default); ``bands``: every worker a band of each update.  0 workers renders in
    the service process (listed once, as ``in_process``).  With ``rounds`` > 1
    every configuration is measured once per round, in turn, so a load that comes
    and goes on a shared machine hits all of them; one row per round
    (``round``), and :func:`median_rows` summarises.
    """
    configs = [(n, sp) for n in counts for sp in (splits if n > 0 else ("in_process",))]
    out = []
    for r in range(rounds):
        for n, split in configs:
            args = ["--scene", "game", "--workers", str(n)]
            if n > 0:
                args += ["--split", split]
            with Running(*args) as svc:
                row = {"workers": n, "split": split, "round": r}
                if not svc.wait_updates(3, 120):
                    out.append({**row, "error": "no updates"})
                    continue
                out.append({**row, **_rates(svc, seconds)})
    return out


def median_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (workers, split): the median of each rate over the rounds."""
    keys = ("updates_per_s", "refreshes_per_s", "incomplete_per_s", "render_ms_p50",
            "refresh_ms_p50", "refresh_overruns")  # fmt: skip
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for r in rows:
        if "updates_per_s" in r:
            groups.setdefault((r["workers"], r["split"]), []).append(r)
    return [
        {"workers": n, "split": sp, "rounds": len(g),
         **{k: float(np.median([x[k] for x in g if x.get(k) is not None] or [np.nan]))
            for k in keys}}
        for (n, sp), g in groups.items()
    ]  # fmt: skip


def write_csv(rows: list[dict[str, Any]], path: Path) -> None:
    """The workers table as CSV (one row per worker count and split)."""
    keys = ["workers", "split", "round", "updates_per_s", "refreshes_per_s", "incomplete_per_s",
            "render_ms_p50", "refresh_ms_p50", "refresh_overruns"]  # fmt: skip
    lines = [",".join(keys)]
    lines += [",".join("" if r.get(k) is None else str(r.get(k)) for k in keys) for r in rows]
    path.write_text("\n".join(lines) + "\n")


# --------------------------------------------------------- motion to photon
class FrameStamps(threading.Thread):
    """Receives frames on a thread; keeps (receive ns, pose_seq) of each."""

    def __init__(self, address: str) -> None:
        super().__init__(name="mtp-frames", daemon=True)
        self.sub = FrameSubscriber(address, hwm=1000)
        self.stamps: list[tuple[int, int | None]] = []
        self.detail: list[tuple[int, int | None, int | None]] = []  # (publish, pose stamp, seq)
        self.stop = threading.Event()

    def run(self) -> None:
        """Take frames until stopped."""
        try:
            while not self.stop.is_set():
                got = self.sub.next(0.1)
                if got is not None:
                    h = got[0]
                    self.stamps.append((time.monotonic_ns(), h.get("pose_seq")))
                    self.detail.append((h["t_ns"], h.get("pose_t_ns"), h.get("pose_seq")))
        finally:
            self.sub.close()


def _devices(pub: str) -> tuple[subprocess.Popen, int]:
    """``holo-devices`` reading the slave side of a fresh pty; returns (proc, master fd)."""
    # deferred: POSIX only: the module still imports elsewhere
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    cmd = [
        sys.executable,
        "-m",
        "drivers.commands.holo_devices",
        "--tracker",
        os.ttyname(slave),
        "--tracker-protocol",
        "native",
        "--pub",
        pub,
        "--watchdog",
        "0",
    ]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdin=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(slave)
    return proc, master


def _first_reflecting(stamps: list[tuple[int, int | None]], seq: int, after_ns: int) -> int | None:
    for t, s in stamps:
        if t >= after_ns and s is not None and s >= seq:
            return t
    return None


def bench_motion_to_photon(n: int, rate_hz: float = 20.0, io_threads: int = 2) -> dict[str, Any]:
    """Pose written into the tracker's pty -> first frame carrying it (ms).

    ``published_ms``: to the service's publication of that frame (its header's
    ``t_ns``, same host clock): the issue's definition.  ``ms``: to its receipt by a
    subscriber in this process (adds the 672 kB transfer and the subscriber's wake-up).
    """
    pub = f"tcp://127.0.0.1:{_port()}"
    devices, master = _devices(pub)
    sent: list[tuple[int, int]] = []
    try:
        with Running(
            "--scene",
            "game",
            "--workers",
            "1",
            "--max-update-hz",
            "15",
            "--devices",
            pub,
            "--io-threads",
            str(io_threads),
        ) as svc:
            frames = FrameStamps(svc.frames)
            frames.start()
            try:
                svc.wait_updates(3, 120)
                k = _warm_up_poses(master, frames)
                stats = _send_poses(master, k + 10, n, rate_hz, sent)
                threading.Event().wait(0.5)
            finally:
                frames.stop.set()
                frames.join(5)
            svc_stats = svc.client.stats()
    finally:
        devices.terminate()
        try:
            devices.wait(5)
        except subprocess.TimeoutExpired:
            devices.kill()
        os.close(master)
    return _mtp_result(sent, frames, rate_hz, stats, svc_stats)


def _warm_up_poses(master: int, frames: FrameStamps, timeout_s: float = 30.0) -> int:
    """Write poses until frames carry one (device and service connected); next seq."""
    k, start = 1, time.monotonic()
    while time.monotonic() - start < timeout_s and not any(s for _, s in frames.stamps):
        os.write(master, native.encode_pose(k, k * 1000, (0.0, 0.0, 600.0), (1.0, 0, 0, 0)))
        k += 1
        threading.Event().wait(0.05)  # pacing, like a tracker
    return k


def _mtp_result(
    sent: list[tuple[int, int]],
    frames: FrameStamps,
    rate_hz: float,
    jitter: float,
    svc_stats: dict[str, Any],
) -> dict[str, Any]:
    lat = [
        (t - t0) / 1e6
        for seq, t0 in sent
        if (t := _first_reflecting(frames.stamps, seq, t0)) is not None
    ]
    res = _pct(lat)
    parts = _breakdown(sent, frames)
    published = parts["to_publish"]
    return {
        "published_ms": published,
        "published_samples": _to_publish(sent, frames),
        "target_met_published": bool(published.get("p95", 1e9) <= MTP_TARGET_MS),
        "ms": res,
        "samples": lat,
        "lost": len(sent) - len(lat),
        "pose_rate_hz": rate_hz,
        "breakdown_ms": parts,
        "write_jitter_ms": jitter,
        "target_ms": MTP_TARGET_MS,
        "target_met_received": bool(res.get("p95", 1e9) <= MTP_TARGET_MS),
        **{
            k: svc_stats[k]
            for k in ("updates_per_s", "refreshes_per_s", "tick_late_ms_p50", "tick_late_ms_p95")
        },
    }


def _to_publish(sent: list[tuple[int, int]], frames: FrameStamps) -> list[float]:
    """Per pose: ms from its write to the publication of the first frame carrying it."""
    first: dict[int, int] = {}
    for pub, pose_t, seq in frames.detail:
        if seq is not None and pose_t is not None and seq not in first:
            first[seq] = pub
    return [(first[seq] - t0) / 1e6 for seq, t0 in sent if seq in first]


def _breakdown(sent: list[tuple[int, int]], frames: FrameStamps) -> dict[str, Any]:
    """p50/p95 of write -> driver stamp, driver stamp -> frame published, publish -> received."""
    first: dict[int, tuple[int, int, int]] = {}
    for (recv, _), (pub, pose_t, seq) in zip(frames.stamps, frames.detail, strict=True):
        if seq is not None and pose_t is not None and seq not in first:
            first[seq] = (recv, pub, pose_t)
    parts: dict[str, list[float]] = {"driver": [], "service": [], "transport": [], "to_publish": []}
    for seq, t0 in sent:
        if seq in first:
            recv, pub, pose_t = first[seq]
            parts["driver"].append((pose_t - t0) / 1e6)
            parts["service"].append((pub - pose_t) / 1e6)
            parts["transport"].append((recv - pub) / 1e6)
            parts["to_publish"].append((pub - t0) / 1e6)
    return {k: _pct(v) for k, v in parts.items()}


def _send_poses(master: int, k0: int, n: int, rate_hz: float, sent: list[tuple[int, int]]) -> float:
    """Write ``n`` poses on an absolute schedule; returns the mean lateness (ms).

    Each write gets a random offset within its period, so pose arrivals fall at
    every phase of the service's refresh ticks (a rate commensurate with the
    refresh rate would sample one phase only).
    """
    period, start, late = 1.0 / rate_hz, time.monotonic(), []
    tick = threading.Event()
    rng = np.random.default_rng(5)
    for i in range(n):
        target = start + (i + rng.random()) * period
        while (now := time.monotonic()) < target:
            tick.wait(target - now)
        k = k0 + i
        x = 50.0 * np.sin(i / 10.0)  # the head sways: each pose differs
        frame = native.encode_pose(k, k * 1000, (x, 0.0, 600.0), (1.0, 0.0, 0.0, 0.0))
        sent.append((k, time.monotonic_ns()))
        os.write(master, frame)
        late.append((time.monotonic() - target) * 1e3)
    return float(np.mean(late))


# --------------------------------------------------------------- reporting
def plot(res: dict[str, Any], path: Path) -> None:
    """Four panels: transport, round trip, workers, motion-to-photon CDF."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    t = res["transport"]
    ax[0, 0].bar(["raw pyzmq", "holo frame stream"], [t["raw_ms"]["p50"], t["ours_ms"]["p50"]])
    ax[0, 0].set(
        title=f"frame transport p50 ({t['frame_bytes'] / 1e3:.0f} kB), "
        f"ratio {t['ratio_p50']:.2f} (target <= {TRANSPORT_TARGET})",
        ylabel="ms",
    )
    rt = res["round_trip"]
    ax[0, 1].hist(rt["ping_samples"], bins=40)
    ax[0, 1].set(
        title=f"ping round trip p50 {rt['ping_ms']['p50']:.2f} ms, "
        f"p99 {rt['ping_ms']['p99']:.2f} ms",
        xlabel="ms",
    )
    w = [x for x in res["workers"] if "updates_per_s" in x]
    base = [x for x in w if x["workers"] == 0]
    for i, split in enumerate(("frames", "bands")):
        pts = base + [x for x in w if x.get("split") == split]
        if len(pts) > len(base):
            xs = [x["workers"] for x in pts]
            ax[1, 0].plot(xs, [x["updates_per_s"] for x in pts], "o-", color=f"C{i}",
                          label=f"updates/s ({split})")  # fmt: skip
            ax[1, 0].plot(xs, [x["refreshes_per_s"] / 10 for x in pts], "s--", color=f"C{i}",
                          label=f"refreshes/s / 10 ({split})")  # fmt: skip
    ax[1, 0].set(title="game scene, 5 x 160 x 120 (0 = in process)", xlabel="workers")
    ax[1, 0].legend()
    mtp = res["motion_to_photon"]
    for label, samples in (
        ("to a subscriber", mtp["samples"]),
        ("to publication", mtp.get("published_samples", [])),
    ):
        m = np.sort(samples)
        if m.size:
            ax[1, 1].plot(m, np.arange(1, m.size + 1) / m.size, label=label)
    ax[1, 1].axvline(MTP_TARGET_MS, color="r", ls=":", label="target p95")
    ax[1, 1].set(title="motion to photon (pose into the pty -> frame)", xlabel="ms", ylabel="CDF")
    ax[1, 1].legend()
    fig.tight_layout()
    save_chart(fig, path, dpi=100)


def _step(what: str) -> None:
    """One progress line on stderr (the summary goes to stdout at the end)."""
    print(f"holo-bench service: {what}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    """``holo-bench service``; returns the exit status."""
    p = argparse.ArgumentParser(
        prog="holo-bench service",
        description=plain_help(__doc__),
        epilog=exit_rule_epilog(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", metavar="DIR", default="bench-out",
                   help="output folder (default bench-out)")
    p.add_argument("--quick", action="store_true", help="fewer samples (a smoke run)")
    p.add_argument(
        "--seconds", metavar="S", type=float_range(0, lo_open=True), default=8.0,
        help="measuring time per worker count",
    )
    p.add_argument(
        "--workers", metavar="N,...", type=comma_list(int_range(0, 64)), default="0,1,2,3",
        help="worker counts to compare, comma-separated",
    )
    p.add_argument(
        "--rounds", metavar="N", type=int_range(1), default=2,
        help="rounds of the worker comparison"
    )
    p.add_argument(
        "--chaos-seconds", metavar="S", type=float_range(0), default=None,
        help="length of the chaos part (holo-bench chaos: workers killed and stopped; "
        "default 60, 10 with --quick; 0 skips it)",
    )
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    q = args.quick
    counts = args.workers
    res: dict[str, Any] = {
        "host": {
            "machine": platform.machine(),
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "pyzmq": zmq.__version__,
            "libzmq": zmq.zmq_version(),
        }
    }
    _step("transport (raw PUB/SUB against the frame codec)")
    res["transport"] = bench_transport(50 if q else 500)
    _step("request round trip")
    res["round_trip"] = bench_round_trip(100 if q else 1000)
    _step(f"render rates with workers {counts[:2] if q else counts} (services started in turn)")
    res["workers_rounds"] = bench_workers(
        counts[:2] if q else counts, 3.0 if q else args.seconds, rounds=1 if q else args.rounds
    )
    res["workers"] = median_rows(res["workers_rounds"])
    res["game"] = next((w for w in res["workers"] if w.get("workers") == 1), res["workers"][0])
    _step("motion to photon (a simulated tracker through the service)")
    res["motion_to_photon"] = bench_motion_to_photon(60 if q else 400)
    if not q:  # the same with one libzmq I/O thread (frames share it with worker replies)
        res["motion_to_photon_1io"] = bench_motion_to_photon(400, io_threads=1)
    chaos_s = args.chaos_seconds if args.chaos_seconds is not None else (10.0 if q else 60.0)
    if chaos_s > 0:
        _step(f"chaos: a worker killed and another stopped every 5 s for {chaos_s:g} s")
        chaos, times = chaos_bench.run_chaos(max(5.0, chaos_s))
        chaos_bench.write(chaos, times, out)
        res["chaos"] = {k: v for k, v in chaos.items() if k not in ("events", "rss_kb", "trace")}
    (out / "service.json").write_text(json.dumps(res, indent=1))
    write_csv(res["workers_rounds"], out / "service_workers.csv")
    plot(res, out / "service.png")
    print(summary(res))
    if "chaos" in res:
        print(chaos_bench.summary(chaos))
    return 0


def summary(res: dict[str, Any]) -> str:
    """One paragraph of the headline figures."""
    t, rt, m = res["transport"], res["round_trip"], res["motion_to_photon"]
    nan = float("nan")
    w = ", ".join(
        f"{x['workers']} {x.get('split')}: {x.get('updates_per_s', 0):.1f}" for x in res["workers"]
    )
    return (
        f"transport p50 ours/raw {t['ratio_p50']:.2f} (target <= {TRANSPORT_TARGET}); "
        f"ping p50 {rt['ping_ms']['p50']:.2f} ms p99 {rt['ping_ms']['p99']:.2f} ms; "
        f"update_objects p50 {rt['update_objects_ms']['p50']:.2f} ms "
        f"p99 {rt['update_objects_ms']['p99']:.2f} ms; updates/s by workers {w}; "
        f"game (1 worker) refreshes/s {res['game'].get('refreshes_per_s', 0):.1f}; "
        f"motion-to-photon (to publication) p50 {m['published_ms'].get('p50', nan):.1f} ms "
        f"p95 {m['published_ms'].get('p95', nan):.1f} ms (target <= {MTP_TARGET_MS}); "
        f"(to a subscriber) p50 {m['ms'].get('p50', nan):.1f} ms "
        f"p95 {m['ms'].get('p95', nan):.1f} ms; lost {m['lost']}"
    )


if __name__ == "__main__":
    raise SystemExit(main())
