"""``holo-bench report``: every benchmark at one size, in one self-contained HTML page.

Runs each benchmark of ``holo-bench`` (render with its peers, light, galilean,
quality, sird, lod, billboards, service, filters, latency, decoders: those built
when it runs) into ``OUT/NAME/`` and writes ``OUT/index.html``: every chart, images
inlined as base64 data URIs (no file beside it is needed), each with a sentence on
how to read it; a table per stage (method, ms, error, against the best peer); the
failure map (each method, where it fails, and the tests that show the failure and
its detection); and what did not run, with the reason.  A benchmark that fails is
reported on the page and the rest go on.

Everything is written into ``OUT.partial-TIME/`` beside ``OUT`` and moved into
``OUT`` when the run ends, so an interrupted run leaves ``OUT``'s page and data as
they were (the partial folder keeps what ran; stderr names it).  Files in ``OUT``
that no report wrote stay.

``--quick`` runs each benchmark at small settings (about 3 minutes from an empty
numba cache on two quiet cores); without it, the benchmarks' own defaults at
``--size``.  Exit status 0 when the page is written, 1 when no benchmark ran.
"""

from __future__ import annotations

import argparse
import ast
import base64
import contextlib
import csv
import html
import importlib
import importlib.util
import json
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from service.base.cli_args import exit_rule_epilog, plain_help
from service.base.cli_args import size as size_type
from service.base.errors import HoloError
from service.bench.filters_bench import COLUMNS, wide
from service.bench.peers import AMORTISE_FRAMES
from service.bench.picks import (
    BUDGET_PCT,
    Pick,
    busy_caveat,
    galilean_pays,
    light_picks,
    occlusion_picks,
    tally,
)
from service.bench.rows import zones_label
from service.bench.staging import MANIFEST, move_into_place, owned_entries, staging_folder
from service.commands.holo_bench import BENCHES
from service.warmup import warm_up


@dataclass(frozen=True)
class Plan:
    """How the report runs one benchmark and what it shows of it.

    Attributes
    ----------
    bench : str
        ``holo-bench`` name (also the output folder).
    stage : str
        The stage or part of the system it measures (the section title).
    quick, full : tuple of tuple of str
        Argument lists, one per run, for ``--quick`` and the full report;
        ``{size}`` is replaced by ``--size`` and ``--out`` is added.
    charts : dict of str to str
        Chart file name -> the sentence on how to read it.
    table : str
        Key of the stage table's builder in :data:`TABLES` (comma-separated: several).
    """

    bench: str
    stage: str
    quick: tuple[tuple[str, ...], ...]
    full: tuple[tuple[str, ...], ...]
    charts: dict[str, str] = field(default_factory=dict)
    table: str = ""


PLANS = (
    Plan("render", "Occlusion (stages 1-4), with peers",
         (("--quick", "--peers", "--size", "{size}", "--scenes", "game,cyclic",
           "--peer-scenes", "spheres-8k"),),
         (("--peers", "--size", "{size}"),),
         {"render_bench.png": "One panel per scene: x is ms per update (log), y the % of "
          "pixels whose visible polygon differs from ray casting; each solid line is one of "
          "our methods, points labelled with the zone count; dashed grey lines are the peers "
          "(llvmpipe, Embree; their y is the % of pixels whose depth differs from ray "
          "casting). Lower-left is better.",
          "peers.png": "Our z-buffer's ms (stages 1-4) divided by each peer's, per scene, zone "
          "count and size, timed in turn in one run: below 1 we are faster.",
          "runlength_angle.png": "Run-length error with its fallback off against the viewing "
          "angle (5 zones): at the zone centres (the sort's mistakes) and for a viewer "
          "anywhere in the angle (plus the zones' coarseness); the z-buffer line is the floor.",
          "runlength_zones.png": "The same errors against the zone count at 32 degrees: more "
          "zones, less error for a viewer between zone centres.",
          "zone_cost.png": "A whole render's ms per stage (stacked) against the zone count; "
          "labels are the ratio to one zone."},
         "render,peers"),
    Plan("light", "Light (stage 5)",
         (("--zones", "1,5", "--size", "{size}", "--repeats", "3", "--scenes", "sphere,game"),),
         (("--size", "{size}"),),
         {"light_bench.png": "One panel per scene: ms (log) against the mean intensity error "
          "versus per-point Blinn; colour is the light model, the marker where it is "
          "evaluated; hollow markers 1 zone. Lower-left is better."},
         "light"),
    Plan("galilean", "Galilean stage (refresh between renders)",
         (("--sweep", "--quick", "--size", "96x72", "--sweep-frames", "9", "--time-size",
           "{size}", "--complexity-counts", "0,3000,30000"),),
         (("--sweep", "--time-size", "{size}"),),
         {"galilean_sweep.png": "PSNR against the update interval, one panel per motion and a "
          "line per galpixel order; the last panel is PSNR against ms per refresh "
          "(upper-left is better).",
          "galilean_thought.png": "The paper's thought experiments: the falling object's "
          "error per refresh, the rotating square's shown radius (true 100: G(1) grows it) "
          "and a head turn through a noisy tracker (G(3) blows up).",
          "galilean_timing.png": "ms of one refresh per order (bars) against the render of the "
          "same frame (red line) and a tenth of it (dashed): a bar under the dashed line is "
          "10x cheaper than rendering.",
          "galilean_complexity.png": "Render, update and G(2) refresh ms against the triangles "
          "in the scene (log-log); where the render crosses the dashed 10x-refresh line, "
          "refreshing pays.",
          "galilean_starvation.png": "One render, then none for 3 s: error against the true "
          "render at each refresh, holding the last render past its use-by (grey line, the "
          "stage as it runs) against extrapolating on and against the render alone."},
         "galilean"),
    Plan("quality", "--quality auto (method chosen per frame)",
         (("--quick", "--size", "{size}"),), (("--size", "{size}"),), {}, "quality"),
    Plan("targets", "Speed targets (issue 14)", (("--quick",),), ((),), {}, "generic"),
    Plan("sird", "Autostereograms (SIRD)",
         (("--sizes", "{size}", "--repeats", "3", "--scenes", "slope"),),
         (("--sizes", "{size}"),),
         {"sird_bench.png": "ms per frame against decoded-depth accuracy and the streak "
          "fraction, one point per method, scene and size."},
         "sird"),
    Plan("lod", "Level of detail",
         (("--size", "{size}", "--repeats", "1", "--crowd", "20", "--meshes", "torus,spiky",
           "--crowd-mesh", "torus"),), (("--size", "{size}"),),
         {"lod_levels.png": "Per mesh, each LOD level's image error, PSNR and ms against its "
          "triangles (log x): the knee is the level worth rendering.",
          "lod_build.png": "What building each LOD chain costs (decimation and error "
          "measurement).",
          "lod_crowd.png": "A crowd rendered with LOD off and on: ms and % pixels differing."},
         "generic"),
    Plan("billboards", "Billboard clouds",
         (("--eps", "1,4", "--zoom", "1,4", "--yaws", "0,90", "--texture-res", "128",
           "--cost-meshes", "torus", "--cost-sizes", "20,80", "--repeats", "3",
           "--size", "{size}"),), (("--size", "{size}"),),
         {"billboard_bench.png": "First: billboards and build CPU seconds against EPS; second: "
          "close up (zoom), the silhouette error in pixels grows with EPS in pixels; third: "
          "depth error / EPS against the angle between ray and billboard, growing as 1 / cos "
          "toward grazing; fourth: CPU ms per frame of the full mesh, its cloud and the "
          "quadric level LOD picks, against on-screen size. Lower is better in all but the "
          "first."}, "generic"),
    Plan("service", "Render service",
         (("--quick", "--seconds", "0.5", "--workers", "1,2", "--rounds", "1"),),
         ((),), {"service.png": "Transport overhead, round trip, worker scaling and "
                 "motion-to-photon of the render service; lower is better.",
                 "chaos.png": "Workers under chaos (holo-bench chaos): every 5 s one worker "
                 "killed and another stopped; left, the gap before each update (target: "
                 "none over 1 s, red), right, the service's RSS (flat is right)."},
         "generic"),
    Plan("filters", "Pose filters", ((),), ((),),
         {"jitter_lag_sim.png": "Each pose filter (and a sweep of its parameters): jitter "
          "against lag on simulated head motion; lower-left is better.",
          "jitter_lag_capture.png": "The same on a recorded capture.",
          "turn_trace.png": "A head turn: raw and filtered angle over time."}, "filters"),
    # a serial tracker (native over a pty) and opentrack's UDP datagrams, side by side
    Plan("latency", "Device drivers: latency",
         (("--frames", "200", "--protocol", "native,opentrack"),),
         (("--protocol", "native,opentrack"),),
         {"latency.png": "Byte arrival to published event: CDFs per pipeline (native frames "
          "from a pty, opentrack datagrams over UDP) and the tail; left is faster."},
         "latency"),
    # best of 3: a single run timed the first decoder cold (sgi at 0.6 MB/s, "below target")
    Plan("decoders", "Serial protocol decoders", (("--scale", "0.2", "--repeat", "3"),), ((),),
         {}, "decoders"),
    Plan("lookingglass", "Looking Glass interleave", (("--repeat", "5"),), (("--repeat", "15"),),
         {"lookingglass.png": "Milliseconds to interleave 45 views onto a 2560x1600 panel, "
          "per numba thread count: wall and the process's CPU time; the red line is the "
          "2 ms target. Lower is better."}, "generic"),
    Plan("lod-stall", "Frame times while a level-of-detail chain builds",
         (("--repeats", "1"),), ((),),
         {"lod_stall.png": "The share of frames slower than x ms (log y), per mode: the "
          "bunny's chain built in a thread of the rendering process (quadric decimation "
          "holds the GIL, frames wait), in a child process (as the service and the game "
          "build), and no build. Lower is better."}, "generic"),
    # quick: the render path and the Galilean refresh kernels (the costliest job)
    Plan("compile", "Compile time (empty numba cache)",
         (("--job", "render zbuffer", "--job", "galilean: refresh kernels, made-up map"),),
         ((),),
         {"compile.png": "Top: each warm-up job's wall and CPU seconds from an empty numba "
          "cache, one after the other (red: the 15 s budget a job); bottom: the costliest "
          "kernel signatures' own CPU seconds. Shorter is better: a new user pays all of "
          "it before the first frame."}, "compile"),
)
#: Benchmarks that may be registered under another name once they land.
ALIASES = {"billboards": ("billboard", "billboard-cloud")}
# benchmarks that another plan's benchmark runs as its last part (chaos.png is in the
# service section), so the page has their figures without a plan of their own
RUN_INSIDE = {"chaos": "service"}
GENERIC_SENTENCE = "See the README's Benchmarks section for how to read this chart."


@dataclass
class Table:
    """A stage table: headers, rows of cells (strings) and a sentence under it."""

    headers: list[str]
    rows: list[list[str]]
    note: str = ""


@dataclass
class Outcome:
    """What one benchmark left: its folder, status and seconds, or why it did not run."""

    plan: Plan
    name: str | None
    out: Path
    ok: bool = False
    seconds: float = 0.0
    cpu_s: float = 0.0
    reason: str = ""


# ------------------------------------------------------------------ running
def registered(plan: Plan, benches: dict) -> str | None:
    """The ``holo-bench`` name the plan's benchmark is registered under, or None."""
    for name in (plan.bench, *ALIASES.get(plan.bench, ())):
        if name in benches and importlib.util.find_spec(benches[name][0]) is not None:
            return name
    return None


def run_plan(plan: Plan, benches: dict, out: Path, quick: bool, size: str) -> Outcome:
    """Run one benchmark's argument lists in this process; stdout goes to ``stdout.txt``."""
    name = registered(plan, benches)
    res = Outcome(plan, name, out / plan.bench)
    if name is None:
        res.reason = "not built: no holo-bench benchmark of that name yet"
        return res
    res.out.mkdir(parents=True, exist_ok=True)
    t0, cpu0 = time.perf_counter(), cpu_seconds()
    try:
        module = importlib.import_module(benches[name][0])
        with (res.out / "stdout.txt").open("w") as fh, contextlib.redirect_stdout(fh):
            for argv in plan.quick if quick else plan.full:
                args = [a.replace("{size}", size) for a in argv] + ["--out", str(res.out)]
                status = int(module.main(args) or 0)
                if status:
                    raise HoloError(f"holo-bench {name} {' '.join(args)}: exit status {status}")
        res.ok = True
    except SystemExit as exc:  # argparse refused the arguments
        res.reason = f"usage error (exit status {exc.code}); see stderr"
    except Exception as exc:  # noqa: BLE001 - one failing benchmark must not end the report
        res.reason = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    res.seconds = time.perf_counter() - t0
    res.cpu_s = cpu_seconds() - cpu0
    return res


# ------------------------------------------------------------------ tables
def _fmt(value, digits: int = 3) -> str:
    if value is None or value == "":
        return "-"
    if isinstance(value, float):
        if abs(value) >= 1000:
            return f"{value:.0f}"
        return f"{value:.{digits}g}" if abs(value) < 1e-2 else f"{value:.{digits}f}"
    return str(value)


def _load(path: Path):
    return json.loads(path.read_text()) if path.exists() else None


def _csv_rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def peers_not_run(status: dict) -> str:
    """Why no peer ran, from ``peers_status.json`` (each peer and its reason)."""
    why = "; ".join(f"{k}: {v}" for k, v in status.get("not_started", {}).items())
    return why or "the render benchmark ran without --peers"


def render_table(out: Path) -> Table:
    """Occlusion: method, ms, % pixels unlike ray casting, ms / the best peer's ms.

    Without any peer measured the last column is left out and the note says why.
    """
    rows = _load(out / "render_bench.json") or []
    peers = _load(out / "peers.json") or []
    best: dict = {}
    for p in peers:
        key = (p["scene"], p["zones"])
        if key not in best or p["peer_ms"] < best[key][1]:
            best[key] = (p["peer"], p["peer_ms"])
    body = []
    for r in rows:
        peer = best.get((r["scene"], r["zones"]))
        vs = f"{r['ms'] / peer[1]:.2f} x {peer[0]}" if peer else "no peer measured"
        body.append([r["method"], f"{r['scene']}, {zones_label(r['zones'])}", _fmt(r["ms"]),
                     _fmt(r["pct_differ"], 4), vs])
    status = _load(out / "peers_status.json") or {}
    heads = ["method", "scene", "ms", "error %", "against the best peer"]
    note = "error: % of pixels whose visible polygon differs from ray casting."
    if not best:
        return Table(heads[:-1], [row[:-1] for row in body],
                     f"{note} No peer ran ({peers_not_run(status)}).")
    why = "; ".join(f"{k}: {v}" for k, v in status.get("not_started", {}).items())
    note += (" Against the best peer: our ms over the fastest peer's on the same scene and "
             "zones (below 1: ours is faster); the methods and the peers ran one after the "
             "other, not in turn: the next table has the ratios measured side by side.")
    return Table(heads, body, note + (f" Peers not measured: {why}." if why else ""))


def peers_table(out: Path) -> Table:
    """Peers timed in turn with our z-buffer: both ms, the ratio, depth agreement.

    No rows (no peer ran): no table, one line saying why.
    """
    rows = _load(out / "peers.json") or []
    status = _load(out / "peers_status.json") or {}
    if not rows:
        return Table([], [], f"No peer ran, so there is no peer table: {peers_not_run(status)}.")
    body = [[r["peer"], f"{r['scene']} ({r['triangles']} triangles), {zones_label(r['zones'])}, "
             f"{r['size']}", _fmt(r["ours_ms"]), _fmt(r["peer_ms"]), f"{r['ratio']:.3f}",
             _fmt(r.get("build_ms")), f"{r['pct_agree']:.4f}"] for r in rows]
    engines = "; ".join(f"{k}: {v}" for k, v in status.get("started", {}).items())
    why = "; ".join(f"{k}: {v}" for k, v in status.get("not_started", {}).items())
    note = ("Side by side: each round times our z-buffer (stages 1-4, depth out) and every "
            "peer in turn; best round's median. ours / peer below 1: ours is faster. Depth "
            f"agrees: % of pixels within {status.get('tolerance', 0.001)} world units of ours "
            f"(or empty in both). Build ms: the peer's BVH build or upload, once per "
            f"scene, not in peer ms (peers_fastest.csv adds it amortised over "
            f"{AMORTISE_FRAMES} frames, or paid every frame for a moving scene). "
            f"Engines: {engines or 'none started'}.")
    return Table(["peer", "scene", "ours ms", "peer ms", "ours / peer", "build ms",
                  "depth agrees %"],
                 body, note + (f" Not started: {why}." if why else ""))


def light_table(out: Path) -> Table:
    """Light: model per evaluation, ms, mean intensity error against per-point Blinn."""
    rows = _load(out / "light_bench.json") or []
    rows = rows if isinstance(rows, list) else rows.get("rows", [])
    body = [[f"{r['model']} per {r['evaluation']}", f"{r['scene']}, {zones_label(r['zones'])}",
             _fmt(r["ms"]), _fmt(r["error"], 4), "no peer measured"] for r in rows]
    return Table(["method", "scene", "ms", "error", "against the best peer"], body,
                 "error: mean absolute intensity difference from per-point Blinn (0-1).")


def galilean_table(out: Path) -> Table:
    """Galilean: ms per refresh per order, its median PSNR over the sweep, render / refresh."""
    tm = _load(out / "galilean_timing.json") or {"orders": {}}
    sweep = (_load(out / "galilean_sweep.json") or {}).get("rows", [])
    body = []
    for key, v in tm["orders"].items():
        order = int(key[1]) if key[1:2].isdigit() else None
        ps = sorted(r["psnr"] for r in sweep if r["order"] == order and r["psnr"] is not None)
        med = ps[len(ps) // 2] if ps else None
        body.append([key, _fmt(v["ms_per_refresh"]), _fmt(med),
                     f"render {v['render_ratio']:.1f} x dearer (no peer measured)"])
    return Table(["method", "ms per refresh", "median PSNR dB (sweep)", "against"], body,
                 f"Timed at {tm.get('size', '?')}; PSNR over every motion and interval of the "
                 "sweep for that order (higher is better).")


def sird_table(out: Path) -> Table:
    """SIRD: method, ms, decoded accuracy and streaks per scene and size."""
    rows = (_load(out / "sird_bench.json") or {}).get("rows", [])
    body = [[r["method"], f"{r['scene']}, {r['size']}", _fmt(r["ms"]),
             f"{100 * (1 - r['accuracy']):.2f} % wrong, streaks {100 * r['streaks']:.2f} %",
             "no peer measured"] for r in rows]
    return Table(["method", "scene", "ms", "error", "against the best peer"], body,
                 "error: % of edge-free pixels decoded off the expected separation, and the "
                 "% of pixels in streaks (runs of 3+ equal colours).")


def quality_table(out: Path) -> Table:
    """--quality auto: its picks, predicted and measured error, within budget or not."""
    rows = _csv_rows(out / "quality_auto.csv")
    body = [[f"{r['method']} + {r['specular']}", f"{r['scene']}, budget {r['budget']}",
             _fmt(float(r["ms"])), f"{r['measured_pct_wrong']} % (predicted "
             f"{r['predicted_pct_wrong']} %)", r["within_budget"]] for r in rows]
    return Table(["picked", "scene", "ms", "measured error", "within budget"], body,
                 "What --quality auto picked per frame, and its error against ray casting with "
                 "per-point light.")


def decoders_table(out: Path) -> Table:
    """Decoders: MB/s per protocol and stream."""
    res = (_load(out / "decoder_throughput.json") or {}).get("results", {})
    body = [[k, _fmt(v["mb_per_s"]), _fmt(v.get("events_per_s", 0.0), 6),
             str(v.get("meets_target", ""))] for k, v in res.items()]
    return Table(["protocol/stream", "MB/s", "events/s", "meets target"], body)


def latency_table(out: Path) -> Table:
    """Drivers' latency: per pipeline and leg, p50 / p95 / p99 / max ms and the target."""
    data = _load(out / "latency.json") or {}
    body = []
    for wiring, legs in data.get("wirings", {}).items():
        lost = data.get("lost", {}).get(wiring, "-")
        for leg, s in legs.items():
            body.append([wiring, leg, *(_fmt(s.get(k)) for k in LATENCY_STATS), str(s.get("n")),
                         str(lost)])
    if "bare_hop" in data:  # the reference: a bare PUB -> SUB hop under the same load
        s, lost = data["bare_hop"], data.get("lost", {}).get("bare_hop", "-")
        body.append(["(reference)", "bare_hop", *(_fmt(s.get(k)) for k in LATENCY_STATS),
                     str(s.get("n")), str(lost)])
    met = {True: "met", False: "NOT met"}.get(data.get("target_met"), "not measured")
    return Table(["pipeline", "leg", "p50 ms", "p95 ms", "p99 ms", "max ms", "frames", "lost"],
                 body, f"Target: {data.get('headline', 'arrival -> published')} p99 <= "
                 f"{_fmt(data.get('target_p99_ms'))} ms: {met}. Legs: to_arrival, the device's "
                 "write to the reader's arrival stamp (kernel pty or UDP socket, and reader "
                 "wake-up); "
                 "published, arrival to the publisher's send; received, arrival to a "
                 "subscriber in the same process; total, write to received; bare_hop, a bare "
                 "PUB -> SUB send and receive timed beside them, nothing else in the path.")


def _cell_as(value, fmt: str) -> str:
    """``value`` in the benchmark's own cell format (``"{:>7.0f}"``), ``-`` when missing."""
    return "-" if value is None or value == "" else fmt.format(value).strip()


#: The latency summaries' columns, in :func:`latency_table`'s order.
LATENCY_STATS = ("p50_ms", "p95_ms", "p99_ms", "max_ms")


def filters_table(out: Path) -> Table:
    """Pose filters: one row per filter setting, the columns ``holo-bench filters`` prints."""
    rows = (_load(out / "results.json") or {}).get("rows", [])
    body = [[_cell_as(r.get(key), fmt) for key, _, fmt in COLUMNS] for r in wide(rows)]
    return Table([head for _, head, _ in COLUMNS], body,
                 "lag ms: angle lag on the simulated sway; jit deg: angle error standing still; "
                 "vlag, vjit: the same for angular velocity (d/s); pred deg: the error of the "
                 "pose predicted ahead through a head turn; cap lag, cap vjit: lag and "
                 "velocity jitter on the recorded Hatire capture; us/smp: filter time per "
                 "sample. Lower is better in every column; each filter trades lag for jitter.")


def generic_table(out: Path, limit: int = 30, columns: int = 9) -> Table:
    """The first CSV a benchmark wrote, its first ``columns`` columns and ``limit`` rows."""
    files = sorted(out.glob("*.csv"))
    if not files:
        return Table([], [], "No table written.")
    rows = _csv_rows(files[0])
    if not rows:
        return Table([], [], f"{files[0].name} is empty.")
    heads = list(rows[0])[:columns]
    body = [[_fmt(_num(r[h])) for h in heads] for r in rows[:limit]]
    more = f" (first {limit} of {len(rows)} rows)" if len(rows) > limit else ""
    return Table(heads, body, f"From {files[0].name}{more}; no peer is measured for this stage.")


def _num(text: str):
    try:
        return float(text) if any(c in text for c in ".e") else int(text)
    except ValueError:
        return text


def compile_table(out: Path) -> Table:
    """Cold compile: wall and CPU seconds per warm-up job, and the whole warm-up's."""
    data = _load(out / "compile.json") or {}
    budget = data.get("budget", {})
    body = [[j["job"], _fmt(j["wall_s"]), _fmt(j["cpu_s"]), str(j["kernels"]),
             "over" if j["job"] in data.get("over_budget", []) else "within"]
            for j in data.get("jobs", [])]
    w = data.get("whole")
    if w:
        over = w["wall_s"] > budget.get("whole_wall_s", float("inf"))
        body.append(["whole holo-warmup (2 processes)", _fmt(w["wall_s"]), _fmt(w["cpu_s"]),
                     "", "over" if over else "within"])
    load = data.get("load", ["?", "?"])
    return Table(["job", "wall s", "CPU s", "kernels", "budget"], body,
                 f"From an empty numba cache, jobs one after the other in one process; load "
                 f"{load[0]}-{load[1]} on {data.get('cores', '?')} cores (wall time stretches "
                 f"with the load, CPU time much less). Budget: "
                 f"{_fmt(budget.get('job_wall_s'))} s a job, "
                 f"{_fmt(budget.get('whole_wall_s'))} s the whole warm-up on 2 quiet cores.")


TABLES = {"render": render_table, "peers": peers_table, "light": light_table,
          "galilean": galilean_table, "sird": sird_table, "quality": quality_table,
          "decoders": decoders_table, "latency": latency_table, "filters": filters_table,
          "generic": generic_table, "compile": compile_table}


# ------------------------------------------------------------------ failure map
@dataclass(frozen=True)
class Failure:
    """A method, where it fails, and the tests that show it and that it is detected.

    ``needs`` is a module that must exist for the row to apply (a part not built
    yet gets a "not built" row instead).
    """

    method: str
    where: str
    shown_by: tuple[str, ...]
    detected_by: tuple[str, ...]
    needs: str = ""


FAILURES = (
    Failure("runlength (painter's order, one average-z sort)",
            "cyclic overlap and interpenetrating polygons: the sort puts a farther polygon "
            "first",
            ("tests/render/test_pipeline.py::test_interpenetration_is_detected_too",),
            ("tests/render/test_pipeline.py::"
             "test_cyclic_overlap_is_detected_and_falls_back_to_the_zbuffer",
             "tests/render/test_pipeline.py::test_pixel_fallback_equals_the_zbuffer_and_reports_it",
             "tests/render/test_quality.py::test_a_sort_cycle_makes_it_leave_runlength")),
    Failure("runlength beyond 16 degrees and with many zones",
            "one sort for every zone: the wider the angle the more zones see it out of order; "
            "a viewer between zone centres sees the wrong object more often with fewer zones",
            ("tests/render/test_pipeline.py::"
             "test_five_zone_error_grows_with_angle_and_shrinks_with_zones",
             "tests/render/test_pipeline.py::test_runlength_within_16_degrees_on_the_game_scene"),
            ("tests/render/test_pipeline.py::"
             "test_cyclic_overlap_is_detected_and_falls_back_to_the_zbuffer",
             "tests/render/test_quality.py::test_measured_error_stays_within_the_budget_over_scenes")),
    Failure("G(1) (galpixels with velocity only)",
            "rotation: a point on a turning object leaves its tangent, so the shown object "
            "grows between updates",
            ("tests/galilean/test_gal_experiments.py::"
             "test_rotating_square_grows_under_g1_bounded_under_g2",),
            ("tests/galilean/test_gal_render.py::test_error_estimate_orders_re_renders",
             "tests/galilean/test_gal_render.py::test_use_by_date_fires_past_45_degrees",
             "tests/render/test_quality.py::test_galilean_order_and_interval_fit_the_budget")),
    Failure("Galilean stage past its use-by (renders late)",
            "past the rated propagation time (or 45 degrees of turn) the extrapolation's "
            "error grows without bound: moving objects smear, turning ones fly apart",
            ("tests/galilean/test_gal_experiments.py::test_error_grows_past_rating",
             "tests/galilean/test_gal_bench_cli.py::test_cli_starvation"),
            ("tests/galilean/test_gal_hold.py::"
             "test_a_starved_stage_shows_the_last_render_once_it_is_past_its_use_by",
             "tests/galilean/test_gal_hold.py::"
             "test_a_render_is_used_by_the_refresh_before_an_object_turns_45_degrees",
             "tests/service/test_service_hold.py::"
             "test_renders_that_stop_coming_leave_the_last_render_held_not_extrapolated")),
    Failure("G(3) (up to jerk)",
            "noisy derivatives (a tracker differentiated three times): the jerk term "
            "amplifies the noise and the prediction diverges",
            ("tests/galilean/test_gal_experiments.py::"
             "test_g3_with_noisy_differentiated_tracker_is_unstable",),
            ("tests/galilean/test_gal_render.py::test_order_guard_falls_back_from_noisy_g3",)),
    Failure("SIRD, one row of random dots (row)",
            "slopes and large separations: the same dots repeat into streaks",
            ("tests/autostereogram/test_sird_stage.py::"
             "test_streaks_on_the_seed_slope_interpolated_leaves_a_tenth_of_rows",),
            ("tests/autostereogram/test_sird_stage.py::test_decoder_recovers_the_sphere",),
            needs="service.autostereogram"),
    Failure("billboard clouds", "parallax: a flat billboard shows no depth within itself "
            "across zones, worst close up and at grazing angles (holo-bench billboard "
            "measures it)",
            ("tests/simplify/test_billboard_limits.py::"
             "test_depth_error_passes_the_lod_bound_at_grazing_angles",),
            ("tests/simplify/test_billboard_limits.py::"
             "test_error_rises_close_up_and_lod_never_picks_the_cloud_past_the_budget",),
            needs="service.billboard_render"),
    Failure("level of detail", "a level too coarse for its size on screen changes the "
            "silhouette; under a time budget it is pushed past the error budget",
            ("tests/render/test_lod.py::test_measured_screen_error_stays_within_the_prediction",),
            ("tests/render/test_lod.py::test_the_selector_never_picks_a_level_over_budget",
             "tests/render/test_lod.py::test_budget_ms_degrades_past_the_error_and_says_so"),
            needs="service.lod"),
)


def test_exists(node_id: str, root: Path) -> bool:
    """Whether ``path::test_name`` names a test function defined at the top of its file."""
    path, _, name = node_id.partition("::")
    file = root / path
    if not name or not file.is_file():
        return False
    tree = ast.parse(file.read_text())
    return any(isinstance(n, ast.FunctionDef) and n.name == name for n in tree.body)


def failure_rows(root: Path) -> list[list]:
    """Cells of the failure map (a tuple cell is one line per item).

    A row whose part is not built says so; a named test missing from ``root``'s
    checkout is marked.
    """
    rows: list[list] = []
    for f in FAILURES:
        if f.needs and importlib.util.find_spec(f.needs) is None:
            rows.append([f.method, f.where, f"not built ({f.needs} does not exist yet)", "-"])
            continue
        cells = []
        for tests in (f.shown_by, f.detected_by):
            cells.append(tuple(t if test_exists(t, root) else f"{t} (not in this checkout)"
                               for t in tests) or "no test named yet")
        rows.append([f.method, f.where, *cells])
    return rows


# ------------------------------------------------------------------ the page
CSS = """body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:.5em 0;font-size:90%}td,th{border:1px solid #bbb;
padding:2px 6px;text-align:left;vertical-align:top}th{background:#eee}img{max-width:100%}
.note{color:#555;font-size:90%}.fail{color:#a00}figure{margin:1em 0}code{font-size:90%}"""


def _cell(value) -> str:
    if isinstance(value, tuple):
        return "<br>".join(f"<code>{html.escape(v)}</code>" for v in value)
    return html.escape(str(value))


def table_html(table: Table) -> str:
    """A :class:`Table` as HTML (every cell escaped)."""
    if not table.headers:
        return f'<p class="note">{html.escape(table.note)}</p>'
    head = "".join(f"<th>{html.escape(h)}</th>" for h in table.headers)
    body = "".join("<tr>" + "".join(f"<td>{_cell(c)}</td>" for c in row) + "</tr>"
                   for row in table.rows)
    note = f'<p class="note">{html.escape(table.note)}</p>' if table.note else ""
    return f"<table><tr>{head}</tr>{body}</table>{note}"


def image_html(path: Path, sentence: str) -> str:
    """A PNG inlined as a base64 data URI, with its how-to-read sentence."""
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (f'<figure><img alt="{html.escape(path.name)}" src="data:image/png;base64,{data}">'
            f"<figcaption><b>{html.escape(path.name)}</b>: {html.escape(sentence)}"
            "</figcaption></figure>")


def section_html(res: Outcome) -> str:
    """One benchmark's section: status, charts with sentences, its stage table."""
    title = f"{res.plan.stage} (holo-bench {res.name or res.plan.bench})"
    parts = [f'<h2 id="{res.plan.bench}">{html.escape(title)}</h2>']
    if res.name is None or not res.ok:
        parts.append(f'<p class="fail">Not run: {html.escape(res.reason)}</p>')
        if res.name is None or not res.out.is_dir():
            return "".join(parts)
    else:
        parts.append(f'<p class="note">Ran in {res.seconds:.1f} s (CPU {res.cpu_s:.1f} s).</p>')
    charts = sorted(res.out.glob("*.png"), key=lambda p: (p.name not in res.plan.charts,
                                                          list(res.plan.charts).index(p.name)
                                                          if p.name in res.plan.charts else 0,
                                                          p.name))
    parts += [image_html(p, res.plan.charts.get(p.name, GENERIC_SENTENCE)) for p in charts]
    for key in res.plan.table.split(","):
        table = TABLES[key](res.out)  # one without headers is a line saying why
        parts.append(("<h3>Stage table</h3>" if table.headers else "") + table_html(table))
    return "".join(parts)


def _ran(results: list[Outcome], bench: str) -> Outcome | None:
    """The outcome of ``bench`` when it ran, else None."""
    return next((r for r in results if r.plan.bench == bench and r.ok), None)


def picks_table(picks: list[Pick]) -> Table:
    """Per case: the fastest exact method and the cheapest within the error budget."""
    def cell(choice, error: bool) -> str:
        if choice is None:
            return "none measured"
        text = f"{choice[0]} ({_fmt(choice[1])} ms"
        return text + (f", {_fmt(choice[2], 4)} %)" if error else ")")

    body = [[p.stage, p.case, cell(p.exact, False), cell(p.within, True)] for p in picks]
    return Table(["stage", "case", "fastest exact", f"cheapest within {BUDGET_PCT:g} % error"],
                 body, "Exact: no pixel unlike ray casting (occlusion), no intensity unlike "
                 "per-point Blinn (light). Error: % of pixels (occlusion), % of full "
                 "intensity (light). From this run's medians; the stage tables below have "
                 "every method.")


def recommendations(results: list[Outcome]) -> tuple[list[str], list[Pick]]:
    """Sentences and per-case picks from the runs of render, light and galilean."""
    lines: list[str] = []
    picks: list[Pick] = []
    sources = (("render", "render_bench.json", occlusion_picks, "occlusion"),
               ("light", "light_bench.json", light_picks, "light"))
    for bench, name, picker, stage in sources:
        res = _ran(results, bench)
        rows = _load(res.out / name) if res else None
        rows = rows.get("rows", []) if isinstance(rows, dict) else rows
        if not rows:
            lines.append(f"{stage.capitalize()}: not measured in this run (holo-bench {bench} "
                         "did not run).")
            continue
        found = picker(rows)
        lines.append(tally(found) + busy_caveat(bench, res.seconds, res.cpu_s))
        picks += found
    res = _ran(results, "galilean")
    cx = _load(res.out / "galilean_complexity.json") if res else None
    sweep = (_load(res.out / "galilean_sweep.json") or {}).get("rows", []) if res else []
    pays = galilean_pays(cx, sweep) if cx else []
    if pays:
        pays[0] += busy_caveat("galilean", res.seconds, res.cpu_s)
    lines += pays or ["Galilean stage: not measured in this run (holo-bench galilean did "
                      "not run)."]
    return lines, picks


def picks_html(results: list[Outcome]) -> str:
    """The section at the top of the page: what to pick, from this run's data."""
    lines, picks = recommendations(results)
    items = "".join(f"<li>{html.escape(line)}</li>" for line in lines)
    table = table_html(picks_table(picks)) if picks else ""
    return f'<h2 id="picks">What to pick (from this run)</h2><ul>{items}</ul>{table}'


def machine_line() -> str:
    """Python, platform, cores, load average and thread settings, in one line."""
    load = os.getloadavg() if hasattr(os, "getloadavg") else ()
    threads = {k: os.environ.get(k, "-") for k in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS",
                                                     "LP_NUM_THREADS")}
    return (f"Python {platform.python_version()} on {platform.platform()}, "
            f"{os.cpu_count()} cores, load average {', '.join(f'{x:.1f}' for x in load)}; "
            + ", ".join(f"{k}={v}" for k, v in threads.items()))


def page(results: list[Outcome], meta: dict, root: Path) -> str:
    """The whole report page."""
    toc = "".join(f'<li><a href="#{r.plan.bench}">{html.escape(r.plan.stage)}</a>'
                  f'{"" if r.ok else " (not run)"}</li>' for r in results)
    fail = Table(["method", "where it fails", "test that shows it", "test that shows the "
                  "system detects it"], failure_rows(root),
                 "Node ids are pytest's: run one with `pytest 'NODE_ID'`.")
    head = (f"<p>{html.escape(meta['what'])}. Wall time {meta['wall_s']:.0f} s, CPU time "
            f"{meta['cpu_s']:.0f} s (user + system, this process and its children). "
            f"{html.escape(meta.get('warmup', ''))}</p>"
            f'<p class="note">{html.escape(meta["machine"])}</p>')
    return ("<!DOCTYPE html><html><head><meta charset=\"utf-8\">"
            f"<title>Holo-realizer benchmark report</title><style>{CSS}</style></head><body>"
            f"<h1>Holo-realizer benchmark report</h1>{head}{picks_html(results)}"
            f'<h2>Contents</h2><ul><li><a href="#picks">What to pick</a></li>{toc}'
            '<li><a href="#failure-map">Failure map</a></li></ul>'
            + "".join(section_html(r) for r in results)
            + '<h2 id="failure-map">Failure map</h2>' + table_html(fail)
            + "</body></html>")


def cpu_seconds() -> float:
    """User + system CPU seconds of this process and its waited-for children."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def compile_ahead() -> str:
    """Compile (or load) the numba kernels ahead, in two processes; one line on what it did.

    On an empty cache the kernels compile about twice as fast on two cores as one
    benchmark after another would (:func:`service.warmup.warm_up`); cached, seconds.
    """
    print("[report] numba kernels: compiling or loading ahead", file=sys.stderr, flush=True)
    rep = warm_up(processes=2)
    return (f"Numba kernels compiled ahead in two processes: {rep.compiled} of {rep.total} "
            f"warm-up jobs compiled, {rep.cached} loaded from the cache, {rep.seconds:.0f} s.")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``holo-bench report``."""
    p = argparse.ArgumentParser(prog="holo-bench report", description=plain_help(__doc__),
                                epilog=exit_rule_epilog("no benchmark ran."),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", metavar="DIR", default="bench-out",
                   help="output folder (default bench-out); filled when the run ends")
    p.add_argument("--quick", action="store_true", help="small settings (about 3 minutes)")
    p.add_argument("--no-warmup", dest="warmup", action="store_false",
                   help="do not compile the numba kernels ahead in two processes")
    p.add_argument("--only", metavar="NAME,...", default=None,
                   help="comma-separated benchmark names to run (default: all)")
    p.add_argument("--size", type=size_type, default=None, metavar="WxH",
                   help="pixels per zone image (default: 160x120 with --quick, else 320x240)")
    return p


def run_all(args: argparse.Namespace, work: Path) -> tuple[list[Outcome], dict]:
    """Every planned benchmark into ``work/NAME/``; the outcomes and the page's meta."""
    plans = [pl for pl in PLANS if args.only is None or pl.bench in args.only.split(",")]
    planned = {n for pl in PLANS for n in (pl.bench, *ALIASES.get(pl.bench, ()))}
    planned |= set(RUN_INSIDE)
    unplanned = [n for n in BENCHES if n not in planned and n != "report"]
    wall0, cpu0 = time.perf_counter(), cpu_seconds()
    size = f"{args.size[0]}x{args.size[1]}"
    warm = compile_ahead() if args.warmup else "Kernels not compiled ahead (--no-warmup)."
    results = []
    for i, plan in enumerate(plans, 1):
        print(f"[report {i}/{len(plans)}] {plan.bench}", file=sys.stderr, flush=True)
        results.append(run_plan(plan, BENCHES, work, args.quick, size))
    for name in unplanned if args.only is None else ():
        res = Outcome(Plan(name, BENCHES[name][1], (), (), {}, "generic"), name, work / name)
        res.reason = "registered, but the report has no plan for it yet (run it by hand)"
        results.append(res)
    meta = {"what": f"holo-bench report{' --quick' if args.quick else ''} at {size}",
            "wall_s": time.perf_counter() - wall0, "cpu_s": cpu_seconds() - cpu0,
            "machine": machine_line(), "warmup": warm}
    return results, meta


def write_page(results: list[Outcome], meta: dict, work: Path) -> None:
    """``index.html`` and ``report.json`` (whose ``benches`` name the folders) in ``work``."""
    root = Path(__file__).resolve().parents[2]
    (work / "index.html").write_text(page(results, meta, root))
    (work / MANIFEST).write_text(json.dumps(
        {**meta, "benches": {r.plan.bench: {"ran": r.ok, "seconds": round(r.seconds, 2),
                                            "cpu_s": round(r.cpu_s, 2), "reason": r.reason}
                             for r in results}}, indent=1))


def main(argv: list[str] | None = None) -> int:
    """``holo-bench report``; returns the exit status.

    Everything is written into a staging folder beside ``--out`` and moved into
    place at the end (:mod:`service.bench.staging`): an interrupted run leaves the
    previous page and its data as they were, and the staging folder with what ran.
    """
    args = build_parser().parse_args(argv)
    args.size = args.size or ((160, 120) if args.quick else (320, 240))
    out = Path(os.path.abspath(args.out))
    work = staging_folder(out)
    try:
        results, meta = run_all(args, work)
        write_page(results, meta, work)
        move_into_place(work, out, owned_entries(out))
    except BaseException:
        # a line of its own: Ctrl-C may land between a progress line's text and its newline
        print(f"\nholo-bench report: {args.out} left as it was; what ran so far is in {work}",
              file=sys.stderr, flush=True)
        raise
    for r in results:
        state = f"ok {r.seconds:.1f} s (CPU {r.cpu_s:.1f} s)" if r.ok else \
            f"not run: {r.reason}"
        print(f"  {r.plan.bench:11s} {state}")
    print(f"wrote {Path(args.out) / 'index.html'} in {meta['wall_s']:.0f} s "
          f"(CPU {meta['cpu_s']:.0f} s)")
    return 0 if any(r.ok for r in results) else 1
