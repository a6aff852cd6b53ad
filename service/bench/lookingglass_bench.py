"""Looking Glass interleave benchmark: ``holo-bench lookingglass --out DIR``.

Interleaves a 45-view stack (the 5 x 9 quilt's tiles, 819x455 each) onto the sample
2560x1600 panel (``examples/lookingglass-visual.json``) with each numba thread count
from 1 to the machine's, in turns (1, 2, ..., 1, 2, ...), and reports per count the
median wall milliseconds and the median CPU milliseconds of the calling process per
interleave.  The target is <= 2 ms a refresh (``TARGET_MS``).  Writes
``DIR/lookingglass.json``, ``.csv`` and ``.png``; the table is made once per
calibration and its time is reported beside (``table_ms``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numba
import numpy as np

from service.base.cli_args import exit_rule_epilog, int_range
from service.bench.charts import save_chart
from service.lookingglass import Interleaver, load_calibration

TARGET_MS = 2.0
EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "lookingglass-visual.json"
#: The view size: a 4096x4096 quilt of 5 x 9 tiles.
VIEW = (455, 819)


def measure(il: Interleaver, views: np.ndarray, threads: list[int], repeat: int) -> dict:
    """Wall and process-CPU ms per interleave for each thread count, interleaved turns."""
    out = np.empty(il.shape, np.uint8)
    il(views, out)  # compile or load the kernel, make the sample maps
    wall: dict[int, list[float]] = {t: [] for t in threads}
    cpu: dict[int, list[float]] = {t: [] for t in threads}
    for _ in range(repeat):
        for t in threads:
            numba.set_num_threads(t)
            w0, c0 = time.perf_counter(), time.process_time()
            il(views, out)
            wall[t].append(1e3 * (time.perf_counter() - w0))
            cpu[t].append(1e3 * (time.process_time() - c0))
    return {str(t): {"wall_ms_median": float(np.median(wall[t])),
                     "wall_ms_min": float(np.min(wall[t])),
                     "cpu_ms_median": float(np.median(cpu[t]))} for t in threads}


def run(out_dir: Path, repeat: int, calibration: Path = EXAMPLE) -> dict:
    """Measure, write the JSON and the chart, return the results."""
    cal = load_calibration(calibration)
    start = time.perf_counter()
    il = Interleaver(cal)
    table_ms = 1e3 * (time.perf_counter() - start)
    views = np.random.default_rng(1).integers(0, 256, (cal.views, *VIEW, 3), np.uint8)
    threads = list(range(1, numba.config.NUMBA_NUM_THREADS + 1))
    results = measure(il, views, threads, repeat)
    best = min(r["wall_ms_median"] for r in results.values())
    report = {
        "panel": [cal.screen_w, cal.screen_h], "views": cal.views, "view_size": VIEW[::-1],
        "subpixels": 3 * cal.screen_w * cal.screen_h, "table_ms": round(table_ms, 1),
        "threads": results, "target_ms": TARGET_MS, "meets_target": best <= TARGET_MS,
        "machine": {"cpus": os.cpu_count(), "load": os.getloadavg()[0],
                    "python": platform.python_version()},
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "lookingglass.json").write_text(json.dumps(report, indent=1))
    lines = ["threads,wall_ms_median,wall_ms_min,cpu_ms_median,target_ms"]
    lines += [f"{t},{r['wall_ms_median']:.3f},{r['wall_ms_min']:.3f},{r['cpu_ms_median']:.3f},"
              f"{TARGET_MS}" for t, r in results.items()]
    (out_dir / "lookingglass.csv").write_text("\n".join(lines) + "\n")
    _chart(report, out_dir / "lookingglass.png")
    return report


def _chart(report: dict, path: Path) -> None:
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt


    threads = [int(t) for t in report["threads"]]
    fig, ax = plt.subplots(figsize=(6, 4))
    for key, label in (("wall_ms_median", "wall"), ("cpu_ms_median", "CPU (process)")):
        ax.plot(threads, [report["threads"][str(t)][key] for t in threads], "o-", label=label)
    ax.axhline(report["target_ms"], color="red", linestyle="--", label="target")
    ax.set(xlabel="numba threads", ylabel="ms per interleave",
           title=f"Looking Glass interleave, {report['views']} views onto "
                 f"{report['panel'][0]}x{report['panel'][1]}")
    ax.set_xticks(threads)
    ax.legend()
    save_chart(fig, path)


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    p = argparse.ArgumentParser(
        prog="holo-bench lookingglass",
        description="Time the Looking Glass interleave: 45 views onto a 2560x1600 panel, "
        "per numba thread count (target 2 ms).",
        epilog=exit_rule_epilog())
    p.add_argument("--out", metavar="DIR", default="bench-out", help="output folder")
    p.add_argument("--repeat", metavar="N", type=int_range(1, 1000), default=15,
                   help="turns per thread count (default 15)")
    args = p.parse_args(argv)
    report = run(Path(args.out), args.repeat)
    for t, r in report["threads"].items():
        print(f"{t} threads: {r['wall_ms_median']:.1f} ms wall, {r['cpu_ms_median']:.1f} ms "
              f"CPU per interleave (target {TARGET_MS} ms)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
