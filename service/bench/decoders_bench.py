"""Decoder throughput benchmark: ``python -m service.bench.decoders_bench --out DIR``.

Feeds each protocol's decoder a prepared byte stream in ``--chunk``-sized pieces (as
a serial reader would) and reports megabytes (10**6 bytes) per second on one core,
best of ``--repeat`` runs, clean and with faults (seeded bursts and corruption).  Writes
``DIR/decoder_throughput.json``.  The target is >= 1 MB/s per core; the real links
carry at most 11.5 kB/s (115200 baud) and 0.96 kB/s (9600 baud).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from drivers.protocols import make_decoder
from drivers.protocols import sgi_dialbox as sgi
from service.base.cli_args import exit_rule_epilog, float_range, int_range
from sim_devices.faults import FaultInjector, FaultSpec, Write
from sim_devices.motion import make_motion
from sim_devices.tracker import TrackerSim

TARGET_MB_S = 1.0


def tracker_stream(protocol: str, seconds: float, faults: str) -> bytes:
    """Bytes a simulated tracker sends in ``seconds`` at 1 kHz through ``faults``."""
    sim = TrackerSim(protocol, make_motion("walk", seed=1, noise_deg=0.1), rate_hz=1000)
    inj = FaultInjector(FaultSpec.parse(faults))
    return b"".join(a.data for _t, make in sim.frames(seconds) for a in inj.apply(make())
                    if isinstance(a, Write))


def dial_stream(packets: int, faults: str) -> bytes:
    """Dial-box bytes: mostly dial reports, one button event in ten."""
    inj = FaultInjector(FaultSpec.parse(faults))
    out = []
    for i in range(packets):
        frame = (sgi.encode_button(i % 32, i % 20 == 0) if i % 10 == 0
                 else sgi.encode_dial(i % 8, i * 3))
        out += [a.data for a in inj.apply(frame) if isinstance(a, Write)]
    return b"".join(out)


#: case name -> (protocol, stream builder(scale, faults)).
CASES: dict[str, tuple[str, Callable[[float, str], bytes]]] = {
    "hatire": ("hatire", lambda s, f: tracker_stream("hatire", 30 * s, f)),
    "native": ("native", lambda s, f: tracker_stream("native", 20 * s, f)),
    "sgi": ("sgi", lambda s, f: dial_stream(int(300_000 * s), f)),
}
FAULTS = {"clean": "", "faulty": "burst=0.05,corrupt=0.02,seed=7"}


def measure(protocol: str, data: bytes, chunk: int, repeat: int) -> dict[str, float]:
    """Best-of-``repeat`` decode time of ``data`` fed in ``chunk``-byte pieces."""
    best, events, frames = float("inf"), 0, 0
    pieces = [data[i:i + chunk] for i in range(0, len(data), chunk)]
    for _ in range(repeat):
        dec = make_decoder(protocol)
        start = time.perf_counter()
        n = sum(len(dec.feed(p, 0)) for p in pieces)
        n += len(dec.flush(0))
        best = min(best, time.perf_counter() - start)
        events, frames = n, dec.stats.frames
    return {"bytes": len(data), "seconds": best, "mb_per_s": len(data) / best / 1e6,
            "frames": frames, "events": events, "events_per_s": events / best}


def run(out_dir: Path, scale: float, chunk: int, repeat: int) -> dict:
    """Run every case; return and write the results."""
    results: dict[str, dict] = {}
    for name, (protocol, build) in CASES.items():
        for label, faults in FAULTS.items():
            res = measure(protocol, build(scale, faults), chunk, repeat)
            res["meets_target"] = res["mb_per_s"] >= TARGET_MB_S
            results[f"{name}/{label}"] = res
    report = {"target_mb_per_s": TARGET_MB_S, "chunk_bytes": chunk, "repeat": repeat,
              "python": sys.version.split()[0], "machine": platform.machine(),
              "processor": platform.processor(), "results": results}
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "decoder_throughput.json").write_text(json.dumps(report, indent=2) + "\n")
    return report


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point."""
    p = argparse.ArgumentParser(prog="holo-bench decoders",
                                description="Measure decoder throughput (MB/s per core).",
                                epilog=exit_rule_epilog())
    p.add_argument("--out", metavar="DIR", type=Path, required=True,
                   help="directory for the JSON report")
    p.add_argument("--scale", metavar="X", type=float_range(0, lo_open=True), default=1.0,
                   help="stream size factor (1: ~1 MB)")
    p.add_argument("--chunk", metavar="N", type=int_range(1), default=4096,
                   help="bytes per feed() call")
    p.add_argument("--repeat", metavar="N", type=int_range(1), default=3,
                   help="runs per case (best is kept)")
    args = p.parse_args(argv)
    report = run(args.out, args.scale, args.chunk, args.repeat)
    for name, res in report["results"].items():
        flag = "ok" if res["meets_target"] else "BELOW TARGET"
        print(f"{name:15s} {res['mb_per_s']:7.2f} MB/s  {res['events_per_s']:10.0f} events/s"
              f"  ({res['bytes']} bytes)  {flag}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
