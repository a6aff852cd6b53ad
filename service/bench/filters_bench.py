"""Benchmark: jitter against lag for every pose filter and a sweep of its parameters.

Usage::

    python -m service.bench.filters_bench --out DIR [--fixture PATH] [--seed N] [--lead-ms MS]

Data:

* simulated motion, generated here with a seeded RNG at a nominal 80 Hz with
  irregular sample intervals (+-20 %): ``still`` (a constant pose plus noise),
  ``sway`` (a sum of sinusoids per channel plus noise) and ``turn`` (minimum-jerk
  head turns whose yaw crosses +-180 degrees plus noise), each with exact truth;
* the recorded Hatire capture (opentrack over PuTTY): replayed through
  :class:`drivers.recording.RawCaptureReader` and the real Hatire decoder; it has
  no timestamps, so frame times come from the frame counter at a nominal rate
  (4765 frames in one minute, about 79.4 Hz; counter gaps become longer intervals).

Figures of merit (angles, degrees; positions in ``results.csv`` too):

* **lag**: the delay ``tau`` that minimises ``RMS(filtered(t) - reference(t - tau))``
  (a cross-correlation peak found by least squares, 1 ms resolution), on ``sway``
  against truth, and on the capture against the raw samples;
* **jitter**: on ``still``, the RMS deviation from truth of the filtered position
  and velocity; on the capture (no truth), the RMS of the velocity's deviation from
  its centred 0.25 s moving average (high-frequency velocity noise);
* **prediction error**: RMS of ``predict(lead) - truth(t + lead)`` on ``turn`` and
  ``sway`` (default lead 50 ms).

Writes ``results.csv``, ``results.json``, ``jitter_lag_sim.png``,
``jitter_lag_capture.png`` and ``turn_trace.png`` into ``--out`` and prints a table.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from drivers.filters import (
    FILTERS,
    AlphaBetaGammaSettings,
    AlphaBetaSettings,
    FilterSettings,
    OneEuroSettings,
    RawSettings,
    predict_ahead,
    run_filter,
)
from drivers.recording import RawCaptureReader
from service.base.cli_args import exit_rule_epilog, float_range, plain_help
from service.bench.charts import save_chart

if TYPE_CHECKING:
    from matplotlib.figure import Figure

DEFAULT_FIXTURE = Path("/work/shared/fixtures/hatire/opentrack-putty-capture.log")
#: Nominal Hatire capture rate: 4765 frames in one minute.
CAPTURE_RATE_HZ = 4765 / 60.0
CAPTURE_BANNER = 79
ANGLES = slice(3, 6)
POSITIONS = slice(0, 3)
LAG_GRID_S = np.arange(-0.05, 0.5005, 0.001)
THETAS = (0.3, 0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.95)


@dataclass(frozen=True)
class Dataset:
    """One input sequence.

    Attributes
    ----------
    name : str
    t : ndarray, shape (N,)
        Seconds.
    samples : ndarray, shape (N, 6)
        What the tracker reports (angles wrapped into +-180 for simulations).
    truth : ndarray, shape (N, 6) or None
        True unwrapped pose, when known.
    truth_vel : ndarray, shape (N, 6) or None
    truth_fn : callable or None
        ``truth_fn(t) -> (pose (M, 6), velocity (M, 6))`` for prediction targets.
    """

    name: str
    t: np.ndarray
    samples: np.ndarray
    truth: np.ndarray | None = None
    truth_vel: np.ndarray | None = None
    truth_fn: object = None


def sweep() -> Iterator[tuple[str, str, str, FilterSettings]]:
    """Every (filter, chart line, label, settings) the benchmark runs."""
    yield "raw", "raw", "-", RawSettings()
    for th in THETAS:
        yield "alpha-beta", "alpha-beta", f"theta={th}", AlphaBetaSettings.from_theta(th)
    for th in THETAS:
        settings = AlphaBetaGammaSettings.from_theta(th)
        yield "alpha-beta-gamma", "alpha-beta-gamma", f"theta={th}", settings
    for beta in (0.0, 0.01, 0.05):
        for fc in (0.25, 0.5, 1.0, 2.0, 4.0, 8.0):
            settings = OneEuroSettings(min_cutoff=fc, beta=beta, d_cutoff=2.0)
            yield "one-euro", f"one-euro beta={beta} dc=2", f"fc={fc} beta={beta} dc=2", settings
    for dc in (0.5, 1.0, 5.0, 10.0):
        settings = OneEuroSettings(min_cutoff=1.0, beta=0.01, d_cutoff=dc)
        yield "one-euro", "one-euro fc=1 beta=0.01", f"fc=1.0 beta=0.01 dc={dc}", settings


def _irregular_times(rng: np.random.Generator, duration_s: float, rate: float) -> np.ndarray:
    n = int(duration_s * rate)
    return np.cumsum(rng.uniform(0.8, 1.2, n) / rate)


def _noisy(rng: np.random.Generator, truth: np.ndarray) -> np.ndarray:
    """Add tracker noise (0.3 mm, 0.15 deg) and wrap angles into [-180, 180)."""
    sigma = np.array([0.3, 0.3, 0.3, 0.15, 0.15, 0.15])
    out = truth + rng.normal(0.0, 1.0, truth.shape) * sigma
    out[:, ANGLES] = (out[:, ANGLES] + 180.0) % 360.0 - 180.0
    return out


def _sway_fn(rng: np.random.Generator):
    """Sum of three sinusoids per channel (0.15, 0.4, 0.9 Hz) around a rest pose."""
    freqs = np.array([0.15, 0.4, 0.9])
    amp = np.array([20.0, 10.0, 15.0, 8.0, 5.0, 3.0])[:, None] / np.array([1.0, 2.0, 4.0])
    phase = rng.uniform(0, 2 * np.pi, (6, 3))
    rest = np.array([0.0, 0.0, 600.0, 170.0, -5.0, 0.0])

    def fn(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = 2 * np.pi * freqs
        arg = w[None, None, :] * t[:, None, None] + phase[None]
        pos = rest + np.sum(amp[None] * np.sin(arg), axis=2)
        vel = np.sum(amp[None] * w * np.cos(arg), axis=2)
        return pos, vel

    return fn


def _min_jerk(t: np.ndarray, t0: float, dur: float, a: float, b: float):
    """Minimum-jerk move from ``a`` to ``b``: position and velocity, each (M,)."""
    tau = np.clip((t - t0) / dur, 0.0, 1.0)
    pos = a + (b - a) * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)
    vel = (b - a) / dur * (30 * tau**2 - 60 * tau**3 + 30 * tau**4)
    return pos, vel


def _turn_fn(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Yaw 150 -> 250 deg (crossing 180) in 0.5 s at 2 s, back in 0.6 s at 5 s; a nod."""
    pos = np.zeros((len(t), 6))
    vel = np.zeros((len(t), 6))
    pos[:, 2] = 600.0
    y1, v1 = _min_jerk(t, 2.0, 0.5, 150.0, 250.0)
    y2, v2 = _min_jerk(t, 5.0, 0.6, 0.0, -100.0)
    p1, w1 = _min_jerk(t, 3.0, 0.4, 0.0, -20.0)
    p2, w2 = _min_jerk(t, 6.0, 0.4, 0.0, 20.0)
    pos[:, 3], vel[:, 3] = y1 + y2, v1 + v2
    pos[:, 4], vel[:, 4] = p1 + p2, w1 + w2
    return pos, vel


def simulated(seed: int) -> list[Dataset]:
    """The three simulated datasets (still, sway, turn), reproducible from ``seed``."""
    rng = np.random.default_rng(seed)
    out = []
    t = _irregular_times(rng, 10.0, 80.0)
    rest = np.tile([0.0, 0.0, 600.0, 5.0, -3.0, 1.0], (len(t), 1))
    out.append(Dataset("still", t, _noisy(rng, rest), rest, np.zeros_like(rest)))
    sway = _sway_fn(rng)
    for name, dur, fn in (("sway", 20.0, sway), ("turn", 8.0, _turn_fn)):
        t = _irregular_times(rng, dur, 80.0)
        pos, vel = fn(t)
        out.append(Dataset(name, t, _noisy(rng, pos), pos, vel, fn))
    return out


def capture(path: Path) -> Dataset:
    """The Hatire capture as a dataset (times from the frame counter, no truth)."""
    seq, poses = _decode_capture(path)
    steps = np.diff(seq) % 1000
    steps[steps == 0] = 1000
    t = np.concatenate([[0.0], np.cumsum(steps)]) / CAPTURE_RATE_HZ
    return Dataset("capture", t, poses)


def _decode_capture(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Counters (N,) and poses (N, 6) ``(x, y, z, yaw, pitch, roll)`` of the capture."""
    try:
        from drivers.events import PoseEvent
        from drivers.protocols.hatire import HatireDecoder
    except ImportError:  # the decoder is another module; keep the bench usable alone
        return _local_parse(path.read_bytes()[CAPTURE_BANNER:])
    reader = RawCaptureReader(path, protocol="hatire", chunk_size=64, skip_bytes=CAPTURE_BANNER)
    dec = HatireDecoder(angle_limit=360.0)
    rows = []
    for rec in reader:
        for ev in dec.feed(rec.data, rec.t_ns):
            if isinstance(ev, PoseEvent):
                rows.append((ev.seq, ev.x, ev.y, ev.z, ev.yaw, ev.pitch, ev.roll))
    arr = np.array(rows, dtype=np.float64)
    return arr[:, 0].astype(np.int64), arr[:, 1:]


def _local_parse(body: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Minimal Hatire frame scan (``<HH6fH``, AA AA ... 55 55), skipping garbage."""
    frame = np.dtype([("h", "<u2"), ("code", "<u2"), ("v", "<f4", 6), ("t", "<u2")])
    rows, i = [], 0
    while i + 30 <= len(body):
        if body[i : i + 2] == b"\xaa\xaa" and body[i + 28 : i + 30] == b"UU":
            rows.append(np.frombuffer(body, frame, 1, i)[0])
            i += 30
        else:
            i += 1
    rec = np.array(rows, dtype=frame)
    keep = rec["code"] < 1000
    v = rec["v"][keep].astype(np.float64)
    return rec["code"][keep].astype(np.int64), np.c_[v[:, 3:6], v[:, 0:3]]


def best_lag(t: np.ndarray, est: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """Delay of ``est`` behind ``ref`` and the RMS residual at that delay.

    Parameters
    ----------
    t : ndarray, shape (N,)
    est, ref : ndarray, shape (N, C)

    Returns
    -------
    lag_s, residual_rms : float
        ``lag_s`` minimises ``RMS(est(t) - ref(t - lag))`` over the lag grid.
    """
    inside = t > t[0] + LAG_GRID_S[-1]

    def err(lag: float) -> float:
        return float(np.sqrt(np.mean((est[inside] - _interp(t[inside] - lag, t, ref)) ** 2)))

    coarse = LAG_GRID_S[::10]  # 10 ms steps, then 1 ms steps around the best
    k = int(np.argmin([err(lag) for lag in coarse]))
    fine = LAG_GRID_S[np.abs(LAG_GRID_S - coarse[k]) <= 0.0105]
    errs = [err(lag) for lag in fine]
    k = int(np.argmin(errs))
    return round(float(fine[k]), 4), float(errs[k])


def _interp(tq: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Linear interpolation of each column of ``y`` (N, C) at times ``tq`` (M,)."""
    return np.stack([np.interp(tq, t, y[:, c]) for c in range(y.shape[1])], axis=1)


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(a**2)))


def _hf_rms(t: np.ndarray, v: np.ndarray, window_s: float = 0.25) -> float:
    """RMS of ``v`` (N, C) minus its centred moving average over ``window_s``."""
    k = max(3, int(round(window_s / np.median(np.diff(t)))) | 1)
    kern = np.ones(k) / k
    smooth = np.stack([np.convolve(v[:, c], kern, mode="same") for c in range(v.shape[1])], 1)
    return _rms((v - smooth)[k:-k])


def score(ds: Dataset, pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, lead: float) -> dict:
    """Figures of merit of one filter run on one dataset (see the module docstring)."""
    settle = ds.t > ds.t[0] + 1.0
    out: dict[str, float] = {}
    for group, sl in (("ang", ANGLES), ("pos", POSITIONS)):
        if ds.truth is None:
            if group == "pos":
                continue
            ref = _unwrap(ds.samples)[:, sl]
            out["ang_lag_ms"] = 1e3 * best_lag(ds.t, pos[:, sl], ref)[0]
            out["ang_vel_hf_jitter"] = _hf_rms(ds.t[settle], vel[settle][:, sl])
            continue
        err = pos[settle][:, sl] - ds.truth[settle][:, sl]
        verr = vel[settle][:, sl] - ds.truth_vel[settle][:, sl]
        out[f"{group}_rms_err"] = _rms(err)
        out[f"{group}_vel_rms_err"] = _rms(verr)
        if ds.truth_fn is not None:
            out[f"{group}_lag_ms"] = 1e3 * best_lag(ds.t, pos[:, sl], ds.truth[:, sl])[0]
            out[f"{group}_vel_lag_ms"] = 1e3 * best_lag(ds.t, vel[:, sl], ds.truth_vel[:, sl])[0]
            future = ds.truth_fn(ds.t + lead)[0][:, sl]
            pred = predict_ahead(pos, vel, acc, lead)[:, sl]
            out[f"{group}_pred_rms_err"] = _rms((pred - future)[settle])
    return out


def _unwrap(samples: np.ndarray) -> np.ndarray:
    out = samples.copy()
    out[:, ANGLES] = np.rad2deg(np.unwrap(np.deg2rad(samples[:, ANGLES]), axis=0))
    return out


def run_all(datasets: list[Dataset], lead: float) -> list[dict]:
    """Run every sweep entry on every dataset; one result row each."""
    rows = []
    for name, line, label, settings in sweep():
        for ds in datasets:
            t0 = time.perf_counter()
            pos, vel, acc = run_filter(name, ds.t, ds.samples, settings)
            us = 1e6 * (time.perf_counter() - t0) / len(ds.t)
            row = {"filter": name, "line": line, "params": label, "dataset": ds.name}
            row["us_per_sample"] = us
            row.update(score(ds, pos, vel, acc, lead))
            rows.append(row)
    return rows


def _points(rows: list[dict], x: tuple[str, str], y: tuple[str, str]) -> dict[str, list]:
    """Chart lines: line name -> [(x, y, label)], x and y as (dataset, key)."""
    by = {(r["dataset"], r["params"], r["line"]): r for r in rows}
    lines: dict[str, list] = {}
    for r in rows:
        if r["dataset"] != x[0]:
            continue
        other = by.get((y[0], r["params"], r["line"]), {})
        point = (r.get(x[1], np.nan), other.get(y[1], np.nan), r["params"])
        lines.setdefault(r["line"], []).append(point)
    return lines


def _panel(ax, lines: dict[str, list], xlabel: str, ylabel: str, title: str) -> None:
    markers = {"raw": "*", "alpha-beta": "o", "alpha-beta-gamma": "s"}
    for name, pts in lines.items():
        xs, ys, labels = zip(*pts, strict=True)
        ax.plot(xs, ys, marker=markers.get(name, "^"), ms=7 if name == "raw" else 4, label=name)
        if name in ("alpha-beta", "one-euro beta=0.01 dc=2"):
            for xv, yv, lab in zip(xs, ys, labels, strict=True):
                ax.annotate(lab.split()[0], (xv, yv), fontsize=6, alpha=0.7)
    ax.set_yscale("log")
    ax.set(xlabel=xlabel, ylabel=ylabel, title=title)
    ax.grid(True, which="both", alpha=0.3)


#: The simulated-motion panels: (x as (dataset, key), y as (dataset, key), title in words).
SIM_PANELS = (
    (("sway", "ang_lag_ms"), ("still", "ang_rms_err"),
     "Angle: jitter standing still vs lag"),
    (("sway", "ang_vel_lag_ms"), ("still", "ang_vel_rms_err"),
     "Angular velocity: jitter vs lag"),
    (("sway", "ang_lag_ms"), ("turn", "ang_pred_rms_err"),
     "Head turn: prediction error vs lag"),
)


def sim_chart(rows: list[dict], path: Path, lead_ms: float) -> Figure:
    """Three panels of jitter (or prediction error) against lag on simulated motion."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(18, 5.5))
    ylabels = ("angle jitter on still (deg RMS)", "velocity jitter (deg/s RMS)",
               f"turn: prediction error at {lead_ms:g} ms (deg RMS)")
    xl = ("angle lag on sway (ms)", "velocity lag on sway (ms)", "angle lag on sway (ms)")
    for ax, (x, y, title), xlabel, ylabel in zip(axes, SIM_PANELS, xl, ylabels, strict=True):
        _panel(ax, _points(rows, x, y), xlabel, ylabel, title)
    axes[0].legend(fontsize=7)
    fig.suptitle("Pose filters on simulated motion: jitter (down) against lag (left)")
    fig.tight_layout()
    return save_chart(fig, path, dpi=110)


def capture_chart(rows: list[dict], path: Path) -> Figure:
    """Velocity noise against lag on the recorded Hatire capture (no truth)."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5.5))
    lines = _points(rows, ("capture", "ang_lag_ms"), ("capture", "ang_vel_hf_jitter"))
    _panel(ax, lines, "angle lag behind raw samples (ms)",
           "high-frequency velocity noise (deg/s RMS)",
           "Recorded Hatire capture: velocity noise vs lag")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_chart(fig, path, dpi=110)


def charts(rows: list[dict], out: Path, lead_ms: float, has_capture: bool) -> list[Path]:
    """Write the jitter/lag charts; return their paths."""
    paths = [out / "jitter_lag_sim.png"]
    sim_chart(rows, paths[0], lead_ms)
    if has_capture:
        paths.append(out / "jitter_lag_capture.png")
        capture_chart(rows, paths[-1])
    return paths


def trace_chart(ds: Dataset, out: Path) -> Path:
    """Yaw and yaw rate through the first head turn for one setting of each filter."""
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred: matplotlib loads only when a chart is drawn
    import matplotlib.pyplot as plt

    picks = {
        "raw": RawSettings(),
        "alpha-beta": AlphaBetaSettings.from_theta(0.8),
        "alpha-beta-gamma": AlphaBetaGammaSettings.from_theta(0.8),
        "one-euro": OneEuroSettings(min_cutoff=1.0, beta=0.01, d_cutoff=2.0),
    }
    win = (ds.t > 1.7) & (ds.t < 3.0)
    fig, (a0, a1) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    a0.plot(ds.t[win], ds.truth[win, 3], "k", lw=2, label="truth")
    a1.plot(ds.t[win], ds.truth_vel[win, 3], "k", lw=2, label="truth")
    for name, settings in picks.items():
        pos, vel, _ = run_filter(name, ds.t, ds.samples, settings)
        a0.plot(ds.t[win], pos[win, 3], lw=1, label=name)
        a1.plot(ds.t[win], vel[win, 3], lw=1, label=name)
    a0.set(ylabel="yaw (deg, unwrapped)", title="Head turn 150 -> 250 deg (crosses 180)")
    a1.set(ylabel="yaw rate (deg/s)", xlabel="t (s)")
    a0.legend(fontsize=7)
    fig.tight_layout()
    path = out / "turn_trace.png"
    save_chart(fig, path, dpi=110)
    return path


#: Summary table: (wide-table key, header, cell format).
COLUMNS = (
    ("filter", "filter", "{:<17}"),
    ("params", "params", "{:<24}"),
    ("sway/ang_lag_ms", "lag ms", "{:>7.0f}"),
    ("still/ang_rms_err", "jit deg", "{:>8.3f}"),
    ("sway/ang_vel_lag_ms", "vlag ms", "{:>7.0f}"),
    ("still/ang_vel_rms_err", "vjit d/s", "{:>8.2f}"),
    ("turn/ang_pred_rms_err", "pred deg", "{:>8.2f}"),
    ("capture/ang_lag_ms", "cap lag", "{:>7.0f}"),
    ("capture/ang_vel_hf_jitter", "cap vjit", "{:>8.2f}"),
    ("still/us_per_sample", "us/smp", "{:>6.1f}"),
)


def wide(rows: list[dict]) -> list[dict]:
    """One row per (filter, params) with ``dataset/metric`` columns."""
    table: dict[tuple[str, str, str], dict] = {}
    for r in rows:
        row = table.setdefault(
            (r["filter"], r["line"], r["params"]), {"filter": r["filter"], "params": r["params"]}
        )
        for k, v in r.items():
            if k not in ("filter", "line", "params", "dataset"):
                row[f"{r['dataset']}/{k}"] = v
    return list(table.values())


def print_table(rows: list[dict]) -> None:
    """Print the summary table (one line per filter setting)."""
    widths = [len(fmt.format("") if "<" in fmt else fmt.format(0.0)) for _, _, fmt in COLUMNS]
    print(
        " ".join(
            h.rjust(w) if i > 1 else h.ljust(w)
            for i, ((_, h, _), w) in enumerate(zip(COLUMNS, widths, strict=True))
        )
    )
    for row in wide(rows):
        print(" ".join(fmt.format(row.get(key, float("nan"))) for key, _, fmt in COLUMNS))


def write_results(rows: list[dict], out: Path, meta: dict) -> None:
    """Write ``results.csv`` (long form) and ``results.json`` (with run metadata)."""
    first = ["dataset", "filter", "line", "params"]
    keys = first + sorted({k for r in rows for k in r} - set(first))
    with open(out / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    clean = [
        {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in r.items()}
        for r in rows
    ]
    (out / "results.json").write_text(json.dumps({"meta": meta, "rows": clean}, indent=1))


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(
        prog="holo-bench filters", description=plain_help(__doc__.split("\n\n")[0]),
        epilog=exit_rule_epilog(),
    )
    ap.add_argument("--out", metavar="DIR", required=True, type=Path, help="output folder")
    ap.add_argument(
        "--fixture",
        metavar="FILE",
        type=Path,
        default=DEFAULT_FIXTURE,
        help="raw Hatire capture (skipped if missing)",
    )
    ap.add_argument("--seed", metavar="N", type=int, default=2012,
                    help="RNG seed of the simulations")
    ap.add_argument("--lead-ms", metavar="MS", type=float_range(0), default=50.0,
                    help="prediction lead (ms)")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    datasets = simulated(args.seed)
    has_capture = args.fixture.is_file()
    if has_capture:
        datasets.append(capture(args.fixture))
    else:
        print(f"note: no capture at {args.fixture}; simulated data only", file=sys.stderr)
    t0 = time.perf_counter()
    rows = run_all(datasets, args.lead_ms / 1e3)
    write_results(
        rows,
        args.out,
        {
            "seed": args.seed,
            "lead_ms": args.lead_ms,
            "filters": sorted(FILTERS),
            "datasets": {d.name: len(d.t) for d in datasets},
            "fixture": str(args.fixture) if has_capture else None,
            "capture_rate_hz": CAPTURE_RATE_HZ,
            "settings": {label: asdict(s) for _, _, label, s in sweep()},
        },
    )
    paths = charts(rows, args.out, args.lead_ms, has_capture)
    paths.append(trace_chart(next(d for d in datasets if d.name == "turn"), args.out))
    print_table(rows)
    print(
        f"\n{len(rows)} runs in {time.perf_counter() - t0:.1f} s; wrote results.csv, "
        f"results.json, {', '.join(p.name for p in paths)} to {args.out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
